"""Named configurations a user picks in one word: ``irdetect process --profile fast``.

A profile is a TOML file in ``data/profiles`` with the tables of a ``--config`` file
(``docs/cli.md``); ``default`` is the built-in defaults. A ``--config`` file given with a
profile is applied on top of it. The profiles and what they are for (measured in
docs/results/throughput.md and docs/results/profiles.md):

``default``
    The full front end: per-frame suppression, the ``dp`` merit, a low first threshold
    and the matched-filter verification of every chain (SNR 2 targets, clutter).
``fast``
    The same suppression (``auto``) and ``dp`` merit without the verification and the
    fast band: a higher first threshold (k 3.5, one robust sigma per frame measured on a
    4-px grid) and the earlier score test. 3-4x the default's frames per CPU-second
    (measured 3.4x at 256x256 to 3.9x at 640x512, docs/results/throughput.md); for
    targets of SNR 3 and up moving up to about 2 px/frame (at SNR 2 it finds about half
    the targets the default finds).
``paper``
    The paper's variant (Wan & Askar 2008), for comparison: max projection, the paper's
    grouping, no verification; the chains keep the one-to-one resolution and the score
    test (with the paper's unique correspondence nothing survives at k 3.5). For
    ``irdetect track``: Cheng et al.'s absolute grey and area gates of their harbour.
``maritime``
    ``irdetect track`` on sea scenes only: the sea-sky band, 5.5 robust sigmas of the
    unsmoothed residual and 5 px against waves and glints (``process`` runs it as the
    default).
"""

from __future__ import annotations

import os
from pathlib import Path

from irdetect import data_dir
from irdetect.config import ProcessConfig, from_dict, merge_tables, read_toml
from irdetect.errors import InputError


def profile_names() -> list[str]:
    """The profiles available: ``default`` and one per ``data/profiles/*.toml``."""
    folder = data_dir("profiles")
    found = sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []
    return ["default"] + [n for n in found if n != "default"]


def profile_path(name: str) -> Path | None:
    """The TOML file of profile ``name`` (None for ``default``); InputError if unknown."""
    if name == "default":
        return None
    path = data_dir("profiles") / f"{name}.toml"
    if not path.is_file():
        raise InputError(f"--profile {name}: unknown profile "
                         f"(known: {', '.join(profile_names())})")
    return path


def load_profile(name: str = "default", config: str | os.PathLike | None = None,
                 cls=ProcessConfig):
    """Configuration of profile ``name`` with the TOML file ``config`` (optional) on top.

    Returns an instance of ``cls``; unknown tables or keys in either file are an
    InputError naming the file (``irdetect.config.from_dict``).
    """
    path = profile_path(name)
    data = {} if path is None else read_toml(path)
    from_dict(cls, data, path=path)                   # a broken profile names itself
    if config is not None:
        merge_tables(data, read_toml(config))
    return from_dict(cls, data, path=config if config is not None else path)
