"""The harbour scene of Cheng et al.: small ships near a sea-sky line, with sea clutter.

A 320x240, 25 frames/s maritime sequence: a sky whose grey rises towards a tilted sea-sky
line, a darker sea with drifting wave texture and short-lived sun glints, white noise, and
four ships drawn as soft-edged ellipses (5-30 px, hull grey 100-180):

* T1, T2 moored (still),
* T3 moving slowly right to left and merging with T2 at frame ``merge_frame`` (833) — it
  passes in front of T2 and comes out on the other side,
* T4 fast, left to right, entering the image at frame 162 and leaving it on the right.

Ground truth (``irdetect.tables.TRUTH``) holds each ship's hull centre (x = column,
y = row, pixels; the centroid of the symmetric hull) in every frame the centre is inside the
image; ``amplitude`` is the hull grey. Target ids are 0..3 for T1..T4.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass

import cv2
import numpy as np

from irdetect import tables
from irdetect.config import from_dict
from irdetect.errors import InputError
from irdetect.simulate.presets import MAX_PIXELS, read_preset


@dataclass(frozen=True)
class Ship:
    """One ship: centre x at its start frame, rows below the sea-sky line, speed, hull."""

    name: str = ""
    x: float = 0.0
    below: float = 10.0
    vx: float = 0.0
    length: float = 8.0
    height: float = 3.0
    grey: float = 150.0
    start: int = 0


@dataclass(frozen=True)
class HarbourScenario:
    """Parameters of the harbour scene (``data/presets/harbour.toml``); pixels, frames, grey."""

    height: int = 240
    width: int = 320
    n_frames: int = 1000
    frame_rate: float = 25.0
    horizon_row: float = 70.0        # row of the sea-sky line at the centre column
    horizon_tilt: float = 1.5        # degrees, positive = lower on the right
    sky_top: float = 60.0
    sky_horizon: float = 95.0
    sea_level: float = 55.0
    sea_clutter: float = 5.0         # std of the wave texture (grey levels)
    wave_scale: tuple = (8.0, 1.2)   # Gaussian sigmas (x, y) of the wave texture, px
    wave_drift: float = 0.15         # px/frame, to the right
    noise_sigma: float = 3.0
    glint_rate: float = 12.0         # new glints per frame (Poisson), each lives 1-2 frames
    glint_amplitude: tuple = (80.0, 220.0)
    merge_frame: int = 833           # T3 (ships[2]) touches T2 (ships[1]) at this frame
    ships: tuple = ()

    def horizon(self, x):
        """Row of the sea-sky line at column(s) x."""
        return self.horizon_row + (np.asarray(x, float) - (self.width - 1) / 2) * \
            math.tan(math.radians(self.horizon_tilt))

    def horizon_line(self) -> tuple[float, float]:
        """The true sea-sky line as (rho, theta): rho = x cos(theta) + y sin(theta)."""
        a = math.tan(math.radians(self.horizon_tilt))
        b = self.horizon_row - a * (self.width - 1) / 2
        theta = math.atan2(1.0, -a)
        return b / math.hypot(a, 1.0), theta


def load_harbour(name: str | os.PathLike = "harbour", **overrides) -> HarbourScenario:
    """Read a harbour preset (``data/presets/<name>.toml`` or a TOML path) with overrides."""
    data, path = read_preset(name, "harbour")
    ships = data.pop("ships", [])
    if not isinstance(ships, list):
        raise InputError("ships must be an array of tables", path)
    data.update({k: v for k, v in overrides.items() if v is not None and k != "ships"})
    s = from_dict(HarbourScenario, data, where="harbour", path=path)
    ship_list = tuple(from_dict(Ship, sh, where=f"harbour.ships[{i}]", path=path)
                      for i, sh in enumerate(ships))
    s = dataclasses.replace(s, ships=overrides.get("ships", ship_list))
    # a bad value of an override comes from the options, not the preset
    _validate(s, None if any(v is not None for v in overrides.values()) else path)
    return s


def _validate(s: HarbourScenario, path=None) -> None:
    """Refuse a bad scene; each InputError carries the ``keys`` at fault."""
    for name in ("height", "width", "n_frames"):
        if getattr(s, name) < 1:
            raise InputError(f"{name} must be >= 1, got {getattr(s, name)}", path, keys=(name,))
    if s.width * s.height > MAX_PIXELS:
        raise InputError(f"frames of {s.width}x{s.height} px: at most {MAX_PIXELS:,} px a "
                         "frame (8192x8192)", path, keys=("width", "height"))
    for name in ("noise_sigma", "sea_clutter", "glint_rate"):
        if not getattr(s, name) >= 0:                            # NaN fails too
            raise InputError(f"{name} must be >= 0, got {getattr(s, name)}", path,
                             keys=(name,))
    for i, sh in enumerate(s.ships):
        if sh.length <= 0 or sh.height <= 0:
            raise InputError(f"ships[{i}] needs length and height > 0", path)


def ship_paths(s: HarbourScenario) -> np.ndarray:
    """Per ship (x at frame 0, y, vx, start): T3 placed so its hull touches T2's at merge_frame.

    Returns
    -------
    ndarray of shape (n_ships, 4)
        x0 (column at frame 0, extrapolated back for late ships), y (row), vx (px/frame),
        start frame.
    """
    out = np.zeros((len(s.ships), 4))
    for j, sh in enumerate(s.ships):
        x_start = sh.x
        if j == 2 and len(s.ships) > 2 and s.merge_frame >= 0:      # T3 meets T2
            t2 = s.ships[1]
            gap = (t2.length + sh.length) / 2 + 2.5     # soft edges join ~2 px early
            side = 1.0 if sh.vx < 0 else -1.0
            x_start = t2.x + side * gap - sh.vx * (s.merge_frame - sh.start)
        y = float(s.horizon(x_start)) + sh.below
        if j == 2 and len(s.ships) > 2:
            y = float(s.horizon(s.ships[1].x)) + s.ships[1].below + 1.0
        out[j] = x_start - sh.vx * sh.start, y, sh.vx, sh.start
    return out


def harbour_truth(s: HarbourScenario, paths: np.ndarray | None = None) -> np.ndarray:
    """TRUTH rows: every ship in every frame from its start with its centre inside the image."""
    paths = ship_paths(s) if paths is None else paths
    f = np.repeat(np.arange(s.n_frames), len(paths))
    j = np.tile(np.arange(len(paths)), s.n_frames)
    x = paths[j, 0] + paths[j, 2] * f
    y = paths[j, 1] + np.zeros(len(f))
    ok = (f >= paths[j, 3]) & (x >= 0) & (x <= s.width - 1) & (y >= 0) & (y <= s.height - 1)
    grey = np.array([sh.grey for sh in s.ships])[j] if len(paths) else np.zeros(0)
    return tables.from_columns(tables.TRUTH, frame=f[ok], target=j[ok], x=x[ok], y=y[ok],
                               amplitude=grey[ok])


def harbour_blocks(s: HarbourScenario | str = "harbour", rng=None, *, block: int = 128,
                   **overrides):
    """Generate the harbour frames (uint8) block by block, with the truth.

    Returns
    -------
    blocks : iterator of ndarray of shape (<= block, H, W), uint8
    truth : structured ndarray (``tables.TRUTH``)
    """
    if isinstance(s, HarbourScenario):
        s = dataclasses.replace(s, **overrides)
        _validate(s)
    else:
        s = load_harbour(s, **overrides)
    rng = np.random.default_rng(rng)
    paths = ship_paths(s)
    truth = harbour_truth(s, paths)
    h, w = s.height, s.width
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    hz = s.horizon(xx[0]).astype(np.float32)[None, :]
    sea = np.clip(yy - hz + 0.5, 0, 1)                               # 1 below the line
    depth = np.clip((hz - yy) / max(float(hz.mean()), 1.0), 0, 1)    # 0 at the line, 1 at top
    static = (1 - sea) * (s.sky_horizon + (s.sky_top - s.sky_horizon) * depth) \
        + sea * s.sea_level
    pad = int(math.ceil(abs(s.wave_drift) * s.n_frames)) + 8
    waves = cv2.GaussianBlur(rng.standard_normal((h + 16, w + 2 * pad)).astype(np.float32),
                             (0, 0), sigmaX=s.wave_scale[0], sigmaY=s.wave_scale[1])
    waves *= s.sea_clutter / max(float(waves.std()), 1e-12)
    # perspective: waves are stronger (nearer) towards the bottom of the image
    wave_gain = (sea * (0.5 + 0.5 * np.clip((yy - hz) / max(h - float(hz.mean()), 1.0), 0, 1)))
    ships = list(zip(paths, s.ships))
    sea_rows = np.flatnonzero(hz.min() + 3 < np.arange(h))

    def glints(n_new):
        xs = rng.uniform(0, w - 1, n_new)
        ys = rng.uniform(sea_rows[0] if len(sea_rows) else 0, h - 1, n_new)
        amp = rng.uniform(*s.glint_amplitude, n_new)
        life = rng.integers(1, 3, n_new)
        return np.column_stack([xs, ys, amp, life])

    live = np.zeros((0, 4))

    def render():
        nonlocal live
        for start in range(0, s.n_frames, block):
            n = min(block, s.n_frames - start)
            out = rng.standard_normal((n, h, w), dtype=np.float32) * s.noise_sigma
            for i in range(n):
                t = start + i
                frame = out[i]
                off = pad + s.wave_drift * t
                wave = cv2.getRectSubPix(waves, (w, h), (off + (w - 1) / 2, 8 + (h - 1) / 2))
                frame += static + wave_gain * wave
                live = np.vstack([live[live[:, 3] > 0], glints(rng.poisson(s.glint_rate))])
                _add_glints(frame, live)
                live[:, 3] -= 1
                for (x0, y, vx, first), sh in ships:
                    if t >= first:
                        _draw_ship(frame, x0 + vx * t, y, sh, rng)
            yield np.clip(np.rint(out), 0, 255).astype(np.uint8)

    return render(), truth


def _add_glints(frame: np.ndarray, live: np.ndarray) -> None:
    if not len(live):
        return
    h, w = frame.shape
    imp = np.zeros_like(frame)
    c = np.clip(np.rint(live[:, 0]).astype(int), 0, w - 1)
    r = np.clip(np.rint(live[:, 1]).astype(int), 0, h - 1)
    np.add.at(imp, (r, c), live[:, 2].astype(np.float32))
    frame += cv2.GaussianBlur(imp, (0, 0), 0.6)


def _draw_ship(frame: np.ndarray, x: float, y: float, ship: Ship, rng) -> None:
    """Blend a soft-edged elliptical hull of grey ``ship.grey`` (with 2 % flicker)."""
    h, w = frame.shape
    a, b = ship.length / 2, ship.height / 2
    c0, c1 = max(0, int(math.floor(x - a - 2))), min(w, int(math.ceil(x + a + 3)))
    r0, r1 = max(0, int(math.floor(y - b - 2))), min(h, int(math.ceil(y + b + 3)))
    if c0 >= c1 or r0 >= r1:
        return
    cols = np.arange(c0, c1, dtype=np.float32)[None, :] - x
    rows = np.arange(r0, r1, dtype=np.float32)[:, None] - y
    rr = np.sqrt((cols / a) ** 2 + (rows / b) ** 2)
    alpha = np.clip(0.5 - (rr - 1) * b, 0, 1)                   # ~1 px soft edge
    grey = ship.grey * (1 + 0.02 * rng.standard_normal())
    patch = frame[r0:r1, c0:c1]
    patch += alpha * (grey - patch)


def simulate_harbour(scenario: HarbourScenario | str = "harbour", *, rng=None, **overrides):
    """Simulate the whole harbour sequence in memory.

    Parameters
    ----------
    scenario : HarbourScenario or str
        A scenario or a preset name / TOML path (default ``data/presets/harbour.toml``).
    rng : numpy.random.Generator or int or None
        Random source for clutter, glints and noise (the ship paths are deterministic).
    **overrides
        Scenario fields to replace, e.g. ``n_frames=200``.

    Returns
    -------
    frames : ndarray of shape (T, H, W), uint8
    truth : structured ndarray (``tables.TRUTH``), target ids 0..3 = T1..T4

    Examples
    --------
    >>> frames, truth = simulate_harbour(n_frames=10, rng=0)
    >>> frames.shape
    (10, 240, 320)
    """
    blocks, truth = harbour_blocks(scenario, rng, **overrides)
    return np.concatenate(list(blocks)), truth
