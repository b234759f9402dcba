#!/usr/bin/env python
"""The verification's settings measured; writes docs/results/verification.md.

1. ``correlate.screen`` (chains whose coarse, nearest-pixel statistic is under screen x
   verify are not refined): for each value, on a simulated 256x256 uint16 sequence (the
   throughput benchmark's, ``--frames`` frames) the share of chains refined and the
   correlation stage's seconds (1 thread); on the real sequences of ../shared/data/real
   the DAUB target-windows, false detections and sequences meeting issue 8's goal; on the
   simulator (``--seeds`` seeds) the full pipeline's Pd and false detections per
   megapixel-window on wan2008 SNR 2 and 3, held-out seeds 1000+ at SNR 2, and the
   clutter scene at SNR 3.
2. The same simulated sequence with the default configuration, ``--profile fast`` and
   ``correlate.verify = 0`` alone (the default's loose first threshold without the
   verification): detections, tracks, the initiation's seconds and the whole run's.

Usage: ``.venv/bin/python scripts/bench_verification.py [--frames N] [--seeds N]
[--out PATH]``
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import irdetect.verify as verify_module
from irdetect.config import ProcessConfig
from irdetect.pipeline import process_file
from irdetect.profiles import load_profile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_detection  # noqa: E402
import bench_real  # noqa: E402
from bench_throughput import generate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCREENS = (0.25, 0.3, 0.35, 0.4, 0.5)
#: (label, scenario, SNR, first seed) of the simulator columns
SCENES = (("wan2008 SNR 2", "wan2008", 2.0, 0), ("wan2008 SNR 3", "wan2008", 3.0, 0),
          ("held-out wan2008 SNR 2", "wan2008", 2.0, 1000), ("clutter SNR 3", "clutter", 3.0, 0))


class RefineCounter:
    """Wraps ``verify.track_significance`` to count the chains it gets, and its hill
    climb (``verify._refine``) to count those it refines (whose coarse statistic
    passed the screen)."""

    def __init__(self):
        self.originals = verify_module.track_significance, verify_module._refine
        self.chains = self.refined = 0

    def __call__(self, evidence, points, screen=-np.inf):
        z, c, v = self.originals[0](evidence, points, screen)
        self.chains += len(z)
        return z, c, v

    def _refine(self, frames, dts, c, v, z, rows, *args):
        self.refined += len(rows)
        return self.originals[1](frames, dts, c, v, z, rows, *args)

    def __enter__(self):
        verify_module.track_significance, verify_module._refine = self, self._refine
        return self

    def __exit__(self, *exc):
        verify_module.track_significance, verify_module._refine = self.originals


def run_file(seq: Path, out: Path, config: ProcessConfig) -> dict:
    timings: dict = {}
    t0 = time.perf_counter()
    r = process_file(seq, out, config, force=True, timings=timings)
    return {**r, "wall": time.perf_counter() - t0, "timings": timings}


def simulator(config: ProcessConfig, seeds: int) -> list[dict]:
    return [bench_detection.run_scene(bench_detection.full_pipeline, scenario, snr,
                                      list(range(first, first + seeds)), config)
            for _, scenario, snr, first in SCENES]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1200)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "verification.md"))
    args = ap.parse_args(argv)
    t_all = time.perf_counter()
    daub = {}
    if bench_real.REAL.is_dir():
        daub = {p.name: bench_real.load(p) for p in sorted(bench_real.REAL.iterdir())
                if p.name.startswith("daub") and (p / "frames").is_dir()}
    screen_rows, path_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        seq, out = Path(tmp) / "seq.h5", Path(tmp) / "out.h5"
        generate(seq, 256, 256, args.frames)
        for screen in SCREENS:
            cfg = bench_real.with_changes(ProcessConfig(), {"correlate": {"screen": screen}})
            with RefineCounter() as count:
                run = run_file(seq, out, cfg)
            screen_rows.append((screen, count.refined / max(count.chains, 1),
                                run["timings"]["correlate"],
                                bench_real.totals(daub, cfg) if daub else None,
                                simulator(cfg, args.seeds)))
            print(f"screen {screen}: {count.refined}/{count.chains} refined", flush=True)
        loose = bench_real.with_changes(ProcessConfig(), {"correlate": {"verify": 0.0}})
        for label, cfg in (("default", ProcessConfig()), ("`--profile fast`", load_profile("fast")),
                           ("`correlate.verify = 0` alone", loose)):
            path_rows.append((label, run_file(seq, out, cfg)))
            print(label, flush=True)
    write_report(Path(args.out), args, screen_rows, path_rows, time.perf_counter() - t_all)
    print(f"wrote {args.out}")
    return 0


def write_report(path: Path, args, screen_rows, path_rows, seconds: float) -> None:
    lines = [
        "# The verification's settings: measured",
        "",
        f"Produced by `scripts/bench_verification.py` ({datetime.date.today().isoformat()}; "
        f"{os.cpu_count()} cores; {seconds:.0f} s). Sequence: {args.frames} simulated "
        "frames of 256x256 uint16 (the throughput benchmark's, 5 targets at SNR 4); "
        f"simulator: {args.seeds} seeds per scene, full pipeline; real: "
        "../shared/data/real (DAUB gate 3 px).",
        "",
        "## 1. `correlate.screen`",
        "",
        "| screen | chains refined | correlation stage s (1 thread) | DAUB windows | DAUB false "
        "| DAUB goal met | " + " | ".join(f"{label} Pd / false per Mpx-window"
                                          for label, *_ in SCENES) + " |",
        "|---|---|---|---|---|---|" + "---|" * len(SCENES),
    ]
    for screen, share, corr_s, real, sim in screen_rows:
        daub = (f"{real['detected']}/{real['targets']} | {real['false']} | {real['goal']} of 7"
                if real else "- | - | -")
        lines.append(f"| {screen:g} | {100 * share:.0f} % | {corr_s:.2f} | {daub} | "
                     + " | ".join(f"{s['pd']:.3f} / {s['false_per_mpx_window']:.1f}"
                                  for s in sim) + " |")
    lines += [
        "",
        "## 2. Leaving the verification out",
        "",
        "| configuration | detections | tracks | initiation s | whole run s |",
        "|---|---|---|---|---|",
    ]
    for label, r in path_rows:
        lines.append(f"| {label} | {r['detections']:,} | {r['tracks']:,} | "
                     f"{r['timings']['initiate']:.1f} | {r['wall']:.1f} |")
    lines.append("")
    path.write_text("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
