"""Configuration: one frozen dataclass per stage, TOML in, resolved JSON out.

Each stage's dataclass mirrors the keyword parameters of the stage's public function
(``tests/test_config.py`` checks that they match). A TOML file holds one table per
stage, e.g.::

    [combine]
    length = 12

    [detect]
    k = 4.0

Unknown tables or keys are an error. The resolved configuration (every value, defaults
included) is stored as JSON in the ``config`` attribute of every results file.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
import typing
from dataclasses import dataclass, field

from irdetect.errors import InputError, check_input_file
from irdetect.gain import STEP


# --- detection front end (wan2008; issue 3) -------------------------------------------

@dataclass(frozen=True)
class SuppressConfig:
    """Clutter suppression (``irdetect.suppress.suppress``)."""

    method: str = "auto"
    size: int = 9
    guard: int = 1
    history: int = 12
    gap: int = 8
    tolerance: int = 1
    fixed_pattern: bool = True
    samples: int = 3
    lead_in: str = "future"
    #: "bright": targets brighter than their background (white-hot); "dark": darker
    #: (a black-hot recording, a cold target): the frames are mirrored in grey level
    polarity: str = "bright"
    #: the first frames of this many earlier windows are the long-memory background of
    #: a still camera (``suppress(long_past=)``: a target that stops stays detected;
    #: 0: off, the default: docs/detection.md says what it costs the tracks)
    long_memory: int = 0
    #: a frame whose gain departs by more than this fraction from the frame before it
    #: is a step of the camera's gain control, and the frames after it are taken back
    #: to frame 0's gain and level before suppression (``irdetect.gain``); 0: off
    gain_step: float = STEP
    #: pixels per side of the blocks each frame is averaged over before everything else
    #: (``irdetect.binning``): footage sampled finer than its detail (an analog video
    #: digitised at twice its sensor's resolution) takes 2; results stay in the input's
    #: pixels. 1: none
    bin: int = 1


@dataclass(frozen=True)
class CombineConfig:
    """Combined frames (``irdetect.combine.combine``)."""

    length: int = 12
    step: int = 12
    #: one more combined frame over the sequence's last ``length`` frames when the
    #: windows every ``step`` frames leave frames after them (``combine.window_starts``;
    #: confirmed as the last of a triple with the two windows before it, unevenly
    #: spaced, ``correlate``'s ``gap``); false: the paper's windows alone, the last
    #: frames unexamined
    tail: bool = True
    projection: str = "dp"
    dp_radius: int = 1
    dp_decay: float = 0.95
    dp_smooth: float = 0.6


@dataclass(frozen=True)
class DetectConfig:
    """Directional threshold detection (``irdetect.detect.detect``)."""

    window: int = 3
    k: float = 2.5
    sigma: str = "local"
    tile: int = 32
    smooth: float = 0.0
    directions: int = 4
    sample: int = 2


@dataclass(frozen=True)
class FuseConfig:
    """Groups and probability-weighted fusion (``irdetect.fuse.fuse``)."""

    gap: int = 1
    d_min: float = 0.5
    min_members: int = 1
    peak_radius: int = 5
    extent: float = 0.0


@dataclass(frozen=True)
class CorrelateConfig:
    """Bidirectional 3-frame correlation (``irdetect.correlate.correlate``)."""

    max_speed: float = 2.0
    tolerance: float = 5.0
    constant_velocity: bool = True
    max_deviation: float = 20.0
    resolve: str = "cost"
    min_score: float = 3.5
    verify: float = 6.5
    verify_local: float = 3.5
    screen: float = 0.4
    chains_per_point: int = 0


@dataclass(frozen=True)
class FastConfig:
    """The fast band (beyond the paper; docs/detection.md): a second ``dp`` merit per
    window that follows the camera's motion with a wide radius, a point test on it, and
    chains in scene coordinates, for targets up to ``radius`` px/frame against the scene
    (``irdetect.pipeline``). ``radius = 0`` turns it off (the paper's single band).
    ``scene``: with it, the paper's band once more in scene coordinates (band 2: its
    narrow merit following the camera, its detection and chains), for targets slow
    against the scene under a camera that moves; windows whose camera moves less than half
    a pixel per frame on average skip it."""

    radius: int = 6
    k: float = 3.5
    sigma: str = "global"
    extent: float = 2.0
    max_deviation: float = 20.0
    scene: bool = True


@dataclass(frozen=True)
class FrameConfig:
    """The per-frame path (beyond the papers; docs/detection.md, "The per-frame path"):
    each frame's CFAR peaks (``irdetect.peaks``) initiated like radar scans in scene
    coordinates (``irdetect.pipeline.perframe.frame_tracks``), fused with the
    combined-frame path's detections (``irdetect.pipeline.fusion``). ``enabled = false``
    runs the combined-frame path alone (the paper's design)."""

    enabled: bool = True
    false_rate: float = 1.0
    sigma: float = 1.0
    max_speed: float = 16.0
    false_tracks: float = 0.001
    confirm_m: int = 3
    confirm_n: int = 4
    clutter_speed: float = 1.5


@dataclass(frozen=True)
class OperatingConfig:
    """The combined-frame path's operating point (beyond the papers; docs/detection.md,
    "Operating point"): a verified detection is kept when its significance on its
    window's integrated map reaches the level the map's own clutter reaches
    ``false_rate`` times per frame of the window (``irdetect.operating.map_threshold``).
    ``false_rate = 0`` keeps every verified chain (the paper's design)."""

    false_rate: float = 0.1


# --- track initiation (zhang2010, liang2015; issues 4, 5) -----------------------------

@dataclass(frozen=True)
class InitiateConfig:
    """Track initiation on the confirmed detections (``irdetect.initiate.initiate_detections``;
    docs/initiation.md). Units: pixels, frames."""

    method: str = "hough-sc"
    n_theta: int = 90
    rho_step: float = 2.0
    tile: float = 0.0
    vote_fraction: float = 0.6
    vote_band: float = 1.0
    parallel_fraction: float = 0.8
    q1: float = 0.25
    q2: float = 0.65
    sigma: float = 1.5
    sigma_range: float = 0.0
    sigma_azimuth: float = 0.0
    radius_rho: float = 3.0
    radius_theta: float = 4.0
    squash: float = 1.25
    accept_ratio: float = 0.5
    reject_ratio: float = 0.15
    merge_peaks: bool = False
    nms_size: int = 5
    verify: bool = True
    gate: float = 3.0
    v_min: float = 0.0
    v_max: float = 0.0
    min_hits: float = 0.5
    confirm_m: int = 3
    confirm_n: int = 4
    fit_confidence: float = 0.99
    false_tracks: float = 0.0
    window: int = 10


# --- frame-by-frame tracker (cheng; issue 6) -------------------------------------------

@dataclass(frozen=True)
class TrackConfig:
    """Frame-by-frame FCM + adaptive PMHT tracker (``irdetect.track.track``)."""

    method: str = "fcm-pmht"
    regions: str = "detector"
    false_rate: float = 1.0
    psf: float = 1.0
    fraction: float = 0.5
    false_tracks: float = 0.001
    sigma: float = 1.0
    max_speed: float = 16.0
    learn_frames: int = 12
    motion_p: float = 0.001
    clutter_speed: float = 1.5
    guided_rate: float = 0.01
    min_shape: float = 0.35
    three_point: bool = True
    sea_sky: bool = False
    band_above: float = 5.0
    band_below: float = 40.0
    suppress_size: int = 15
    k: float = 5.0
    smooth: float = 1.0
    tile: int = 32
    min_contrast: float = 0.0
    min_area: float = 1.0
    max_area: float = 200.0
    grey_gate: bool = False
    min_grey: float = 100.0
    max_grey: float = 180.0
    max_regions: int = 200
    frame_interval: float = 1.0
    q0: float = 0.001
    r: float = 0.5
    adaptive: bool = True
    beta: float = 0.9
    m: float = 2.0
    gate: float = 4.0
    w_position: float = 1.0
    w_grey: float = 1.0
    w_area: float = 1.0
    w_direction: float = 1.0
    grey_scale: float = 4.5
    area_scale: float = 0.5
    direction_after: int = 3
    min_speed: float = 0.2
    confirm_hits: int = 3
    confirm_window: int = 30
    max_misses: int = 12
    max_merged: int = 150
    merge_margin: float = 1.0
    max_tracks: int = 200
    init_speed: float = 2.0
    feature_memory: float = 0.9
    lost_clutter: float = 1.0
    window: int = 64


# --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ProcessConfig:
    """Everything ``irdetect process`` needs, one field per stage."""

    suppress: SuppressConfig = field(default_factory=SuppressConfig)
    combine: CombineConfig = field(default_factory=CombineConfig)
    detect: DetectConfig = field(default_factory=DetectConfig)
    fuse: FuseConfig = field(default_factory=FuseConfig)
    correlate: CorrelateConfig = field(default_factory=CorrelateConfig)
    fast: FastConfig = field(default_factory=FastConfig)
    frame: FrameConfig = field(default_factory=FrameConfig)
    operating: OperatingConfig = field(default_factory=OperatingConfig)
    initiate: InitiateConfig = field(default_factory=InitiateConfig)
    track: TrackConfig = field(default_factory=TrackConfig)
    #: pixels where nothing is reported (``irdetect.exclude``: rectangles "X0,Y0,X1,Y1"
    #: or mask images; a burned-in overlay): process and track
    exclude: tuple = ()


def from_dict(cls, data: dict, *, where: str = "config", path=None):
    """Build dataclass ``cls`` from a nested dict, rejecting unknown keys.

    Nested dataclass fields take nested dicts. Values are checked against the field's
    type (int, float, str, bool) so a typo in a TOML file fails early with its name.
    """
    if not isinstance(data, dict):
        raise InputError(f"{where} must be a table, got {type(data).__name__}", path)
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise InputError(f"unknown config key {where}.{unknown[0]} "
                         f"(known: {', '.join(sorted(names)) or 'none'})", path)
    kwargs = {}
    for name, value in data.items():
        kind = hints[name]
        if dataclasses.is_dataclass(kind):
            kwargs[name] = from_dict(kind, value, where=f"{where}.{name}", path=path)
        else:
            kwargs[name] = _check_value(kind, value, f"{where}.{name}", path)
    return cls(**kwargs)


def _check_value(kind, value, where, path):
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind in (int, float, str, bool) and not (isinstance(value, kind)
                                                and not (kind is int and isinstance(value, bool))):
        raise InputError(f"{where} must be {kind.__name__}, got {value!r}", path)
    if kind is tuple or typing.get_origin(kind) is tuple:
        if not isinstance(value, (list, tuple)):
            raise InputError(f"{where} must be a list, got {value!r}", path)
        return tuple(value)
    return value


def read_toml(path: str | os.PathLike) -> dict:
    """A TOML file as a dict; a missing or invalid file is an InputError naming it."""
    check_input_file(path, "TOML file")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not a valid TOML file ({exc})", path) from None


def load_config(path: str | os.PathLike | None, cls=ProcessConfig, overrides: dict | None = None):
    """Read a TOML config file into ``cls``; ``None`` gives the defaults.

    ``overrides`` is a nested dict applied on top of the file (command-line options).
    """
    data = merge_tables({} if path is None else read_toml(path), overrides or {})
    return from_dict(cls, data, path=path)


def merge_tables(base: dict, top: dict) -> dict:
    """``base`` with ``top`` on top: a table (dict) of ``top`` updates the same table of
    ``base`` key by key, any other value replaces it. ``base`` is updated and returned."""
    for key, value in top.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            base[key] = {**base[key], **value}
        else:
            base[key] = value
    return base


def to_json(config) -> str:
    """The resolved configuration as a JSON string (stored in results files)."""
    return json.dumps(dataclasses.asdict(config), sort_keys=True)
