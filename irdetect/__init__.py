"""irdetect: dim point target detection and track initiation in infrared image sequences.

Conventions used everywhere: image stacks are arrays of shape (T, H, W); a point is
(x, y) with x = column and y = row in pixels, the centre of pixel (0, 0) at (0, 0);
a line is rho = x cos(theta) + y sin(theta) with theta in [0, pi); frames count from 0.
"""

import sys
from pathlib import Path

__version__ = "0.1.0"


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
