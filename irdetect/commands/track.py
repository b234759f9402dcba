"""Track small (possibly extended) targets frame by frame through a whole sequence.

Candidate regions of every frame (by default the per-frame detector of process: the
suppressed residual with the camera's motion, the PSF's matched filter, CFAR peaks on the
local noise and each peak's half-maximum region, less those shaped like lines, and a
confirmed track's gate searched again at a lower level; the maritime and paper profiles: a
top-hat, a CFAR threshold, connected components, optionally only near the sea-sky line)
are associated to the tracks by fuzzy c-means memberships and followed by a
constant-velocity filter with adaptive process noise (Cheng et al.; docs/tracking.md), or
by the CV Kalman + GNN baseline (--method gnn). A track starts from a region no track
takes, or (the default profile) from three on a line in three frames: a target too fast
for a new track's gate.
Writes /track_points (one row per track per frame, image coordinates), /tracks (one row
per track) and, with the detector's regions, /camera (the camera's offset of every frame
that the tracks' scene coordinates took: held where the image-fixed background was taken
although the offsets moved; tracks are followed in scene coordinates).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from irdetect.commands import (DATASET_HELP, SEQUENCE_KINDS, add_input_options,
                               flat_frames, with_input_options)
from irdetect.config import to_json
from irdetect.profiles import load_profile
from irdetect.errors import InputError, refused_settings
from irdetect.io import ResultsWriter, check_output_path, open_sequence

log = logging.getLogger(__name__)


def add_arguments(p):
    p.add_argument("input", help=f"sequence: {SEQUENCE_KINDS}")
    p.add_argument("-o", "--output",
                   help="results file (default: INPUT_NAME.track.h5 in the current folder)")
    p.add_argument("--config", help="TOML file; its [track] table sets the tracker (docs/tracking.md)")
    p.add_argument("--profile", default="default", metavar="NAME",
                   help="default (the per-frame detector of process: moving targets against "
                   "the scene, confirmed only when clutter of the measured density would "
                   "rarely make a track as good; any sensor), maritime (sea scenes: the sea-sky band, unsmoothed, 5.5 "
                   "sigmas and 5 px against waves and glints) or paper (the paper's absolute "
                   "grey and area gates of its harbour scene)")
    p.add_argument("--method", choices=["fcm-pmht", "gnn"],
                   help="FCM + adaptive PMHT (default) or the CV Kalman + GNN baseline")
    p.add_argument("--psf", type=float, metavar="PX",
                   help="the sensor's point spread: sigma (px) of the Gaussian matched "
                   "filter of the default profile's regions (default 1; a sensor whose "
                   "point targets fill about one pixel, 0.6; 0: none; the [track] psf "
                   "setting, docs/tracking.md)")
    p.add_argument("--sea-sky", action="store_true", default=None,
                   help="maritime scene: search only near the sea-sky line")
    p.add_argument("--dataset", help=DATASET_HELP)
    add_input_options(p)
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


def run(args) -> int:
    from irdetect import tables
    from irdetect.pipeline import check_size
    from irdetect.track import track

    overrides = {k: v for k, v in (("method", args.method), ("sea_sky", args.sea_sky),
                                   ("psf", args.psf)) if v is not None}
    if args.psf is not None and args.psf < 0:
        raise InputError(f"--psf {args.psf:g}: the PSF's sigma must be >= 0 px")
    config = with_input_options(load_profile(args.profile, args.config), args)
    config = dataclasses.replace(config, track=dataclasses.replace(config.track, **overrides))
    path = Path(args.input)
    output = Path(args.output or f"{path.name if path.is_dir() else path.stem}.track.h5")
    check_output_path(output, args.force, inputs=(args.input,))
    params = {k: getattr(config.track, k) for k in config.track.__dataclass_fields__}
    with refused_settings(args.config):     # the tracker's own checks, on flat frames
        # (of three levels: equal ones would be a frame-rate conversion's repeats)
        flat = np.arange(3, dtype=np.float32)[:, None, None] * np.ones((32, 32), np.float32)
        track(flat, lambda rows: None, False,
              dataclasses.asdict(config.suppress), **params)
    with open_sequence(args.input, dataset=args.dataset) as source:
        check_size(source.shape, args.input, config.suppress.bin)
        if len(source) < config.track.confirm_hits:
            raise InputError(f"the sequence has {len(source)} frame"
                             f"{'' if len(source) == 1 else 's'}; a track is confirmed after "
                             f"{config.track.confirm_hits} hits (track.confirm_hits)",
                             args.input)
        with ResultsWriter(output, force=args.force, inputs=(args.input,), attrs={
                "config": to_json(config), "input": path.name,
                "input_path": str(path.resolve()), "n_frames": source.shape[0],
                "frame_height": source.shape[1], "frame_width": source.shape[2],
                "frame_rate": source.frame_rate or float("nan")}) as out:
            out.append("track_points", tables.empty(tables.TRACK_POINT))
            points, summary = track(source, lambda rows: out.append("track_points", rows),
                                    args.progress, dataclasses.asdict(config.suppress),
                                    lambda rows: out.append("camera", rows), **params,
                                    exclude=config.exclude)
            out.write("tracks", summary)
    log.info("wrote %s: %d frame%s, %d track%s", output, len(source),
             "" if len(source) == 1 else "s", len(summary), "" if len(summary) == 1 else "s")
    flat = flat_frames(args.input, args.dataset) if not len(summary) else None
    if flat:
        log.info("no track: %s", flat)
    elif not len(summary) and config.track.regions == "detector":
        from irdetect.peaks import frame_level

        log.info("no track: a frame-by-frame tracker follows targets that reach the "
                 "per-frame level (%.1f local sigmas here) in most frames; for dimmer ones "
                 "irdetect process integrates 12 frames%s%s",
                 frame_level(source.shape[1:], config.track.false_rate),
                 "; targets that fill about one pixel reach it more often with --psf 0.6"
                 if config.track.psf > 0.6 else "",
                 "; targets darker than their background (a recording saved black-hot) "
                 "take --polarity dark" if config.suppress.polarity == "bright" else "")
    return 0
