#!/usr/bin/env python
"""Track initiation on a long sequence; writes docs/results/long_initiation.md.

A recording much longer than a target's time in view: ``--segments`` pieces of 240 frames
of 256x256 uint16 (wan2008 targets at SNR 4 and 1 px/frame, random directions, new targets
in every piece), one after another. The front end runs once (defaults); the confirmed
detections are then initiated with ``initiate.window`` = 0 (one window over the whole
sequence: the votes needed grow with its length) and with sliding windows of 5, 10 (the
default) and 20 combined frames. Tracks are scored per target with the line rule (Pt,
false tracks, median speed error; ``score_image_tracks``) and the path rule (within
6 px of the target in half the track's frames; ``score_track_paths``).

Usage: ``.venv/bin/python scripts/bench_long_initiation.py [--segments N] [--out PATH]``
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from irdetect.config import ProcessConfig
from irdetect.metrics.initiation import score_image_tracks, score_track_paths
from irdetect.pipeline import detect_sequence, initiate_tracks
from irdetect.simulate import load_scenario, simulate

ROOT = Path(__file__).resolve().parents[1]
SEGMENT = 240
WINDOWS = (0, 5, 10, 20)


def long_sequence(segments: int):
    """(frames (T, 256, 256) uint16, TRUTH rows) of ``segments`` pieces in a row."""
    frames, truths = [], []
    for k in range(segments):
        s = load_scenario("wan2008", height=256, width=256, n_frames=SEGMENT, dtype="uint16",
                          background=1000.0, noise_sigma=20.0, snr=4.0, directions=[])
        f, tr = simulate(s, rng=k)
        tr = tr.copy()
        tr["frame"] += SEGMENT * k
        tr["target"] += 10 * k
        frames.append(f)
        truths.append(tr)
    return np.concatenate(frames), np.concatenate(truths)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, default=4)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "long_initiation.md"))
    args = ap.parse_args(argv)
    frames, truth = long_sequence(args.segments)
    config = ProcessConfig()
    out = detect_sequence(frames, config)
    detections, camera = out["detections"], out["camera"]
    rows = []
    for window in WINDOWS:
        cfg = dataclasses.replace(config, initiate=dataclasses.replace(config.initiate,
                                                                       window=window))
        t0 = time.perf_counter()
        tracks = initiate_tracks(detections, cfg)
        seconds = time.perf_counter() - t0
        line = score_image_tracks(tracks, truth, camera=camera)
        path = score_track_paths(tracks, truth, gate=6.0, camera=camera)
        err = line["speed_error"]
        rows.append(f"| {window or 'whole sequence (0)'} | {len(tracks)} | "
                    f"{line['pt_overall']:.2f} | {line['n_false']} | "
                    f"{path['pt_overall']:.2f} | {path['n_false']} | "
                    f"{100 * np.median(err) if len(err) else float('nan'):.1f} % | "
                    f"{seconds:.2f} |")
        print(rows[-1], flush=True)
    n_targets = len(np.unique(truth["target"]))
    text = "\n".join([
        "# Track initiation on a long sequence",
        "",
        f"Produced by `scripts/bench_long_initiation.py` on {time.strftime('%Y-%m-%d %H:%M')}: "
        f"{args.segments} x {SEGMENT} frames of 256x256 (uint16, SNR 4, 1 px/frame), "
        f"{n_targets} targets, each in view for one {SEGMENT}-frame piece "
        f"({SEGMENT // 12} combined frames of {len(frames) // 12}); {len(detections)} "
        "confirmed detections from the default front end.",
        "",
        "| `initiate.window` (combined frames) | tracks | Pt (line rule) | false (line) | "
        "Pt (path rule, 6 px) | false (path) | median speed error | seconds |",
        "|---|---|---|---|---|---|---|---|",
        *rows, ""])
    Path(args.out).write_text(text)
    print("wrote", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
