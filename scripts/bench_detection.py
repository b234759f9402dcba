#!/usr/bin/env python
"""Benchmark the detection front end; writes docs/results/detection.md.

Measures, with the simulator's ground truth (and the real sequences in
../shared/data/real when present):

1. wan2008 scene over SNR 1.5 .. 6 (N seeds each): Pd and false detections for
   (a) the full pipeline, (b) single-frame top-hat + threshold, (c) max projection +
   threshold (no directional detection, no correlation), (d) the velocity-matched-filter
   bound with known velocity (analytic);
2. the structured-clutter scene, same methods;
3. the choices made beyond the paper: projection (paper's max vs the DP merit),
   correlation options (constant velocity, resolution of non-unique matches, score test);
4. the suppressor, on the clutter scene and on the real sequences (how the default was
   chosen);
5. throughput in frames/s (2 shared cores: noisy).

Usage: ``python scripts/bench_detection.py [--quick] [--seeds N] [--out PATH]
[--jobs N | --scheduler ADDRESS]`` (runs go through irdetect.batch.map_tasks).
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import norm

from irdetect import tables
from irdetect.batch import map_tasks
from irdetect.combine import combine
from irdetect.config import ProcessConfig
from irdetect.detect import DirectionalDetection
from irdetect.fuse import fuse
from irdetect.metrics.detection import score_detections
from irdetect.pipeline import detect_sequence
from irdetect.simulate import load_scenario, simulate
from irdetect.suppress import suppress

ROOT = Path(__file__).resolve().parents[1]
REAL = (ROOT / ".." / "shared" / "data" / "real").resolve()
SNRS = (1.5, 2.0, 2.5, 3.0, 4.0, 6.0)


# --- methods ----------------------------------------------------------------------------

def full_pipeline(frames, cfg: ProcessConfig):
    """irdetect's fused detections (both paths, ``detect_sequence``)."""
    return detect_sequence(frames, cfg)["detections"], 12, 12


def single_frame_tophat(frames, cfg: ProcessConfig, k: float = 5.0):
    """(b): per frame, top-hat (9x9) and threshold k x robust sigma; window = 1 frame."""
    res = suppress(frames, method="tophat", size=9)
    rows = [_as_detections(_threshold_fuse(r, k), t) for t, r in enumerate(res)]
    return np.concatenate(rows), 1, 1


def max_projection_threshold(frames, cfg: ProcessConfig, k: float = 5.0):
    """(c): top-hat, max projection of 12 frames, threshold k x robust sigma per pixel."""
    res = suppress(frames, method="tophat", size=9)
    comb = combine(res, length=12, step=12, projection="max")
    rows = [_as_detections(_threshold_fuse(c, k), i) for i, c in enumerate(comb)]
    return np.concatenate(rows), 12, 12


def _threshold_fuse(img, k):
    """Per-pixel CFAR (median + k x 1.4826 MAD over the frame), groups fused."""
    med = np.median(img)
    sig = max(1.4826 * float(np.median(np.abs(img - med))), 1e-6)
    z = ((img - med) / sig).astype(np.float32)
    mask = z > k
    det = DirectionalDetection(mask, np.where(mask, 0, -1).astype(np.int8), z)
    return fuse(det, img)


def _as_detections(cand, index):
    out = np.zeros(len(cand), tables.DETECTION)
    for name in ("x", "y", "intensity", "score", "n_members"):
        out[name] = cand[name]
    out["combined_frame"] = index
    return out


def vmf_bound(snr: float, psf_sigma: float = 0.6, frames: int = 12,
              pfa: float = 1e-6) -> float:
    """(d) Pd of a matched filter with known velocity over one window (analytic).

    The target's energy over the window, summed along its known path with the sampled
    Gaussian PSF as the template: d = snr x sqrt(frames x mean over sub-pixel phase of
    sum psf^2); threshold for pfa per pixel (1e-6: 1 false detection per megapixel-window,
    one velocity hypothesis per pixel): Pd = 1 - Phi(Phi^-1(1 - pfa) - d).
    """
    phases = np.linspace(-0.5, 0.5, 11)
    grid = np.arange(-4, 5)
    energy = []
    for px in phases:
        for py in phases:
            gx = np.exp(-((grid - px) ** 2) / (2 * psf_sigma ** 2))
            gy = np.exp(-((grid - py) ** 2) / (2 * psf_sigma ** 2))
            energy.append(float((np.outer(gy, gx) ** 2).sum()))
    d = snr * math.sqrt(frames * float(np.mean(energy)))
    return float(1 - norm.cdf(norm.ppf(1 - pfa) - d))


