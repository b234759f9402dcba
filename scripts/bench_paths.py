#!/usr/bin/env python
"""The per-frame path's cost to dim targets: wan2008 and clutter scenes at low SNR, the
defaults against the combined-frame path alone (``frame.enabled = false``, the design
before issue 26), on the seeds earlier rounds chose constants on (0-19) and on held-out
seeds (1000-1019); writes docs/results/paths.md.

Pd = target-windows detected / target-windows (gate 3 px, ``score_detections``), false =
unmatched detections, summed over the seeds.

Usage: .venv/bin/python scripts/bench_paths.py [--seeds 20] [--out docs/results/paths.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import time
from pathlib import Path

from irdetect.config import ProcessConfig
from irdetect.metrics.detection import score_detections
from irdetect.pipeline import detect_sequence
from irdetect.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
SCENES = (("wan2008", 2.0), ("wan2008", 3.0), ("clutter", 3.0), ("clutter", 4.0))
SEED_SETS = (("seeds 0-19", 0), ("held-out seeds 1000-1019", 1000))


def configurations():
    c = ProcessConfig()
    return (("defaults (both paths)", c),
            ("combined-frame path alone", dataclasses.replace(
                c, frame=dataclasses.replace(c.frame, enabled=False))))


def run(scene, snr, first, n, config) -> dict:
    detected = targets = false = 0
    for seed in range(first, first + n):
        frames, truth = simulate(scene, snr=snr, rng=seed)
        out = detect_sequence(frames, config)
        m = score_detections(out["detections"], truth, n_frames=len(frames), length=12,
                             step=12, shape=frames.shape[1:])
        detected, targets, false = (detected + m["detected"], targets + m["targets"],
                                    false + m["false"])
    return {"pd": detected / targets, "detected": detected, "targets": targets,
            "false": false}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "paths.md"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    lines = ["# Dim targets with and without the per-frame path", "",
             f"Produced by `scripts/bench_paths.py --seeds {args.seeds}` "
             f"({datetime.date.today().isoformat()}, {os.cpu_count()} cores). "
             "Pd (detected / target-windows) and false detections summed over the seeds; "
             "gate 3 px.", "",
             "| scene | SNR | seeds | " + " | ".join(f"{n}: Pd (detected) / false"
                                                   for n, _ in configurations()) + " |",
             "|---|---|---|" + "---|" * len(configurations())]
    for scene, snr in SCENES:
        for label, first in SEED_SETS:
            cells = []
            for name, config in configurations():
                r = run(scene, snr, first, args.seeds, config)
                cells.append(f"{r['pd']:.3f} ({r['detected']}/{r['targets']}) / {r['false']}")
                print(scene, snr, label, name, cells[-1], flush=True)
            lines.append(f"| {scene} | {snr:g} | {label} | " + " | ".join(cells) + " |")
    lines += ["", f"Run time {time.perf_counter() - t0:.0f} s."]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("wrote", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
