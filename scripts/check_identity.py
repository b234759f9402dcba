#!/usr/bin/env python
"""Check that a rewrite of the front end changes no result: save the tables, compare later.

Runs the front end (``irdetect.pipeline.iter_results`` + track initiation) on wan2008 at
SNR 2 and 3 (several seeds, 120 frames), the clutter preset, the real DAUB sequences
daub-data20 and daub-data13-c and the panning istd640-seq4-71 (``../shared/data/real``,
skipped when absent), and saves the
tables of ``detect_sequence`` (candidates, the combined and per-frame detections, segments,
fused detections and tracks) byte for byte. ``--compare`` reruns and reports every table
that differs; with ``--atol`` a table passes when it has the same rows and dtype and every
float column within ``atol`` of the saved one (the compiled kernels of ``irdetect.kernels``
sum in another order than the numpy / OpenCV code they replaced: float32 sums agree to
about 1e-6).

Usage::

    .venv/bin/python scripts/check_identity.py --save /tmp/before.npz
    ... edit ...
    .venv/bin/python scripts/check_identity.py --compare /tmp/before.npz [--workers 2] [--atol 1e-6]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
TABLES = ("candidates", "combined_detections", "frame_detections", "frame_tracks", "segments",
          "detections", "tracks")


def cases(quick: bool = False):
    """(name, frames) of every scene checked."""
    from irdetect.io import open_sequence
    from irdetect.simulate import simulate

    seeds = (1,) if quick else (1, 2, 3)
    for snr in (2.0, 3.0):
        for seed in seeds:
            frames, _ = simulate("wan2008", snr=snr, rng=seed, n_frames=120)
            yield f"wan2008-snr{snr:g}-seed{seed}", frames
    for seed in seeds[:2]:
        frames, _ = simulate("clutter", rng=seed, n_frames=96)
        yield f"clutter-seed{seed}", frames
    # a panning camera (tracks in scene coordinates) at 640x512
    for name in ("daub-data20", "daub-data13-c", "istd640-seq4-71"):
        if (REAL / name).is_dir():
            with open_sequence(REAL / name / "frames") as src:
                yield name, src[0:len(src)]
        else:
            print(f"{name}: not found under {REAL}, skipped", file=sys.stderr)


def run(frames, config, workers: int) -> dict:
    from irdetect.pipeline import detect_sequence

    return detect_sequence(frames, config, workers=workers)


def difference(ref: np.ndarray, new: np.ndarray) -> float:
    """Largest absolute difference of two tables' columns; inf when their dtypes or row
    counts differ or a non-float column differs; 0 when byte for byte equal."""
    if ref.dtype != new.dtype or len(ref) != len(new):
        return np.inf
    if ref.tobytes() == new.tobytes():
        return 0.0
    gap = 0.0
    for name in ref.dtype.names:
        a, b = ref[name], new[name]
        if np.issubdtype(a.dtype, np.floating):
            same = np.isnan(a) & np.isnan(b)
            d = np.abs(a.astype(np.float64) - b)[~same]
            gap = max(gap, float(d.max()) if d.size else 0.0)
        elif not np.array_equal(a, b):
            return np.inf
    return gap


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", help="write the tables to this .npz")
    g.add_argument("--compare", help="compare with the tables saved in this .npz")
    ap.add_argument("--config", help="TOML config (default: the defaults)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="one seed per scene")
    ap.add_argument("--atol", type=float, default=0.0,
                    help="float columns may differ by this much (default 0: byte for byte)")
    args = ap.parse_args(argv)
    from irdetect.config import load_config

    config = load_config(args.config)
    saved = dict(np.load(args.compare)) if args.compare else {}
    out, bad = {}, 0
    for name, frames in cases(args.quick):
        t0 = time.perf_counter()
        res = run(frames, config, args.workers)
        secs = time.perf_counter() - t0
        counts = " ".join(f"{t} {len(res[t])}" for t in TABLES)
        for t in TABLES:
            key = f"{name}/{t}"
            out[key] = res[t]
            if args.compare:
                if key not in saved:
                    print(f"  {key}: not in {args.compare}")
                    continue
                ref = saved[key]
                gap = difference(ref, res[t])
                if gap > args.atol:
                    bad += 1
                    print(f"  DIFFERS {key}: {len(ref)} rows saved, {len(res[t])} now, "
                          f"largest difference {gap:.3g}")
        print(f"{name}: {counts} ({secs:.1f} s)", flush=True)
    if args.save:
        np.savez(args.save, **out)
        print(f"saved {len(out)} tables to {args.save}")
        return 0
    print("identical" if bad == 0 else f"{bad} tables differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