# --- scoring -----------------------------------------------------------------------------

def score(method, frames, truth, cfg, gate=3.0):
    dets, length, step = method(frames, cfg)
    return score_detections(dets, truth, n_frames=len(frames), length=length, step=step,
                            shape=frames.shape[1:], gate=gate)


def aggregate(scores):
    t = sum(s["targets"] for s in scores)
    d = sum(s["detected"] for s in scores)
    f = sum(s["false"] for s in scores)
    w = sum(s["windows"] for s in scores)
    mpx = sum(s["windows"] * s["_mpx"] for s in scores)
    return {"pd": d / t if t else float("nan"), "false_per_window": f / w,
            "false_per_mpx_window": f / mpx, "targets": t, "windows": w}


#: where the Monte Carlo runs go (set by --jobs / --scheduler): irdetect.batch.map_tasks
EXECUTOR = {"jobs": 1, "scheduler": None}


def one_seed(task):
    """One Monte Carlo run (module level, so map_tasks can ship it to other processes)."""
    method, scenario, snr, seed, cfg, overrides = task
    frames, truth = simulate(scenario, snr=snr, rng=seed, **overrides)
    s = score(method, frames, truth, cfg)
    s["_mpx"] = frames.shape[1] * frames.shape[2] / 1e6
    return s


def run_scene(method, scenario, snr, seeds, cfg, **overrides):
    tasks = [(method, scenario, snr, seed, cfg, overrides) for seed in seeds]
    return aggregate(map_tasks(one_seed, tasks, **EXECUTOR))


def load_real():
    from irdetect.io import open_sequence, read_point_annotations

    seqs = []
    if not REAL.is_dir():
        return seqs
    for folder in sorted(REAL.iterdir()):
        if not (folder / "frames").is_dir():
            continue
        with open_sequence(folder / "frames") as src:
            frames = src[:]
        truth = read_point_annotations(folder / "truth.txt", len(frames))
        gate = 3.0 if folder.name.startswith("daub") else 5.0
        seqs.append((folder.name, frames, truth, gate))
    return seqs


def run_real(seqs, cfg):
    out, per = [], []
    for name, frames, truth, gate in seqs:
        dets, length, step = full_pipeline(frames, cfg)
        s = score_detections(dets, truth, n_frames=len(frames), length=length, step=step,
                             shape=frames.shape[1:], gate=gate)
        s["_mpx"] = frames.shape[1] * frames.shape[2] / 1e6
        out.append(s)
        per.append(f"{s['detected']}/{s['targets']}")
    agg = aggregate(out)
    agg["per_sequence"] = " ".join(per)
    return agg


def with_(cfg, **kw):
    """cfg with stage fields replaced: with_(cfg, suppress__method="tophat")."""
    for key, value in kw.items():
        stage, name = key.split("__")
        cfg = dc.replace(cfg, **{stage: dc.replace(getattr(cfg, stage), **{name: value})})
    return cfg


# --- report ------------------------------------------------------------------------------

