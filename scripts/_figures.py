"""The benchmarks' figures: curves saved as PNG beside their tables in docs/results/.

Drawn with matplotlib (``pip install irdetect[plot]``) on the Agg canvas and written
atomically by ``irdetect.plot.write_figure``. A benchmark without matplotlib still writes
its tables; ``save_curves`` then says so and returns None.
"""

from __future__ import annotations

import sys
from pathlib import Path


def _panels(path, n: int, width: float, height: float):
    """(figure, axes) of ``n`` panels side by side, or None (said on stderr) without
    matplotlib."""
    from irdetect.errors import InputError
    from irdetect.plot import require_matplotlib

    try:
        Figure, Canvas = require_matplotlib()
    except InputError as exc:
        print(f"no figure {path}: {exc}", file=sys.stderr)
        return None
    fig = Figure(figsize=(width * n, height), dpi=100, layout="constrained")
    Canvas(fig)
    return fig, fig.subplots(1, n, squeeze=False)[0]


def save_curves(path, panels, *, title: str | None = None, width: float = 6.0,
                height: float = 4.0) -> Path | None:
    """Write one PNG of line panels side by side.

    Parameters
    ----------
    path : str or Path
        The PNG to write (replaced when it exists).
    panels : list of dict
        One per panel: ``xlabel``, ``ylabel``, ``series`` (list of dicts with ``x``,
        ``y``, ``label`` and optional matplotlib style keys: ``ls``, ``marker``,
        ``color``), optional ``title``, ``xscale``, ``yscale``, ``ylim``, ``xticks``.
    title : str, optional
        The figure's title.

    Returns
    -------
    Path or None
        The file written; None when matplotlib is missing.
    """
    from irdetect.plot import write_figure

    made = _panels(path, len(panels), width, height)
    if made is None:
        return None
    fig, axes = made
    for ax, panel in zip(axes, panels):
        for s in panel["series"]:
            style = {k: s[k] for k in ("ls", "marker", "color", "mfc", "lw") if k in s}
            style.setdefault("marker", "o")
            ax.plot(s["x"], s["y"], label=s["label"], **style)
        ax.set_xlabel(panel["xlabel"])
        ax.set_ylabel(panel["ylabel"])
        if panel.get("xscale"):
            ax.set_xscale(panel["xscale"])
        if panel.get("yscale"):
            ax.set_yscale(panel["yscale"])
        if panel.get("ylim"):
            ax.set_ylim(*panel["ylim"])
        if panel.get("xticks") is not None:
            ax.set_xticks(panel["xticks"])
        if panel.get("title"):
            ax.set_title(panel["title"], fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    return write_figure(path, fig, force=True)


def save_bars(path, panels, *, title: str | None = None, width: float = 6.0,
              height: float = 4.0) -> Path | None:
    """Write one PNG of grouped bar panels side by side.

    Parameters
    ----------
    path : str or Path
        The PNG to write (replaced when it exists).
    panels : list of dict
        One per panel: ``categories`` (the bar groups' names), ``groups`` (list of dicts
        with ``label`` and ``values``, one value per category), ``ylabel``, optional
        ``title`` and ``yscale``.

    Returns
    -------
    Path or None
        The file written; None when matplotlib is missing.
    """
    import numpy as np

    from irdetect.plot import write_figure

    made = _panels(path, len(panels), width, height)
    if made is None:
        return None
    fig, axes = made
    for ax, panel in zip(axes, panels):
        x = np.arange(len(panel["categories"]))
        n = max(1, len(panel["groups"]))
        bar = 0.8 / n
        for i, group in enumerate(panel["groups"]):
            ax.bar(x - 0.4 + bar * (i + 0.5), group["values"], bar, label=group["label"])
        ax.set_xticks(x, panel["categories"], rotation=30, ha="right")
        ax.set_ylabel(panel["ylabel"])
        if panel.get("yscale"):
            ax.set_yscale(panel["yscale"])
        if panel.get("title"):
            ax.set_title(panel["title"], fontsize=10)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    return write_figure(path, fig, force=True)
