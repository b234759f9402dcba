"""What the false tracks of the real folders follow: irdetect's defaults, track by track.

For every folder of ../shared/data/real (frames/ and truth.txt), ``irdetect process``'s
default configuration; every track the path rule calls false (it lies within 2 x gate of
the target in fewer than 80 % of its frames, or another track follows the target over the
same frames with a larger share: bench_real's rule) gets one row: its
coordinates (scene: image minus the camera's offsets, or image), frames, speed, the
confirmed detections on it (within 3 px of its position at their window's middle frame),
their local SNR (``snr``), their distance from the target's true position, the share of
its frames within 2 x gate of the target, and the rms distance of its detections from its
line. One strip of image crops per false track (its first, middle and last detection's
middle frame, 48 x 48 px around the detection, each crop's grey levels stretched between
its 1st and 99.9th percentiles; a white mark where the truth puts the target when it lies
in the crop) is written beside the table: the evidence the rows' numbers summarise.

The same for ``irdetect track`` (the frame-by-frame tracker, defaults): on every folder
each track the same rule calls false (by its points' distance from the target), and
on the clutter-only crops of bench_tracking (each folder's largest strip clear of the
target's path: every track there is false unless the strip holds an object the truth does
not name), with its points' speed (a line fitted to them, in the image), local SNR (their
``grey``), distance from the target and rms about that line.

Usage: .venv/bin/python scripts/false_tracks.py [--out docs/results/false-tracks.md]
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from irdetect.initiate import track_positions  # noqa: E402
from irdetect.io import open_sequence, read_point_annotations  # noqa: E402
from irdetect.pipeline import detect_sequence  # noqa: E402
from irdetect.track import track  # noqa: E402

sys.path.insert(0, str(ROOT / "scripts"))
# scripts/: bench_real's gate and path rule, bench_tracking's gate and clutter-only strip
from bench_real import PATH_SHARE, gate_of, path_rule  # noqa: E402
from bench_tracking import _crop, _gate  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
#: a detection lies on a track within this distance (px) of its position
ON_TRACK_PX = 3.0
CROP = 48
SCALE = 2


def false_tracks(out: dict, truth: np.ndarray, gate: float) -> list[dict]:
    """One dict per track of ``detect_sequence``'s output that the path rule calls false
    (``bench_real.score_tracks``: off the target, or a second track on it at once)."""
    det, cam = out["detections"], out["camera"]
    mid = 0.5 * (det["frame_start"] + det["frame_end"])
    paths = []
    for tr in out["tracks"]:
        frames = np.arange(tr["frame_start"], tr["frame_end"] + 1)
        paths.append(np.column_stack([frames, track_positions(tr.reshape(1), frames, cam)[0]]))
    shares, right = path_rule(paths, truth, gate)
    rows = []
    for tr, share in zip(out["tracks"][~right], shares[~right]):
        at = track_positions(tr.reshape(1), mid, cam)[0]
        on = np.hypot(det["x"] - at[:, 0], det["y"] - at[:, 1]) <= ON_TRACK_PX
        d, t = det[on], np.rint(mid[on]).astype(int)
        off = np.hypot(d["x"] - at[on, 0], d["y"] - at[on, 1])
        rows.append({"track": int(tr["track_id"]), "scene": bool(tr["scene"]),
                     "frames": (int(tr["frame_start"]), int(tr["frame_end"])),
                     "speed": float(np.hypot(tr["vx"], tr["vy"])), "detections": d,
                     "mid": t, "share": float(share),
                     "from_target": np.hypot(d["x"] - truth["x"][t], d["y"] - truth["y"][t]),
                     "rms": float(np.sqrt(np.mean(off ** 2))) if len(off) else float("nan")})
    return rows


def crop_strip(frames: np.ndarray, truth: np.ndarray, x, y, t) -> np.ndarray:
    """The crops (uint8, CROP x SCALE high) of a false track's first, middle and last
    point (x, y px in frame t; arrays in time order), side by side."""
    picks = sorted({0, len(x) // 2, len(x) - 1}) if len(x) else []
    h, w = frames.shape[1:]
    tiles = []
    for i in picks:
        cx, cy = int(round(x[i])), int(round(y[i]))
        x0 = min(max(0, cx - CROP // 2), max(0, w - CROP))
        y0 = min(max(0, cy - CROP // 2), max(0, h - CROP))
        c = np.asarray(frames[t[i], y0:y0 + CROP, x0:x0 + CROP], np.float32)
        lo, hi = np.percentile(c, (1, 99.9))
        tile = np.clip((c - lo) * (255.0 / max(hi - lo, 1e-6)), 0, 255).astype(np.uint8)
        tile = cv2.resize(tile, (CROP * SCALE, CROP * SCALE), interpolation=cv2.INTER_NEAREST)
        tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2BGR)
        cv2.circle(tile, (int((x[i] - x0 + 0.5) * SCALE), int((y[i] - y0 + 0.5) * SCALE)),
                   5 * SCALE, (0, 200, 255), 1)
        tx, ty = truth["x"][t[i]] - x0, truth["y"][t[i]] - y0
        if 0 <= tx < CROP and 0 <= ty < CROP:
            cv2.drawMarker(tile, (int((tx + 0.5) * SCALE), int((ty + 0.5) * SCALE)),
                           (255, 255, 255), cv2.MARKER_CROSS, 6 * SCALE, 1)
        tiles.append(tile)
        tiles.append(np.full((CROP * SCALE, 4, 3), 64, np.uint8))
    return np.hstack(tiles[:-1]) if tiles else np.zeros((CROP * SCALE, 1, 3), np.uint8)


def tracker_false_tracks(points: np.ndarray, truth: np.ndarray, gate: float,
                         offset=(0, 0)) -> list[dict]:
    """One dict per track of ``irdetect track``'s points (``tables.TRACK_POINT``, image
    px of frames cut at ``offset`` = (x0, y0)) that the path rule calls false (fewer
    than PATH_SHARE of its points within 2 x gate of the target, or a second track on
    it at once)."""
    ids = np.unique(points["track_id"])
    each = [points[points["track_id"] == tid] for tid in ids]
    each = [p[np.argsort(p["frame"])] for p in each]
    paths = [np.column_stack([p["frame"], p["x"] + offset[0], p["y"] + offset[1]])
             for p in each]
    shares, right = path_rule(paths, truth, gate)
    rows = []
    for i in np.flatnonzero(~right):
        tid, share, p = ids[i], shares[i], each[i]
        f, x, y = p["frame"], paths[i][:, 1], paths[i][:, 2]
        far = np.hypot(x - truth["x"][f], y - truth["y"][f])
        a = np.column_stack([f, np.ones(len(f))])
        fit = [np.linalg.lstsq(a, c, rcond=None)[0] for c in (x, y)] if len(f) > 1 else None
        rms = (float(np.sqrt(np.mean((a @ fit[0] - x) ** 2 + (a @ fit[1] - y) ** 2)))
               if fit else float("nan"))
        rows.append({"track": int(tid), "frames": (int(f[0]), int(f[-1])), "n": len(p),
                     "speed": float(np.hypot(fit[0][0], fit[1][0])) if fit else 0.0,
                     "grey": p["grey"], "from_target": far, "share": float(share), "rms": rms,
                     "x": x, "y": y, "t": f})
    return rows


def _strip(frames, truth, label, x, y, t) -> np.ndarray:
    """A labelled strip of crops."""
    strip = crop_strip(frames, truth, x, y, t)
    band = np.zeros((18, max(strip.shape[1], 8 * len(label)), 3), np.uint8)
    cv2.putText(band, label, (2, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
    pad = np.zeros((CROP * SCALE, band.shape[1] - strip.shape[1], 3), np.uint8)
    return np.vstack([band, np.hstack([strip, pad])])


def _write_sheet(path: Path, strips: list[np.ndarray]) -> None:
    if not strips:
        return
    width = max(s.shape[1] for s in strips)
    sheet = np.vstack([np.hstack([s, np.zeros((s.shape[0], width - s.shape[1], 3), np.uint8)])
                       for s in strips])
    ok, buf = cv2.imencode(".png", sheet)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buf.tobytes())
    os.replace(tmp, path)


def _range(v, digits=0) -> str:
    return f"{np.min(v):.{digits}f}-{np.max(v):.{digits}f}" if len(v) else "–"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "false-tracks.md"))
    args = ap.parse_args(argv)
    out_path = Path(args.out)
    png, png_track = out_path.with_suffix(".png"), out_path.with_name(out_path.stem + "-track.png")
    lines, strips, n_tracks = [], [], 0
    t_lines, t_strips, n_tracker, n_crop_frames = [], [], 0, 0
    n_false = {"whole": 0, "crop": 0}
    folders = sorted(p for p in REAL.iterdir() if (p / "truth.txt").is_file())
    for folder in folders:
        with open_sequence(folder / "frames") as src:
            frames = src[:]
        truth = read_point_annotations(folder / "truth.txt", len(frames))
        gate = gate_of(folder.name)                     # bench_real's, for process
        out = detect_sequence(frames)
        n_tracks += len(out["tracks"])
        for row in false_tracks(out, truth, gate):
            d = row["detections"]
            lines.append(f"| {folder.name} | {row['track']} | "
                         f"{'scene' if row['scene'] else 'image'} | "
                         f"{row['frames'][0]}-{row['frames'][1]} | {row['speed']:.2f} | "
                         f"{len(d)} | {_range(d['snr'], 1)} | {_range(row['from_target'])} | "
                         f"{row['share']:.2f} | {row['rms']:.2f} |")
            strips.append(_strip(frames, truth, f"{folder.name} track {row['track']}",
                                 d["x"], d["y"], row["mid"]))
            print(lines[-1], flush=True)
        # the frame-by-frame tracker: the whole folder, then its clutter-only strip
        points, tracks = track(frames)
        n_tracker += len(tracks)
        cuts = [("whole", (0, 0), frames)]
        box = _crop(truth, frames.shape[1:])
        if box is not None:
            a, b, c, e = box
            cuts.append((f"crop {e - c}x{b - a} at x {c}, y {a}", (c, a),
                         np.ascontiguousarray(frames[:, a:b, c:e])))
            n_crop_frames += len(frames)
        for where, offset, clip in cuts:
            pts = points if where == "whole" else track(clip)[0]
            for row in tracker_false_tracks(pts, truth, _gate(folder.name), offset):
                n_false[where.split()[0]] += 1
                t_lines.append(f"| {folder.name} | {where} | {row['track']} | "
                               f"{row['frames'][0]}-{row['frames'][1]} | {row['n']} | "
                               f"{row['speed']:.2f} | {_range(row['grey'], 1)} | "
                               f"{_range(row['from_target'])} | {row['share']:.2f} | "
                               f"{row['rms']:.2f} |")
                t_strips.append(_strip(frames, truth, f"{folder.name} {where.split()[0]} "
                                       f"track {row['track']}", row["x"], row["y"], row["t"]))
                print(t_lines[-1], flush=True)
    _write_sheet(png, strips)
    _write_sheet(png_track, t_strips)
    text = [
        "# What the false tracks of the real folders follow",
        "",
        f"Produced by `scripts/false_tracks.py` ({datetime.date.today()}; "
        f"{os.cpu_count()} cores, {platform.machine()}). Data: ../shared/data/real. "
        "The default configuration of each command.",
        "",
        "## `irdetect process`",
        "",
        "A track is false when it lies within 2 x gate (bench_real's: 3 px DAUB, 5 px the "
        f"others) of the target in fewer than {PATH_SHARE:.0%} of its frames, or another "
        "track follows the target over the same frames with a larger share (its path "
        f"rule): {len(lines)} of {n_tracks} tracks over {len(folders)} folders.",
        "",
        "Columns: coordinates (scene: image minus the camera's offsets `/camera`; image), "
        "its frames, speed (px/frame, in its coordinates), the confirmed detections on it "
        f"(within {ON_TRACK_PX:g} px of its position at their window's middle frame), their "
        "local SNR, their distance from the target's true position in their middle frame, "
        "the share of its frames within 2 x gate of the target, and the rms distance of its "
        "detections from its line.",
        "",
        f"Crops: [{png.name}]({png.name}), one strip per row, in order (48 x 48 px "
        "around the first, middle and last detection, at their middle frame; orange circle: "
        "the detection; white cross: the target's true position when it lies in the crop).",
        "",
        "| folder | track | coordinates | frames | speed (px/frame) | detections on it | "
        "their SNR | from the target (px) | share within 2 x gate | rms about its line (px) |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *lines,
        "",
        "## `irdetect track`",
        "",
        f"A track is false when fewer than {PATH_SHARE:.0%} of its points lie within 2 x gate "
        f"(bench_tracking's: 5 px easy1 / easy3, 3 px the others) of the target, or another "
        "track's points follow it over the same frames with a larger share: "
        f"{n_false['whole']} of {n_tracker} tracks on the {len(folders)} folders, and "
        f"{n_false['crop']} on their "
        f"clutter-only crops ({n_crop_frames} frames; bench_tracking's strips, where every "
        "track counts as false).",
        "",
        "Columns: the folder or its crop, the track's id, frames, points, speed (a line fitted "
        "to its points in the image, px/frame), its points' local SNR (`grey`), distance from "
        "the target's true position, the share within 2 x gate, the rms about the line.",
        "",
        f"Crops: [{png_track.name}]({png_track.name}), as above, around its first, middle "
        "and last point.",
        "",
        "| folder | where | track | frames | points | speed (px/frame) | their SNR | "
        "from the target (px) | share within 2 x gate | rms about its line (px) |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *t_lines, ""]
    tmp = out_path.with_name(out_path.name + ".tmp")
    tmp.write_text("\n".join(text))
    os.replace(tmp, out_path)
    print(f"wrote {out_path}, {png} and {png_track}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
