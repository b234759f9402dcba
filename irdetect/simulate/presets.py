"""Scenario presets: TOML files in ``data/presets``, each with a ``kind``.

``kind`` is ``"sequence"`` (point targets, ``irdetect.simulate.sequence``), ``"harbour"``
(extended ships, ``irdetect.simulate.harbour``) or ``"scans"`` (radar-style measurements,
``irdetect.simulate.scans``); a preset without one is a sequence.
"""

from __future__ import annotations

import os
from pathlib import Path

from irdetect import data_dir
from irdetect.config import read_toml
from irdetect.errors import InputError

PRESETS = data_dir("presets")


#: the largest frame the simulator writes (a frame is built whole in memory)
MAX_PIXELS = 8192 * 8192


def preset_path(name: str | os.PathLike) -> Path:
    """``data/presets/<name>.toml``, or ``name`` itself when it is a ``.toml`` path."""
    path = Path(name)
    return path if path.suffix == ".toml" else PRESETS / f"{name}.toml"


def preset_kind(name: str | os.PathLike) -> str | None:
    """The ``kind`` of a preset, or None when there is no such preset."""
    path = preset_path(name)
    return read_toml(path).get("kind", "sequence") if path.is_file() else None


def read_preset(name: str | os.PathLike, kind: str) -> tuple[dict, Path]:
    """Read a preset of the given kind; returns its keys (less ``kind``, ``description``).

    Raises
    ------
    InputError
        No such preset (the message lists the presets of this kind), invalid TOML, or a
        preset of another kind.
    """
    path = preset_path(name)
    if not path.is_file():
        known = sorted(p.stem for p in PRESETS.glob("*.toml") if preset_kind(p) == kind)
        raise InputError(f"unknown {kind} scenario (presets: {', '.join(known)})", name)
    data = read_toml(path)
    data.pop("description", None)
    found = data.pop("kind", "sequence")
    if found != kind:
        raise InputError(f"this preset is a {found} scenario, not a {kind} scenario", path)
    return data, path
