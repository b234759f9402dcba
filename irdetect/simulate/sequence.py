"""Synthetic infrared sequences of dim point targets with ground truth.

Model (``docs/simulator.md``): every frame is

    Z(x, y, t) = background + clutter(x, y, t) + sum_j S_j(x, y, t) + N(x, y, t)

with N i.i.d. Gaussian of standard deviation ``noise_sigma``, and each target a Gaussian
point-spread function sampled at pixel centres,

    S_j(x, y, t) = A_j exp(-((x - x_j(t))^2 + (y - y_j(t))^2) / (2 psf_sigma^2)),

of peak amplitude A_j = snr * noise_sigma (peak SNR; in dB 20 log10 snr) at a sub-pixel
position moving at constant velocity. ``psf_sigma = 0.6`` puts 99 % of the sampled energy in 3x3 px.
Structured clutter is optional: a smooth cloud-like field drifting slowly, a bright
tilted horizon edge and hot pixels. Coordinates: x = column, y = row, pixels.
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

_DTYPES = {"uint8": (np.uint8, 255.0), "uint16": (np.uint16, 65535.0), "float32": (np.float32, None)}


@dataclass(frozen=True)
class SequenceScenario:
    """Parameters of a simulated IR sequence (one TOML preset in ``data/presets``).

    Sizes are pixels, speeds pixels per frame, angles degrees (0 = +x, 90 = +y, i.e. down
    the image), grey levels in the units of ``dtype``.
    """

    height: int = 240
    width: int = 320
    n_frames: int = 48
    dtype: str = "uint8"
    frame_rate: float = 25.0
    background: float = 60.0
    noise_sigma: float = 4.0
    # targets
    n_targets: int = 5
    snr: float = 3.0
    psf_sigma: float = 0.6
    speed: tuple = (1.0, 1.0)
    directions: tuple = ()          # degrees, one per target; empty = uniform at random
    margin: float = 8.0             # px kept between every target path and the border
    stop_frame: int = 0             # the targets stop in the scene at this frame and hover
                                    # there (0: they never stop)
    # structured clutter
    cloud_amplitude: float = 0.0    # peak-to-peak grey levels of the cloud field
    cloud_scale: float = 24.0       # px, correlation length of the cloud field
    cloud_drift: tuple = (0.0, 0.0)  # px/frame (vx, vy) of the cloud field
    horizon_amplitude: float = 0.0  # grey step across the horizon (ground brighter)
    horizon_row: float = 0.6        # fraction of the height where the horizon crosses x = 0
    horizon_tilt: float = 3.0       # degrees
    hot_pixels: int = 0
    hot_pixel_amplitude: float = 40.0
    # the camera: the scene (background, clutter, targets) moves in the image by
    # camera_pan px/frame plus a random offset of up to camera_jitter px per frame and
    # axis; the sensor's hot pixels stay put in the image
    camera_pan: tuple = (0.0, 0.0)
    camera_jitter: float = 0.0
    # the camera's gain control: the gain switches between 1 and 1 + agc_step every
    # agc_period frames (from frame agc_period on), about the background level, before
    # the frames are rounded and clipped to the dtype (0: a fixed gain)
    agc_step: float = 0.0
    agc_period: int = 20



def load_scenario(name: str | os.PathLike = "wan2008", **overrides) -> SequenceScenario:
    """Read a preset from ``data/presets/<name>.toml`` (or a TOML path) with overrides.

    A new ``n_targets`` without ``directions`` takes the first ``n_targets`` of the
    preset's directions, or random ones when the preset has fewer.

    Raises
    ------
    InputError
        Unknown preset, unreadable TOML, unknown key or value of the wrong type.
    """
    data, path = read_preset(name, "sequence")
    _validate(from_dict(SequenceScenario, data, where="scenario", path=path), path)
    given = {k: v for k, v in overrides.items() if v is not None}
    preset_dirs = list(data.get("directions", ()))
    if "n_targets" in given and "directions" not in given and preset_dirs:
        # the preset's directions are for its own targets: the first n of them, or all at
        # random when more targets are asked for (--targets 3 on wan2008 failed)
        n = int(given["n_targets"])
        given["directions"] = preset_dirs[:n] if n <= len(preset_dirs) else []
    scenario = from_dict(SequenceScenario, {**data, **given}, where="scenario", path=path)
    if given:
        _validate(scenario, None)   # a bad value comes from the options, not the preset
    return scenario


def _validate(s: SequenceScenario, path=None) -> None:
    """Refuse a bad scenario; each InputError carries the ``keys`` at fault, so the
    command names the options that set them."""
    if s.dtype not in _DTYPES:
        raise InputError(f"dtype must be one of {', '.join(_DTYPES)}, got {s.dtype!r}", path,
                         keys=("dtype",))
    for name in ("height", "width", "n_frames"):
        if getattr(s, name) < 1:
            raise InputError(f"{name} must be >= 1, got {getattr(s, name)}", path, keys=(name,))
    if s.width * s.height > MAX_PIXELS:
        raise InputError(f"frames of {s.width}x{s.height} px: at most {MAX_PIXELS:,} px a "
                         "frame (8192x8192)", path, keys=("width", "height"))
    for name in ("noise_sigma", "psf_sigma", "snr", "speed", "directions"):
        value = getattr(s, name)
        if not all(math.isfinite(v) for v in np.ravel(value)):
            raise InputError(f"{name} must hold finite numbers, got {value}", path,
                             keys=(name,))
    for name, low, strict in (("noise_sigma", 0, False), ("snr", 0, False),
                              ("n_targets", 0, False), ("psf_sigma", 0, True)):
        value = getattr(s, name)
        if value < low or (strict and value == low):
            raise InputError(f"{name} must be {'>' if strict else '>='} {low}, got {value}",
                             path, keys=(name,))
    if len(s.speed) != 2 or not 0 <= s.speed[0] <= s.speed[1]:
        raise InputError(f"speed must be [min, max] with 0 <= min <= max, got {s.speed}", path,
                         keys=("speed",))
    if s.stop_frame < 0:
        raise InputError(f"stop_frame must be >= 0, got {s.stop_frame}", path,
                         keys=("stop_frame",))
    if s.directions and len(s.directions) != s.n_targets:
        raise InputError(f"directions has {len(s.directions)} angles for {s.n_targets} "
                         "targets", path, keys=("directions", "n_targets"))
    if len(s.camera_pan) != 2 or not all(math.isfinite(v) for v in s.camera_pan):
        raise InputError(f"camera_pan must be [vx, vy] px/frame, got {s.camera_pan}", path,
                         keys=("camera_pan",))
    if not (math.isfinite(s.camera_jitter) and s.camera_jitter >= 0):
        raise InputError(f"camera_jitter must be a number >= 0, got {s.camera_jitter}", path,
                         keys=("camera_jitter",))
    if not (math.isfinite(s.agc_step) and s.agc_step > -1):
        raise InputError(f"agc_step must be a number > -1, got {s.agc_step}", path,
                         keys=("agc_step",))
    if s.agc_period < 1:
        raise InputError(f"agc_period must be >= 1, got {s.agc_period}", path,
                         keys=("agc_period",))
    pan = math.hypot(*s.camera_pan)
    span = (max(s.speed) + pan) * (s.n_frames - 1)
    if s.n_targets and min(s.width, s.height) - 2 * s.margin <= 0:
        raise InputError(f"frames of {s.width}x{s.height} leave no room inside the "
                         f"{s.margin:g}-px margin", path, keys=("width", "height", "margin"))
    if s.n_targets and span > 2 * max(s.width, s.height):
        moving = f"{max(s.speed):g} px/frame" + (f" and a camera pan of {pan:g} px/frame"
                                                 if pan else "")
        raise InputError(f"targets at {moving} leave the {s.width}x{s.height} frame long "
                         f"before frame {s.n_frames}", path,
                         keys=("speed", "camera_pan", "n_frames", "width", "height"))


def target_paths(s: SequenceScenario, rng: np.random.Generator) -> np.ndarray:
    """Draw start positions and velocities that keep each path inside the frame, or,
    on an axis it is longer than the frame, cross it whole.

    Returns
    -------
    ndarray of shape (n_targets, 4)
        Rows (x0, y0, vx, vy): position at frame 0 (x = column, y = row) and px/frame in
        the image (the target's speed in the scene plus ``camera_pan``; the camera's
        jitter comes on top, ``camera_offsets``).
    """
    out = np.zeros((s.n_targets, 4))
    for j in range(s.n_targets):
        speed = rng.uniform(*s.speed)
        angle = math.radians(s.directions[j]) if s.directions else rng.uniform(0, 2 * math.pi)
        vx = speed * math.cos(angle) + s.camera_pan[0]
        vy = speed * math.sin(angle) + s.camera_pan[1]
        dx, dy = vx * (s.n_frames - 1), vy * (s.n_frames - 1)
        lo_x, hi_x = s.margin - min(dx, 0), s.width - 1 - s.margin - max(dx, 0)
        lo_y, hi_y = s.margin - min(dy, 0), s.height - 1 - s.margin - max(dy, 0)
        # an axis the path is longer than the frame on (lo > hi): every start between
        # the two bounds crosses the whole frame along it during the sequence; u says
        # when (0 as early as it can, 1 as late), one u for both axes so that the two
        # crossings overlap (all such paths through the centre at mid-sequence made every
        # target of a scene meet there)
        u = rng.uniform() if lo_x > hi_x or lo_y > hi_y else 0.0
        out[j] = (_start(lo_x, hi_x, dx, u, rng), _start(lo_y, hi_y, dy, u, rng), vx, vy)
    return out


def _start(lo: float, hi: float, d: float, u: float, rng: np.random.Generator) -> float:
    """A start coordinate in [lo, hi] (a path of length d inside the frame), or, when
    lo > hi (a path longer than the frame), the one that crosses it at time fraction u."""
    if lo <= hi:
        return rng.uniform(lo, hi)
    early, late = (lo, hi) if d > 0 else (hi, lo)
    return early + u * (late - early)


def camera_offsets(s: SequenceScenario, rng: np.random.Generator) -> np.ndarray:
    """The camera's image offsets (T, 2): a scene point at p in frame 0 is at p + C_t in
    frame t (``camera_pan`` t plus a uniform jitter of +-``camera_jitter`` px per axis,
    relative to frame 0's)."""
    t = np.arange(s.n_frames, dtype=float)[:, None]
    c = t * np.asarray(s.camera_pan, float)[None, :]
    if s.camera_jitter > 0:
        jit = rng.uniform(-s.camera_jitter, s.camera_jitter, (s.n_frames, 2))
        c += jit - jit[0]
    return c


def truth_table(s: SequenceScenario, paths: np.ndarray,
                camera: np.ndarray | None = None) -> np.ndarray:
    """Ground truth rows (``tables.TRUTH``) for every target in every frame it is inside
    (image positions: ``paths`` plus the camera's jitter, ``camera`` minus its pan; from
    ``stop_frame`` on a target moves with the pan alone)."""
    frames = np.arange(s.n_frames)
    n = len(paths)
    f = np.repeat(frames, n)
    j = np.tile(np.arange(n), s.n_frames)
    moved = np.minimum(f, s.stop_frame) if s.stop_frame else f     # frames of own motion
    pan_x, pan_y = s.camera_pan
    x = paths[j, 0] + (paths[j, 2] - pan_x) * moved + pan_x * f
    y = paths[j, 1] + (paths[j, 3] - pan_y) * moved + pan_y * f
    if camera is not None:
        jx, jy = (camera - frames[:, None] * np.asarray(s.camera_pan, float)).T
        x, y = x + jx[f], y + jy[f]
    inside = (x >= 0) & (x <= s.width - 1) & (y >= 0) & (y <= s.height - 1)
    return tables.from_columns(tables.TRUTH, frame=f[inside], target=j[inside], x=x[inside],
                               y=y[inside], amplitude=np.full(inside.sum(), s.snr * s.noise_sigma))


def _static_clutter(s: SequenceScenario, rng: np.random.Generator,
                    pad: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(scene, sensor): the background and horizon over the frame padded by ``pad`` px
    on every side (the scene the camera moves over), and the hot pixels (frame-sized)."""
    h, w = s.height + 2 * pad, s.width + 2 * pad
    field = np.full((h, w), s.background, np.float32)
    if s.horizon_amplitude:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32) - pad
        edge = s.horizon_row * s.height + xx * math.tan(math.radians(s.horizon_tilt))
        field += s.horizon_amplitude * 0.5 * (1 + np.tanh((yy - edge) / 1.6))  # logistic, 0.8 px
    sensor = np.zeros((s.height, s.width), np.float32)
    if s.hot_pixels:
        idx = rng.choice(s.height * s.width, size=min(s.hot_pixels, s.height * s.width),
                         replace=False)
        sensor.reshape(-1)[idx] += s.hot_pixel_amplitude
    return field, sensor


def _cloud_field(s: SequenceScenario, rng: np.random.Generator,
                 camera_pad: int = 0) -> tuple[np.ndarray, int]:
    """A smooth random field of peak-to-peak ``cloud_amplitude``, padded for the drift
    and the camera's motion."""
    pad = int(math.ceil(max(abs(v) for v in s.cloud_drift) * s.n_frames)) + 2 + camera_pad
    h, w = s.height + 2 * pad, s.width + 2 * pad
    field = np.zeros((h, w), np.float32)
    for octave in range(3):  # three octaves: cloud banks with softer detail inside
        scale = s.cloud_scale / 2 ** octave
        noise = rng.standard_normal((h, w)).astype(np.float32)
        layer = cv2.GaussianBlur(noise, (0, 0), scale)
        field += (layer / (layer.std() + 1e-12)) / 2 ** octave
    field -= field.min()
    field *= s.cloud_amplitude / max(float(field.max()), 1e-12)
    return field, pad


def simulate_blocks(s: SequenceScenario, rng=None, *, block: int = 256):
    """Generate a scenario's frames block by block, with its truth.

    Returns
    -------
    blocks : iterator of ndarray of shape (<= block, H, W)
        The frames in ``s.dtype``; memory holds one block at a time.
    truth : structured ndarray
        ``tables.TRUTH`` for the whole sequence.
    """
    rng = np.random.default_rng(rng)
    paths = target_paths(s, rng)
    moving = s.camera_jitter > 0 or any(s.camera_pan)
    camera = camera_offsets(s, rng) if moving else None
    truth = truth_table(s, paths, camera)
    # the scene is drawn padded by the camera's largest offset and sampled per frame
    pad = int(math.ceil(np.abs(camera).max())) + 2 if moving else 0
    scene, sensor = _static_clutter(s, rng, pad)
    cloud = _cloud_field(s, rng, pad) if s.cloud_amplitude else None
    amp = s.snr * s.noise_sigma
    half = int(math.ceil(4 * s.psf_sigma))

    def render():
        for start in range(0, s.n_frames, block):
            n = min(block, s.n_frames - start)
            out = rng.standard_normal((n, s.height, s.width), dtype=np.float32)
            out *= s.noise_sigma
            out += sensor
            for i in range(n):
                t = start + i
                cx, cy = (camera[t] if moving else (0.0, 0.0))
                if moving:
                    # the scene point at p is at p + C_t in the image
                    out[i] += cv2.getRectSubPix(scene, (s.width, s.height),
                                                (pad + (s.width - 1) / 2 - cx,
                                                 pad + (s.height - 1) / 2 - cy))
                else:
                    out[i] += scene
                if cloud is not None:
                    field, cpad = cloud
                    fx = cpad + s.cloud_drift[0] * t + (s.width - 1) / 2 - cx
                    fy = cpad + s.cloud_drift[1] * t + (s.height - 1) / 2 - cy
                    out[i] += cv2.getRectSubPix(field, (s.width, s.height), (fx, fy))
                rows = truth[truth["frame"] == t]
                for x, y in zip(rows["x"], rows["y"]):
                    _add_psf(out[i], x, y, amp, s.psf_sigma, half)
                if s.agc_step and (t // s.agc_period) % 2:
                    out[i] -= s.background
                    out[i] *= 1.0 + s.agc_step
                    out[i] += s.background
            yield _to_dtype(out, s.dtype)

    return render(), truth


def _add_psf(frame: np.ndarray, x: float, y: float, amp: float, sigma: float, half: int) -> None:
    h, w = frame.shape
    c0, r0 = int(round(x)) - half, int(round(y)) - half
    c1, r1 = min(w, c0 + 2 * half + 1), min(h, r0 + 2 * half + 1)
    c0, r0 = max(0, c0), max(0, r0)
    if c0 >= c1 or r0 >= r1:
        return
    gx = np.exp(-((np.arange(c0, c1) - x) ** 2) / (2 * sigma ** 2))
    gy = np.exp(-((np.arange(r0, r1) - y) ** 2) / (2 * sigma ** 2))
    frame[r0:r1, c0:c1] += amp * np.outer(gy, gx).astype(np.float32)


def _to_dtype(frames: np.ndarray, dtype: str) -> np.ndarray:
    kind, top = _DTYPES[dtype]
    if top is None:
        return frames.astype(kind)
    return np.clip(np.rint(frames), 0, top).astype(kind)


def simulate(scenario: str | SequenceScenario = "wan2008", *, rng=None, **overrides):
    """Simulate a whole IR sequence in memory.

    Parameters
    ----------
    scenario : str or SequenceScenario
        A preset name from ``data/presets`` (e.g. ``"wan2008"``, ``"clutter"``), a TOML
        path, or a scenario object.
    rng : numpy.random.Generator or int or None
        Random source (seed) for paths, clutter and noise.
    **overrides
        Scenario fields to replace, e.g. ``snr=2.0, n_frames=120``.

    Returns
    -------
    frames : ndarray of shape (T, H, W)
        In the scenario's dtype.
    truth : structured ndarray
        ``irdetect.tables.TRUTH``: frame, target, x (column), y (row), amplitude.

    Examples
    --------
    >>> frames, truth = simulate("wan2008", snr=4, rng=1)
    >>> frames.shape
    (48, 240, 320)
    >>> sorted(set(truth["target"]))
    [0, 1, 2, 3, 4]
    """
    if isinstance(scenario, SequenceScenario):
        s = dataclasses.replace(scenario, **overrides)
        _validate(s)
    else:
        s = load_scenario(scenario, **overrides)
    blocks, truth = simulate_blocks(s, rng)
    return np.concatenate(list(blocks)), truth