def fmt(x, digits=2):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def pd_figure(path, curves, bound):
    """PNG of section 1: Pd and false detections per megapixel-window against SNR for
    methods (a)-(c), and the matched-filter bound (d); None without matplotlib."""
    from _figures import save_curves

    names = {"a": "(a) full pipeline", "b": "(b) single-frame top-hat",
             "c": "(c) max projection + threshold"}
    pd_series = [{"x": SNRS, "y": [p for p, _ in curves[k]], "label": names[k]}
                 for k in names]
    pd_series.append({"x": SNRS, "y": bound, "label": "(d) velocity-matched filter bound",
                      "ls": "--", "marker": "none", "color": "black"})
    fa_series = [{"x": SNRS, "y": [max(f, 0.01) for _, f in curves[k]], "label": names[k]}
                 for k in names]
    return save_curves(path, [
        {"xlabel": "SNR (peak amplitude / noise sigma)", "ylabel": "Pd (target-windows)",
         "series": pd_series, "ylim": (0, 1.02), "xticks": SNRS,
         "title": "wan2008: Pd against SNR"},
        {"xlabel": "SNR (peak amplitude / noise sigma)",
         "ylabel": "false detections per Mpx-window (0 drawn at 0.01)", "yscale": "log",
         "series": fa_series, "xticks": SNRS, "title": "false detections ((b): per frame)"},
    ])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 seeds instead of 20")
    ap.add_argument("--seeds", type=int, help="seeds per SNR (default 20, 5 with --quick)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "detection.md"))
    ap.add_argument("--jobs", type=int, default=1, help="local processes for the runs (1)")
    ap.add_argument("--scheduler", help="Dask scheduler address for the runs")
    args = ap.parse_args(argv)
    EXECUTOR.update(jobs=args.jobs, scheduler=args.scheduler)
    logging.disable(logging.WARNING)
    n_seeds = args.seeds or (5 if args.quick else 20)
    seeds = range(n_seeds)
    few = range(min(n_seeds, 8))
    cfg = ProcessConfig()
    # the front end before the matched-filter verification (issue 3's first version)
    previous = dict(detect__k=3.5, correlate__verify=0.0, correlate__min_score=5.0,
                    correlate__max_deviation=5.0, correlate__tolerance=2.0)
    t_start = time.perf_counter()
    lines = []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    wan = load_scenario("wan2008")
    say("# Detection front end: measured")
    say()
    say(f"Produced by `scripts/bench_detection.py{' --quick' if args.quick else ''}` "
        f"({n_seeds} seeds per SNR; {time.strftime('%Y-%m-%d')}). Scene `wan2008`: "
        f"{wan.width}x{wan.height} px, {wan.n_frames} frames (4 combined frames of 12), "
        f"{wan.n_targets} targets at 1 px/frame, Gaussian PSF sigma {wan.psf_sigma} px, "
        f"noise sigma {wan.noise_sigma} grey levels, uint8. SNR = peak amplitude / noise "
        "sigma. A target in a window is detected when a detection lies within 3 px of its "
        "true path in that window (one-to-one). At this frame size 1 false detection per "
        f"megapixel-window is {wan.width * wan.height / 1e6:.3f} per window.")
    say()
    say("Methods: (a) the full pipeline with the default configuration; (b) single-frame "
        "top-hat (9x9) + threshold 5 x robust sigma, scored per frame (window = 1 frame); "
        "(c) top-hat, max projection of 12 frames + per-pixel threshold 5 x robust sigma, "
        "no directional detection or correlation; (d) matched filter with the known velocity "
        "over a 12-frame window, analytic, threshold at 1e-6 per pixel (1 false detection "
        "per megapixel-window).")
    say()
    say("## 1. wan2008: Pd and false detections per megapixel-window versus SNR")
    say()
    say("| SNR | dB | (a) Pd | (a) false/Mpx-win | (b) Pd | (b) false/Mpx-frame | "
        "(c) Pd | (c) false/Mpx-win | (d) VMF Pd bound |")
    say("|---|---|---|---|---|---|---|---|---|")
    curves = {"a": [], "b": [], "c": []}
    for snr in SNRS:
        a = run_scene(full_pipeline, "wan2008", snr, seeds, cfg)
        b = run_scene(single_frame_tophat, "wan2008", snr, range(min(n_seeds, 3)), cfg)
        c = run_scene(max_projection_threshold, "wan2008", snr, seeds, cfg)
        for key, r in (("a", a), ("b", b), ("c", c)):
            curves[key].append((r["pd"], r["false_per_mpx_window"]))
        say(f"| {snr:g} | {20 * math.log10(snr):.1f} | {fmt(a['pd'])} | "
            f"{fmt(a['false_per_mpx_window'], 1)} | {fmt(b['pd'])} | "
            f"{fmt(b['false_per_mpx_window'], 1)} | {fmt(c['pd'])} | "
            f"{fmt(c['false_per_mpx_window'], 1)} | {fmt(vmf_bound(snr, wan.psf_sigma))} |")
    say()
    figure = pd_figure(Path(args.out).with_name("detection-pd-snr.png"), curves,
                       [vmf_bound(snr, wan.psf_sigma) for snr in SNRS])
    if figure:
        say(f"![Pd and false detections against SNR, per method]({figure.name})")
        say()
    say(f"(b) uses {min(n_seeds, 3)} seeds (it scores 48 frames per seed).")
    say()
    say("The defaults were tuned on seeds 0-19 of this scene (section 3 uses seeds 0-7). "
        f"Held-out check, full pipeline, seeds 1000-{999 + n_seeds} (never used in tuning):")
    say()
    say("| SNR | (a) Pd | (a) false/Mpx-win | no verification (previous default) Pd | "
        "false/Mpx-win |")
    say("|---|---|---|---|---|")
    for snr in (2.0, 3.0, 4.0):
        a = run_scene(full_pipeline, "wan2008", snr, range(1000, 1000 + n_seeds), cfg)
        p = run_scene(full_pipeline, "wan2008", snr, range(1000, 1000 + n_seeds),
                      with_(cfg, **previous))
        say(f"| {snr:g} | {fmt(a['pd'])} | {fmt(a['false_per_mpx_window'], 1)} | "
            f"{fmt(p['pd'])} | {fmt(p['false_per_mpx_window'], 1)} |")
    say()
    say("## 2. Structured clutter scene (`clutter` preset: drifting clouds, bright tilted "
        "horizon, 30 hot pixels; speeds 0.5-1.5 px/frame)")
    say()
    say("| SNR | (a) Pd | (a) false/Mpx-win | (b) Pd | (b) false/Mpx-frame | (c) Pd | "
        "(c) false/Mpx-win |")
    say("|---|---|---|---|---|---|---|")
    for snr in (3.0, 4.0, 6.0):
        a = run_scene(full_pipeline, "clutter", snr, few, cfg)
        b = run_scene(single_frame_tophat, "clutter", snr, range(min(n_seeds, 3)), cfg)
        c = run_scene(max_projection_threshold, "clutter", snr, few, cfg)
        say(f"| {snr:g} | {fmt(a['pd'])} | {fmt(a['false_per_mpx_window'], 1)} | "
            f"{fmt(b['pd'])} | {fmt(b['false_per_mpx_window'], 1)} | {fmt(c['pd'])} | "
            f"{fmt(c['false_per_mpx_window'], 1)} |")
    say()
    say(f"{len(few)} seeds per row ((b): {min(n_seeds, 3)}).")
    say()
    say("## 3. Choices beyond the paper (wan2008, full pipeline, one option changed)")
    say()
    variants = [
        ("default (dp merit, decay 0.95, k 2.5, peak split 5 px, const. velocity 20 px, "
         "tolerance 5 px, min_score 3.5, matched-filter verification 6.5, resolve=cost)", {}),
        ("no verification (the previous default: k 3.5, max_deviation 5, tolerance 2, "
         "min_score 5)", previous),
        ("verify 6", dict(correlate__verify=6.0)),
        ("verify 7", dict(correlate__verify=7.0)),
        ("min_score 3.2", dict(correlate__min_score=3.2)),
        ("min_score 0 (every chain verified)", dict(correlate__min_score=0.0)),
        ("max_deviation 8, tolerance 3", dict(correlate__max_deviation=8.0,
                                              correlate__tolerance=3.0)),
        ("k 3.0 (with verification)", dict(detect__k=3.0)),
        ("k 2.2 (with verification)", dict(detect__k=2.2)),
        ("no peak split (the paper's groups only)", dict(fuse__peak_radius=0)),
        ("no verification, min_score 4.5", {**previous, "correlate__min_score": 4.5}),
        ("paper's max projection, window 5 (k 3.5, no verification)",
         dict(previous, combine__projection="max", detect__window=5)),
        ("paper's max projection, window 5, with verification",
         dict(combine__projection="max", detect__window=5)),
        ("no constant-velocity test", dict(correlate__constant_velocity=False)),
        ("resolve=all (literal eqs. 5-7, verified)", dict(correlate__resolve="all")),
        ("resolve=unique (paper's uniqueness, verified)", dict(correlate__resolve="unique")),
        ("no verification, no score test (min_score 0, k 3.5)",
         dict(previous, correlate__min_score=0.0)),
        ("paper-literal correlation (k 3.5, all, no CV, no score test, no verification)",
         dict(previous, correlate__resolve="all", correlate__constant_velocity=False,
              correlate__min_score=0.0)),
        ("dp_decay 0.9", dict(combine__dp_decay=0.9)),
        ("dp_radius 2 (follows up to 2 px/frame)", dict(combine__dp_radius=2)),
    ]
    say("| variant | Pd SNR 2 | false/Mpx-win SNR 2 | Pd SNR 3 | false/Mpx-win SNR 3 |")
    say("|---|---|---|---|---|")
    for name, kw in variants:
        v = with_(cfg, **kw)
        r2 = run_scene(full_pipeline, "wan2008", 2.0, few, v)
        r3 = run_scene(full_pipeline, "wan2008", 3.0, few, v)
        say(f"| {name} | {fmt(r2['pd'])} | {fmt(r2['false_per_mpx_window'], 1)} | "
            f"{fmt(r3['pd'])} | {fmt(r3['false_per_mpx_window'], 1)} |")
    say()
    say(f"{len(few)} seeds per cell.")
    say()
    say("## 4. Suppressor (full pipeline otherwise default): how the default was chosen")
    say()
    real = load_real()
    say("| suppressor | wan2008 SNR 3 Pd | false/Mpx-win | clutter SNR 4 Pd | false/Mpx-win | "
        "real Pd | real false/Mpx-win | real per sequence (detected/target-windows) |")
    say("|---|---|---|---|---|---|---|---|")
    for method, size in (("temporal", 9), ("tophat", 9), ("tophat", 5), ("maxmean", 9),
                         ("maxmedian", 9), ("none", 9)):
        v = with_(cfg, suppress__method=method, suppress__size=size)
        w3 = run_scene(full_pipeline, "wan2008", 3.0, few, v)
        cl = run_scene(full_pipeline, "clutter", 4.0, few, v)
        rr = run_real(real, v) if real else None
        label = method if method in ("temporal", "none") else f"{method} {size}"
        say(f"| {label} | {fmt(w3['pd'])} | {fmt(w3['false_per_mpx_window'], 1)} | "
            f"{fmt(cl['pd'])} | {fmt(cl['false_per_mpx_window'], 1)} | "
            + (f"{fmt(rr['pd'])} | {fmt(rr['false_per_mpx_window'], 1)} | "
               f"{rr['per_sequence']} |" if rr else "- | - | real data absent |"))
    say()
    if real:
        say("Real sequences (" + ", ".join(n for n, *_ in real) + "): "
            "gate 3 px for DAUB, 5 px for the others (their READMEs); the targets there "
            "move 0-0.3 px/frame, so the temporal background also removes much of them.")
    say()
    say("## 5. Throughput (full pipeline, in memory, default configuration)")
    say()
    say("| frames | size | frames/s |")
    say("|---|---|---|")
    for h, w in ((240, 320), (256, 256)):
        frames, _ = simulate("wan2008", snr=3, rng=0, n_frames=240, height=h, width=w)
        t0 = time.perf_counter()
        full_pipeline(frames, cfg)
        dt = time.perf_counter() - t0
        say(f"| 240 | {w}x{h} | {240 / dt:.0f} |")
    say()
    say(f"2 cores shared with other jobs while this ran: timings are noisy. Whole benchmark: "
        f"{time.perf_counter() - t_start:.0f} s.")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
