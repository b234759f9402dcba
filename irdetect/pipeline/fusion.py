"""The fusion of the two paths' detections and the track initiation on them.

(filled in below: ``initiate_tracks`` is the hand-off to Hough + subtractive clustering.)
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from irdetect.config import ProcessConfig


def initiate_tracks(detections: np.ndarray, config: ProcessConfig,
                    camera=None) -> np.ndarray:
    """Tracks from the confirmed detections (``irdetect.initiate``), TRACK table.

    With the camera's offsets (a CAMERA table) of a moving camera, tracks are initiated
    twice: on the image positions (a target the camera holds, whose scene path is the
    camera's) and on the scene positions, image minus offset (a target straight in the
    scene under a panning or shaking camera; ``scene`` rows, their positions follow the
    camera, ``irdetect.initiate.track_positions``). Of two tracks that claim mostly the
    same detections the one whose positions lie nearer them is kept.
    """
    from irdetect.initiate import camera_at, initiate_detections

    params = asdict(config.initiate)
    image = initiate_detections(detections, **params)
    if camera is None or len(camera) < 2 or len(detections) < 2 or not (
            np.ptp(camera["dx"]) >= MOVING_PX or np.ptp(camera["dy"]) >= MOVING_PX):
        return image
    t = 0.5 * (detections["frame_start"] + detections["frame_end"])
    scene_det = detections.copy()
    off = camera_at(camera, t)
    scene_det["x"] -= off[:, 0]
    scene_det["y"] -= off[:, 1]
    scene = initiate_detections(scene_det, **params)
    if len(scene):
        # into the image coordinates of each track's first frame
        start = camera_at(camera, scene["frame_start"])
        scene["x0"] += start[:, 0]
        scene["y0"] += start[:, 1]
        scene["rho"] += (start[:, 0] * np.cos(scene["theta"])
                         + start[:, 1] * np.sin(scene["theta"]))
        scene["scene"] = True
    both = np.concatenate([image, scene])
    keep = _distinct_tracks(both, detections, camera, float(config.initiate.gate))
    out = both[keep]
    out["track_id"] = np.arange(len(out))
    return out


#: the camera's offsets over the sequence spanning this many px make it "moving" for the
#: track initiation (scene tracks are tried beside the image ones)
MOVING_PX = 1.0


def _distinct_tracks(tracks, detections, camera, gate: float) -> np.ndarray:
    """Indices of tracks to keep: of two whose supporting detections (those of their
    span within ``gate`` px of their positions) overlap by half or more, the one with
    more support, then the smaller mean distance, wins."""
    from irdetect.initiate import track_positions

    if len(tracks) < 2:
        return np.arange(len(tracks))
    t = 0.5 * (detections["frame_start"] + detections["frame_end"])
    pos = track_positions(tracks, t, camera)                              # (n, d, 2)
    dist = np.hypot(pos[..., 0] - detections["x"][None], pos[..., 1] - detections["y"][None])
    inside = (t[None] >= tracks["frame_start"][:, None]) & (t[None] <= tracks["frame_end"][:, None])
    support = inside & (dist <= gate)
    count = support.sum(1)
    mean = np.where(count > 0, (dist * support).sum(1) / np.maximum(count, 1), np.inf)
    order = np.lexsort((mean, -count))
    kept: list[int] = []
    for i in order:                     # a loop over the tracks (a handful)
        if count[i] == 0 and kept:
            continue
        if any((support[i] & support[j]).sum() >= 0.5 * min(count[i], count[j]) > 0
               for j in kept):
            continue
        kept.append(int(i))
    return np.sort(np.array(kept, dtype=np.int64))
