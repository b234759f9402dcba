"""irdetect: dim point target detection and track initiation in infrared image sequences.

Conventions used everywhere: image stacks are arrays of shape (T, H, W); a point is
(x, y) with x = column and y = row in pixels, the centre of pixel (0, 0) at (0, 0);
a line is rho = x cos(theta) + y sin(theta) with theta in [0, pi); frames count from 0.
"""

import sys
from pathlib import Path

__version__ = "0.1.0"


def read_results(path, *, as_frame: bool | None = None):
    """Read a results file: its tables (detections, tracks, ...) and root attributes.

    Parameters
    ----------
    path : str or os.PathLike
        A results file written by ``irdetect process``, ``track`` or ``initiate``
        (``docs/format.md``).
    as_frame : bool or None
        None (default): tables as ``pandas.DataFrame`` when pandas is installed, else as
        numpy structured arrays; True: DataFrames (pandas required); False: arrays.

    Returns
    -------
    irdetect.io.Results
        ``results.tables`` maps a table name to its rows (x = column, y = row, px;
        frames from 0), ``results["tracks"]`` is one of them, ``results.attrs`` the root
        attributes, ``results.config`` the resolved configuration (dict).

    Raises
    ------
    irdetect.errors.InputError
        Missing or unreadable file.

    Examples
    --------
    >>> import irdetect                                            # doctest: +SKIP
    >>> res = irdetect.read_results("seq.irdetect.h5")
    >>> res["tracks"][["track_id", "vx", "vy", "frame_start", "frame_end"]]
    """
    from irdetect.io.results import read_results as _read

    return _read(path, as_frame=as_frame)


def data_dir(name: str) -> Path:
    """The folder ``data/<name>`` (e.g. ``presets``) shipped with irdetect.

    In a source checkout (an editable install) it is the repository's ``data/<name>``; a
    wheel installs the same files under ``<prefix>/share/irdetect/<name>``
    (``[tool.setuptools.data-files]`` in pyproject.toml).
    """
    source = Path(__file__).resolve().parents[1] / "data" / name
    if source.is_dir():
        return source
    return Path(sys.prefix) / "share" / "irdetect" / name
