"""What the false tracks of the real folders follow: irdetect's defaults, track by track.

For every folder of ../shared/data/real (frames/ and truth.txt), ``irdetect process``'s
default configuration; every track the path rule calls false (it lies within 2 x gate of
the target in fewer than 80 % of its frames, bench_real's rule) gets one row: its
coordinates (scene: image minus the camera's offsets, or image), frames, speed, the
confirmed detections on it (within 3 px of its position at their window's middle frame),
their local SNR (``snr``), their distance from the target's true position, the share of
its frames within 2 x gate of the target, and the rms distance of its detections from its
line. One strip of image crops per false track (its first, middle and last detection's
middle frame, 48 x 48 px around the detection, each crop's grey levels stretched between
its 1st and 99.9th percentiles; a white mark where the truth puts the target when it lies
in the crop) is written beside the table: the evidence the rows' numbers summarise.

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

REAL = ROOT.parent / "shared" / "data" / "real"
#: the path rule of bench_real (issue 16): within 2 x gate in this share of the frames
PATH_SHARE = 0.8
#: a detection lies on a track within this distance (px) of its position
ON_TRACK_PX = 3.0
CROP = 48
SCALE = 2


def gate_of(name: str) -> float:
    """The scoring gate (px): 5 for the easy clips, 3 for the others (bench_real's)."""
    return 5.0 if name.startswith("easy") else 3.0


def false_tracks(out: dict, truth: np.ndarray, gate: float) -> list[dict]:
    """One dict per track of ``detect_sequence``'s output that the path rule calls false."""
    det, cam = out["detections"], out["camera"]
    mid = 0.5 * (det["frame_start"] + det["frame_end"])
    rows = []
    for tr in out["tracks"]:
        frames = np.arange(tr["frame_start"], tr["frame_end"] + 1)
        pos = track_positions(tr.reshape(1), frames, cam)[0]
        near = np.hypot(pos[:, 0] - truth["x"][frames], pos[:, 1] - truth["y"][frames])
        share = float((near <= 2 * gate).mean())
        if share >= PATH_SHARE:
            continue
        at = track_positions(tr.reshape(1), mid, cam)[0]
        on = np.hypot(det["x"] - at[:, 0], det["y"] - at[:, 1]) <= ON_TRACK_PX
        d, t = det[on], np.rint(mid[on]).astype(int)
        off = np.hypot(d["x"] - at[on, 0], d["y"] - at[on, 1])
        rows.append({"track": int(tr["track_id"]), "scene": bool(tr["scene"]),
                     "frames": (int(tr["frame_start"]), int(tr["frame_end"])),
                     "speed": float(np.hypot(tr["vx"], tr["vy"])), "detections": d,
                     "mid": t, "share": share,
                     "from_target": np.hypot(d["x"] - truth["x"][t], d["y"] - truth["y"][t]),
                     "rms": float(np.sqrt(np.mean(off ** 2))) if len(off) else float("nan")})
    return rows


def crop_strip(frames: np.ndarray, truth: np.ndarray, row: dict) -> np.ndarray:
    """The crops (uint8, CROP x SCALE high) of a false track's first, middle and last
    detection, side by side."""
    d, t = row["detections"], row["mid"]
    picks = sorted({0, len(d) // 2, len(d) - 1}) if len(d) else []
    h, w = frames.shape[1:]
    tiles = []
    for i in picks:
        x, y = int(round(d["x"][i])), int(round(d["y"][i]))
        x0, y0 = min(max(0, x - CROP // 2), w - CROP), min(max(0, y - CROP // 2), h - CROP)
        c = np.asarray(frames[t[i], y0:y0 + CROP, x0:x0 + CROP], np.float32)
        lo, hi = np.percentile(c, (1, 99.9))
        tile = np.clip((c - lo) * (255.0 / max(hi - lo, 1e-6)), 0, 255).astype(np.uint8)
        tile = cv2.cvtColor(cv2.resize(tile, None, fx=SCALE, fy=SCALE,
                                       interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
        cv2.circle(tile, (int((d["x"][i] - x0 + 0.5) * SCALE), int((d["y"][i] - y0 + 0.5) * SCALE)),
                   5 * SCALE, (0, 200, 255), 1)
        tx, ty = truth["x"][t[i]] - x0, truth["y"][t[i]] - y0
        if 0 <= tx < CROP and 0 <= ty < CROP:
            cv2.drawMarker(tile, (int((tx + 0.5) * SCALE), int((ty + 0.5) * SCALE)),
                           (255, 255, 255), cv2.MARKER_CROSS, 6 * SCALE, 1)
        tiles.append(tile)
        tiles.append(np.full((CROP * SCALE, 4, 3), 64, np.uint8))
    return np.hstack(tiles[:-1]) if tiles else np.zeros((CROP * SCALE, 1, 3), np.uint8)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "false-tracks.md"))
    args = ap.parse_args(argv)
    out_path = Path(args.out)
    lines, strips, n_tracks = [], [], 0
    folders = sorted(p for p in REAL.iterdir() if (p / "truth.txt").is_file())
    for folder in folders:
        with open_sequence(folder / "frames") as src:
            frames = src[:]
        truth = read_point_annotations(folder / "truth.txt", len(frames))
        out = detect_sequence(frames)
        n_tracks += len(out["tracks"])
        for row in false_tracks(out, truth, gate_of(folder.name)):
            d = row["detections"]
            snr = f"{d['snr'].min():.1f}-{d['snr'].max():.1f}" if len(d) else "–"
            far = (f"{row['from_target'].min():.0f}-{row['from_target'].max():.0f}"
                   if len(d) else "–")
            lines.append(f"| {folder.name} | {row['track']} | "
                         f"{'scene' if row['scene'] else 'image'} | "
                         f"{row['frames'][0]}-{row['frames'][1]} | {row['speed']:.2f} | "
                         f"{len(d)} | {snr} | {far} | {row['share']:.2f} | {row['rms']:.2f} |")
            label = f"{folder.name} track {row['track']}"
            strip = crop_strip(frames, truth, row)
            band = np.full((18, max(strip.shape[1], 8 * len(label)), 3), 0, np.uint8)
            cv2.putText(band, label, (2, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
            pad = np.zeros((CROP * SCALE, band.shape[1] - strip.shape[1], 3), np.uint8)
            strips.append(np.vstack([band, np.hstack([strip, pad])]))
            print(lines[-1], flush=True)
    png = out_path.with_suffix(".png")
    if strips:
        width = max(s.shape[1] for s in strips)
        sheet = np.vstack([np.hstack([s, np.zeros((s.shape[0], width - s.shape[1], 3),
                                                  np.uint8)]) for s in strips])
        ok, buf = cv2.imencode(".png", sheet)
        tmp = png.with_name(png.name + ".tmp")
        tmp.write_bytes(buf.tobytes())
        os.replace(tmp, png)
    text = [
        "# What the false tracks of the real folders follow",
        "",
        f"Produced by `scripts/false_tracks.py` ({datetime.date.today()}; "
        f"{os.cpu_count()} cores, {platform.machine()}). Data: ../shared/data/real. "
        "irdetect's default configuration; a track is false when it lies within 2 x gate "
        f"(3 px DAUB and istd640, 5 px easy1 / easy3) of the target in fewer than "
        f"{PATH_SHARE:.0%} of its frames (bench_real's path rule). {len(lines)} of "
        f"{n_tracks} tracks over {len(folders)} folders.",
        "",
        "Columns: coordinates (scene: image minus the camera's offsets `/camera`; image), "
        "its frames, speed (px/frame, in its coordinates), the confirmed detections on it "
        f"(within {ON_TRACK_PX:g} px of its position at their window's middle frame), their "
        "local SNR, their distance from the target's true position in their middle frame, "
        "the share of its frames within 2 x gate of the target, and the rms distance of its "
        "detections from its line.",
        "",
        f"Crops: [{png.name}]({png.name}), one strip per row below, in order (48 x 48 px "
        "around the first, middle and last detection, at their middle frame; orange circle: "
        "the detection; white cross: the target's true position when it lies in the crop).",
        "",
        "| folder | track | coordinates | frames | speed (px/frame) | detections on it | "
        "their SNR | from the target (px) | share within 2 x gate | rms about its line (px) |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *lines, ""]
    tmp = out_path.with_name(out_path.name + ".tmp")
    tmp.write_text("\n".join(text))
    os.replace(tmp, out_path)
    print(f"wrote {out_path} and {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
