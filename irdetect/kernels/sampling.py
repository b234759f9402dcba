"""Track sums of the verification (``irdetect.verify``), compiled.

``track_sums`` replaces one ``cv2.remap`` per block of frames over maps of every
segment x hypothesis x frame (``x0 + vx dt + shift``, built with numpy): it walks each
hypothesis's straight track through the frames and samples it where it lies, so no map
is built and each segment's hypotheses are sampled from the same few cache lines.
"""

from __future__ import annotations

import numpy as np

from irdetect.kernels import jit


@jit
def _clamp(i, n):
    """The index i clamped to [0, n - 1] (a border pixel replicated)."""
    return min(max(i, 0), n - 1)


@jit
def track_sums(blocks, dts, shift, x0, y0, vx, vy, bilinear, cap, out):
    """sum_f min(S_f(x0 + vx dts[f] + shift[f, 0], y0 + vy dts[f] + shift[f, 1]), cap).

    Parameters
    ----------
    blocks : tuple of float32 ndarray (F_j, H, W)
        The frames S_f in blocks (F = sum F_j), C-contiguous.
    dts : float32 ndarray (F,)
        Each frame's time relative to the middle frame.
    shift : float32 ndarray (F, 2)
        Each frame's offset (x, y) added to the position (zeros: none).
    x0, y0 : float32 ndarray (n, hyp)
        Positions (x = column, y = row) at the middle frame.
    vx, vy : float32 ndarray (n, hyp) or (n, 1)
        Velocities, px/frame (one column: the same for every hypothesis of a row).
    bilinear : bool
        Bilinear interpolation, else the nearest pixel (round half to even, as OpenCV).
    cap : float32
        Each sample counts at most ``cap`` (inf: no cap).
    out : float32 ndarray (n, hyp)
        The sums, written in place.

    Notes
    -----
    Positions outside a frame take its border pixels' values (``cv2.BORDER_REPLICATE``);
    y is clipped to [0, H - 1] first, as the tall-image ``cv2.remap`` of the numpy code
    did (``tests/test_kernels.py`` keeps it as the reference). Sums are float32, frame by
    frame, so they agree with it to float32 rounding (about 1e-6 relative).
    """
    n, hyp = x0.shape
    one_v = vx.shape[1] == 1
    acc = np.zeros(hyp, np.float32)
    for i in range(n):
        acc[:] = 0
        f = 0
        for blk in blocks:
            h, w = blk.shape[1], blk.shape[2]
            for k in range(blk.shape[0]):
                img = blk[k]
                dt, sx, sy = dts[f], shift[f, 0], shift[f, 1]
                for j in range(hyp):
                    jv = 0 if one_v else j
                    x = x0[i, j] + vx[i, jv] * dt + sx
                    y = y0[i, j] + vy[i, jv] * dt + sy
                    y = min(max(y, np.float32(0)), np.float32(h - 1))
                    x = min(max(x, np.float32(-1)), np.float32(w))
                    if bilinear:
                        fx, fy = np.floor(x), np.floor(y)
                        ax, ay = x - fx, y - fy
                        ix, iy = int(fx), int(fy)
                        ix0, ix1 = _clamp(ix, w), _clamp(ix + 1, w)
                        iy1 = _clamp(iy + 1, h)
                        top = img[iy, ix0] * (1 - ax) + img[iy, ix1] * ax
                        bottom = img[iy1, ix0] * (1 - ax) + img[iy1, ix1] * ax
                        s = top * (1 - ay) + bottom * ay
                    else:
                        s = img[int(np.rint(y)), _clamp(int(np.rint(x)), w)]
                    acc[j] += min(s, cap)
                f += 1
        out[i, :] = acc
    return out


@jit
def patch_sums(blocks, dts, shift, x0, y0, vx, vy, radius, cap, out):
    """Nearest-pixel track sums of a (2 radius + 1)^2 grid of 1-px steps around each track.

    out[i, (dy + radius) (2 radius + 1) + dx + radius] = sum_f min(S_f(rint(x_f) + dx,
    rint(y_f) + dy), cap), x_f = x0[i] + vx[i] dts[f] + shift[f, 0] (y_f alike), for
    dx, dy in -radius..radius: the coarse stage of ``irdetect.verify.track_significance``
    (``track_sums`` with ``bilinear=False`` over the grid's hypotheses), each frame's
    samples read from one patch instead of one rounding per hypothesis.

    Parameters
    ----------
    blocks, dts, shift, cap
        As ``track_sums``.
    x0, y0, vx, vy : float32 ndarray (n,)
        Each track's centre (x = column, y = row) at the middle frame and velocity.
    radius : int
        The grid's half-width (1: 3 x 3).
    out : float32 ndarray (n, (2 radius + 1)^2)
        The sums, written in place; hypotheses in the order of ``np.meshgrid(d, d,
        indexing="ij")`` over (dx, dy), dx the slow index.

    Notes
    -----
    rint(x) + dx is rint(x + dx) except at exact half-pixel ties (round half to even),
    where the numpy code's hypothesis x + dx could take the pixel beside.
    """
    m = 2 * radius + 1
    acc = np.zeros(m * m, np.float32)
    for i in range(len(x0)):
        acc[:] = 0
        f = 0
        for blk in blocks:
            h, w = blk.shape[1], blk.shape[2]
            for k in range(blk.shape[0]):
                img = blk[k]
                dt = dts[f]
                x = x0[i] + vx[i] * dt + shift[f, 0]
                y = y0[i] + vy[i] * dt + shift[f, 1]
                x = min(max(x, np.float32(-1 - radius)), np.float32(w + radius))
                y = min(max(y, np.float32(-1 - radius)), np.float32(h + radius))
                rx, ry = int(np.rint(x)) - radius, int(np.rint(y)) - radius
                for a in range(m):
                    col = _clamp(rx + a, w)
                    for b in range(m):
                        acc[a * m + b] += min(img[_clamp(ry + b, h), col], cap)
                f += 1
        out[i, :] = acc
    return out


KERNELS = (track_sums, patch_sums)


def warm_up() -> None:
    """Compile or load the kernels for the types the verification passes (one and
    two or three blocks: the pipeline passes a block per window)."""
    f32 = np.float32
    block, a = np.zeros((1, 2, 2), f32), np.zeros((1, 1), f32)
    for blocks in ((block,), (block, block), (block, block, block)):
        dts, shift = np.zeros(len(blocks), f32), np.zeros((len(blocks), 2), f32)
        track_sums(blocks, dts, shift, a, a, a, a, True, f32(np.inf), np.zeros((1, 1), f32))
        patch_sums(blocks, dts, shift, a[0], a[0], a[0], a[0], 1, f32(np.inf),
                   np.zeros((1, 9), f32))
