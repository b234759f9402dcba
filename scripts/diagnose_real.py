"""Where irdetect loses the targets and where its false detections come from, per window.

For each DAUB sequence in ../shared/data/real (or those named), the default
configuration (or ``--config``) is run and every missed target-window and every false
detection is printed with the stage that decided it:

  missed, no candidate    no fused point of the window within the gate of the true
                          path: suppression / dp merit / CFAR lost it (the residual's
                          peak near the truth, in noise sigmas, is printed per frame
                          with ``--residual``)
  missed, not chained     a candidate lies on the path but no 3-window chain through
                          it passed the motion bound and the constant-velocity test
  missed, not verified    a chain through it exists; its verification statistic z
                          (``verify``), ring ratio (``RING_RATIO``) and local z
                          (``verify_local``) are printed
  false                   a confirmed detection off the path: its position, score and,
                          for the chain that confirmed it, z and local z

Usage: .venv/bin/python scripts/diagnose_real.py [NAME ...] [--config CONFIG.toml]
       [--residual]

This is a diagnostic tool for docs/real.md; the measured tables come from
scripts/bench_real.py.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

import irdetect.pipeline as pipeline
from irdetect import verify as verify_mod
from irdetect.combine import window_starts
from irdetect.config import ProcessConfig, load_config
from irdetect.metrics.detection import path_distance
from irdetect.suppress import future_frames, noise_sigma, past_frames, suppress

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_real import REAL, gate_of, load  # noqa: E402


class Recorder:
    """Wraps ``irdetect.pipeline.combined.correlate``: keeps, per window triple, every chain that
    passed the motion bound and constant-velocity test with its verification numbers."""

    def __init__(self):
        self.triples = []
        self.original = pipeline.combined.correlate

    def __call__(self, p1, p2, p3, step, evidence=None, **kw):
        out = self.original(p1, p2, p3, step, evidence, **kw)
        loose = self.original(p1, p2, p3, step, None, **{**kw, "verify": 0.0,
                                                         "verify_local": 0.0,
                                                         "resolve": "all", "min_score": 0.0})
        chains = []
        if evidence is not None and len(loose.index):
            pts = np.stack([np.column_stack([t["x"], t["y"]])[loose.index[:, i]]
                            for i, t in enumerate((p1, p2, p3))], axis=1)
            z, c, v = verify_mod.track_significance(evidence, pts)
            ring = verify_mod.ring_significance(evidence, c, v)
            local = verify_mod.local_significance(evidence, c, v, z)
            tm = float(np.mean(evidence.index))
            chains = [(loose.index[i], z[i], ring[i], local[i], c[i], v[i],
                       tm) for i in range(len(z))]
        accepted = {tuple(r) for r in out.index}
        self.triples.append((chains, accepted))
        return out


def residual_peaks(frames, truth, start, cfg, length):
    """Per frame of the window: the suppressed frame's largest value within 1 px of the
    truth, in robust noise sigmas (PSF-smoothed as the dp merit sees it)."""
    sup = asdict(cfg.suppress)
    sup.pop("long_memory")               # the pipeline's, not suppress's
    keep = past_frames(**sup)
    ahead = future_frames(start=start, stop=start + length, **sup)
    res = suppress(frames[start:start + length], previous=frames[max(0, start - keep):start],
                   following=frames[start + length:start + length + ahead], **sup)
    out = []
    for i, r in enumerate(res):
        r = cv2.GaussianBlur(r, (0, 0), 0.6)
        x, y = int(round(truth["x"][start + i])), int(round(truth["y"][start + i]))
        out.append(float(r[max(0, y - 1):y + 2, max(0, x - 1):x + 2].max() / noise_sigma(r)))
    return out


def diagnose(name, cfg, residual=False):
    frames, truth = load(REAL / name)
    gate = gate_of(name)
    rec = Recorder()
    pipeline.combined.correlate = rec
    try:
        out = pipeline.detect_sequence(frames, cfg)
    finally:
        pipeline.combined.correlate = rec.original
    length, step = cfg.combine.length, cfg.combine.step
    starts = window_starts(len(frames), length=length, step=step, tail=cfg.combine.tail)
    det, cand = out["detections"], out["candidates"]
    print(f"== {name}: {len(out['tracks'])} tracks")
    for k, s in enumerate(starts):
        tk = truth[(truth["frame"] >= s) & (truth["frame"] < s + length)]
        path = np.column_stack([tk["x"], tk["y"]])
        dk, ck = det[det["combined_frame"] == k], cand[cand["combined_frame"] == k]
        dd = path_distance(np.column_stack([dk["x"], dk["y"]]), path) if len(dk) else []
        dc = path_distance(np.column_stack([ck["x"], ck["y"]]), path) if len(ck) else []
        for i in np.flatnonzero(np.asarray(dd) > gate):
            print(f"  window {k} (frames {s}-{s + length - 1}): FALSE at ({dk['x'][i]:.0f}, "
                  f"{dk['y'][i]:.0f}) score {dk['score'][i]:.1f} v ({dk['vx'][i]:.2f}, "
                  f"{dk['vy'][i]:.2f})" + _chain_note(rec, k, ck, dk[i]))
        if len(dd) and np.min(dd) <= gate:
            continue
        near = np.flatnonzero(np.asarray(dc) <= gate)
        if len(near) == 0:
            j = int(np.argmin(dc)) if len(dc) else None
            note = (f"nearest candidate {dc[j]:.0f} px away" if j is not None
                    else "no candidates")
            print(f"  window {k} (frames {s}-{s + length - 1}): MISSED, no candidate on the "
                  f"path ({note})")
            if residual:
                peaks = residual_peaks(frames, truth, int(s), cfg, length)
                print("    residual peak at the truth, sigmas:",
                      " ".join(f"{p:.1f}" for p in peaks))
            continue
        rows = set(int(r) for r in near)
        chains = []
        for t in range(max(0, k - 2), min(k + 1, len(rec.triples))):
            for idx, z, ring, local, c, v, tm in rec.triples[t][0]:
                if int(idx[k - t]) in rows:
                    chains.append((z, ring, local, t))
        if not chains:
            print(f"  window {k} (frames {s}-{s + length - 1}): MISSED, candidate on the path "
                  f"(score {ck['score'][near].max():.1f}) but no chain through it passed the "
                  f"motion bound / constant-velocity test")
        else:
            z, ring, local, t = max(chains)
            print(f"  window {k} (frames {s}-{s + length - 1}): MISSED, not verified: best "
                  f"chain (triple {t}) z {z:.1f} (verify {cfg.correlate.verify}), ring "
                  f"{ring:.2f} (max {verify_mod.RING_RATIO}), local z {local:.1f} "
                  f"(verify_local {cfg.correlate.verify_local})")


def _chain_note(rec, k, ck, d):
    """z and local z of the accepted chain that confirmed detection d of window k."""
    best = None
    for t in range(max(0, k - 2), min(k + 1, len(rec.triples))):
        chains, accepted = rec.triples[t]
        for idx, z, ring, local, c, v, tm in chains:
            if tuple(idx) not in accepted:
                continue
            row = ck[int(idx[k - t])] if int(idx[k - t]) < len(ck) else None
            if row is None:
                continue
            if abs(row["x"] - d["x"]) + abs(row["y"] - d["y"]) < 15:
                if best is None or z > best[0]:
                    best = (z, local)
    return f"; chain z {best[0]:.1f}, local z {best[1]:.1f}" if best else ""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="sequences (default: every DAUB sequence)")
    ap.add_argument("--config", help="TOML configuration (default: the defaults)")
    ap.add_argument("--residual", action="store_true",
                    help="print the residual at the truth for windows with no candidate")
    args = ap.parse_args(argv)
    if not REAL.is_dir():
        print(f"real data not found at {REAL}")
        return 1
    cfg = load_config(args.config) if args.config else ProcessConfig()
    names = args.names or sorted(p.name for p in REAL.iterdir()
                                 if p.name.startswith("daub") and (p / "frames").is_dir())
    for name in names:
        diagnose(name, cfg, args.residual)
    return 0


if __name__ == "__main__":
    sys.exit(main())
