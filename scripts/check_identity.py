#!/usr/bin/env python
"""Check that a rewrite of the front end changes no result: save the tables, compare later.

Runs the front end (``irdetect.pipeline.iter_results`` + track initiation) on wan2008 at
SNR 2 and 3 (several seeds, 120 frames), the clutter preset and the real DAUB sequences
daub-data20 and daub-data13-c (``../shared/data/real``, skipped when absent), and saves the
candidates, detections, segments and tracks tables byte for byte. ``--compare`` reruns
and reports every table that differs.

Usage::

    .venv/bin/python scripts/check_identity.py --save /tmp/before.npz
    ... edit ...
    .venv/bin/python scripts/check_identity.py --compare /tmp/before.npz [--workers 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
TABLES = ("candidates", "detections", "segments", "tracks")


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
    for name in ("daub-data20", "daub-data13-c"):
        if (REAL / name).is_dir():
            with open_sequence(REAL / name / "frames") as src:
                yield name, src[0:len(src)]
        else:
            print(f"{name}: not found under {REAL}, skipped", file=sys.stderr)


def run(frames, config, workers: int) -> dict:
    from irdetect.pipeline import detect_sequence

    return detect_sequence(frames, config, workers=workers)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", help="write the tables to this .npz")
    g.add_argument("--compare", help="compare with the tables saved in this .npz")
    ap.add_argument("--config", help="TOML config (default: the defaults)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="one seed per scene")
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
                same = ref.dtype == res[t].dtype and ref.tobytes() == res[t].tobytes()
                if not same:
                    bad += 1
                    print(f"  DIFFERS {key}: {len(ref)} rows saved, {len(res[t])} now")
        print(f"{name}: {counts} ({secs:.1f} s)", flush=True)
    if args.save:
        np.savez(args.save, **out)
        print(f"saved {len(out)} tables to {args.save}")
        return 0
    print("identical" if bad == 0 else f"{bad} tables differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
