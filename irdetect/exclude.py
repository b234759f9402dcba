"""Excluded pixels: where no detection, peak or region is reported.

A recording may carry what no detector should report: symbology burned into the video (a
time stamp and angles whose digits change every frame, a reticle), a part of the sensor's
housing or a rotor in the field of view. The user names those pixels once per run
(``ProcessConfig.exclude``, ``--exclude`` of ``process`` and ``track``); each entry is
either a rectangle ``"X0,Y0,X1,Y1"`` (px, x = column, y = row; the columns X0 .. X1 - 1
and rows Y0 .. Y1 - 1, clipped to the frame) or the path of an image of the frame's size
whose nonzero pixels are excluded. The stages still see every pixel (the suppression,
the noise estimates and the camera's registration run on whole frames); what lies in the
excluded pixels is dropped where it would be reported: the combined-frame path's fused
points and the per-frame path's peaks (``irdetect.pipeline.combined.front``), and the
tracker's regions (``irdetect.track.pipeline.track``), by the pixel of their position.
Nor are they clutter samples of the combined-frame path's operating level
(``Pending._scene_only``): an overlay's changing digits would set it.
"""

from __future__ import annotations

import os
import re

import cv2
import numpy as np

from irdetect.errors import InputError, check_input_file

_RECTANGLE = re.compile(r"^\s*(-?\d+)\s*,\s*(-?\d+)\s*,\s*(-?\d+)\s*,\s*(-?\d+)\s*$")


def read_exclusions(specs) -> list:
    """The entries of ``specs`` read: ``(x0, y0, x1, y1)`` tuples of int for rectangles,
    (H, W) bool arrays for mask images.

    Raises
    ------
    InputError
        A rectangle with X1 <= X0 or Y1 <= Y0, or an entry that is neither a rectangle
        nor a readable image file (named in the message).
    """
    out = []
    for spec in specs:
        spec = str(spec)
        m = _RECTANGLE.match(spec)
        if m:
            x0, y0, x1, y1 = (int(v) for v in m.groups())
            if x1 <= x0 or y1 <= y0:
                raise InputError(f"exclude rectangle {spec!r} is empty (X0,Y0,X1,Y1 with "
                                 "X1 > X0 and Y1 > Y0)")
            out.append((x0, y0, x1, y1))
            continue
        if not os.path.exists(spec) and re.fullmatch(r"[-\d\s,.]+", spec):
            raise InputError(f"exclude {spec!r}: a rectangle is X0,Y0,X1,Y1 in whole px")
        check_input_file(spec, "exclusion mask image")
        image = cv2.imread(spec, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError("not a readable image (an exclusion mask)", spec)
        if image.ndim == 3:
            image = image.max(axis=2)
        out.append(np.asarray(image) != 0)
    return out


def exclusion_mask(specs, shape) -> np.ndarray | None:
    """(H, W) bool mask of the excluded pixels (True: excluded) of frames of ``shape``
    (H, W); None when ``specs`` names none.

    Raises
    ------
    InputError
        As ``read_exclusions``, or a mask image whose size is not the frames'.
    """
    entries = read_exclusions(specs)
    if not entries:
        return None
    h, w = (int(v) for v in shape)
    mask = np.zeros((h, w), bool)
    for spec, entry in zip(specs, entries):
        if isinstance(entry, tuple):
            x0, y0, x1, y1 = entry
            mask[max(0, y0):max(0, y1), max(0, x0):max(0, x1)] = True
        elif entry.shape != (h, w):
            raise InputError(f"exclusion mask of {entry.shape[1]}x{entry.shape[0]} px for "
                             f"frames of {w}x{h}", spec)
        else:
            mask |= entry
    return mask


def excluded(mask: np.ndarray | None, x, y) -> np.ndarray:
    """Whether each point (x = column, y = row, px) lies in an excluded pixel (its nearest
    pixel; points outside the frame are not excluded)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if mask is None or x.size == 0:
        return np.zeros(x.shape, bool)
    h, w = mask.shape
    col, row = np.rint(x), np.rint(y)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    out = np.zeros(x.shape, bool)
    out[inside] = mask[row[inside].astype(np.intp), col[inside].astype(np.intp)]
    return out
