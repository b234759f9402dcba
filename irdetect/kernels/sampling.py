"""Track sums of the verification (``irdetect.verify``), compiled.

``patch_sums`` (the coarse stage's nearest-pixel grids), ``climb`` (the bilinear hill
climb, one chain at a time) and ``track_sums`` (the bilinear sums of the ring and local
tests) replace one ``cv2.remap`` per block of frames over maps of every segment x
hypothesis x frame (``x0 + vx dt + shift``, built with numpy): they walk each
hypothesis's straight track through the frames and sample it where it lies, so no map is
built and each chain's hypotheses are sampled from the same few cache lines.
"""

from __future__ import annotations

import numpy as np

from irdetect.kernels import jit


@jit
def _clamp(i, n):
    """The index i clamped to [0, n - 1] (a border pixel replicated)."""
    return min(max(i, 0), n - 1)


@jit
def _axis(x, n):
    """Bilinear sampling along one axis of n px: the two indices (clamped: a border
    pixel replicated) and the weight of the second, float32 (x clamped to [-1, n]
    first)."""
    x = min(max(x, np.float32(-1)), np.float32(n))
    fx = np.floor(x)
    i = int(fx)
    return _clamp(i, n), _clamp(i + 1, n), x - fx


@jit
def _row(y, h):
    """``_axis`` for a row coordinate, clipped to [0, H - 1] first (the rows of one frame
    only, as the tall-image ``cv2.remap`` of the numpy code)."""
    return _axis(min(max(y, np.float32(0)), np.float32(h - 1)), h)


@jit
def _bilinear(img, x, y):
    """img (H, W) at (x, y) bilinear (``_axis``, ``_row``); float32."""
    one = np.float32(1)
    ix0, ix1, ax = _axis(x, img.shape[1])
    iy0, iy1, ay = _row(y, img.shape[0])
    top = img[iy0, ix0] * (one - ax) + img[iy0, ix1] * ax
    bottom = img[iy1, ix0] * (one - ax) + img[iy1, ix1] * ax
    return top * (one - ay) + bottom * ay


@jit
def _track_sum(blocks, dts, shift, x0, y0, vx, vy, cap):
    """One hypothesis's bilinear track sum sum_f min(S_f(x0 + vx dts[f] + shift[f]), cap),
    frame by frame in float32 (as ``track_sums``)."""
    acc = np.float32(0)
    f = 0
    for blk in blocks:
        for k in range(blk.shape[0]):
            dt = dts[f]
            acc += min(_bilinear(blk[k], x0 + vx * dt + shift[f, 0], y0 + vy * dt + shift[f, 1]),
                       cap)
            f += 1
    return acc


@jit
def track_sums(blocks, dts, shift, x0, y0, vx, vy, cap, order, out):
    """sum_f min(S_f(x0 + vx dts[f] + shift[f, 0], y0 + vy dts[f] + shift[f, 1]), cap),
    bilinear, for every hypothesis of every row.

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
    cap : float32
        Each sample counts at most ``cap`` (inf: no cap).
    order : int64 ndarray (n,)
        The order in which to visit the rows (``row_order``).
    out : float32 ndarray (n, hyp)
        The sums, written in place.

    Notes
    -----
    Rows visited in order of their y at the middle frame (``row_order``) read the same
    cached rows of each frame one after the other (1.8-5.7x faster than in input order
    in a microbenchmark of random chains on 640x512 and 256x256 frames, which do not fit
    the cache 36 at a time); each row's sum is unchanged by the order. Positions outside a
    frame take its border pixels' values (``cv2.BORDER_REPLICATE``); y is clipped to
    [0, H - 1] first, as the tall-image ``cv2.remap`` of the numpy code did
    (``tests/test_kernels.py`` keeps it as the reference). Sums are float32, frame by
    frame (``_track_sum``), so they agree with it to float32 rounding (about 1e-6
    relative).
    """
    one_v = vx.shape[1] == 1
    for i in order:
        for j in range(x0.shape[1]):
            jv = 0 if one_v else j
            out[i, j] = _track_sum(blocks, dts, shift, x0[i, j], y0[i, j], vx[i, jv],
                                   vy[i, jv], cap)
    return out


@jit
def patch_sums(blocks, dts, shift, x0, y0, vx, vy, cap, order, out):
    """Nearest-pixel track sums of the 3 x 3 grid of 1-px steps around each of L
    starting points of each track.

    out[i, 9 l + 3 (dx + 1) + dy + 1] = sum_f min(S_f(rint(x_f) + dx, rint(y_f) + dy),
    cap), x_f = x0[i, l] + vx[i] dts[f] + shift[f, 0] (y_f alike), dx, dy in -1, 0, 1:
    the coarse stage of ``irdetect.verify.track_significance``, each frame's 9 samples
    read from one 3 x 3 patch instead of one rounding per hypothesis.

    Parameters
    ----------
    blocks, dts, shift, cap
        As ``track_sums``.
    x0, y0 : float32 ndarray (n, L)
        Each track's L starting points (x = column, y = row) at the middle frame (the
        verification's leads: the line moved ahead by 1, 3, 5, 7 frames).
    vx, vy : float32 ndarray (n,)
        Each track's velocity, px/frame.
    order : int64 ndarray (n,)
        The order in which to visit the tracks (``row_order``).
    out : float32 ndarray (n, 9 L)
        The sums, written in place; per starting point, hypotheses in the order of
        ``np.meshgrid(d, d, indexing="ij")`` over (dx, dy), dx the slow index.

    Notes
    -----
    rint(x) + dx is rint(x + dx) except at exact half-pixel ties (round half to even),
    where the numpy code's hypothesis x + dx could take the pixel beside. Each starting
    point's 9 sums stay in registers over the frames (1.8-3x faster than 9 sums in an
    array on chains saved from the pipeline).
    """
    n_l = x0.shape[1]
    for i in order:
        for l in range(n_l):
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = np.float32(0)
            f = 0
            for blk in blocks:
                h, w = blk.shape[1], blk.shape[2]
                for k in range(blk.shape[0]):
                    img = blk[k]
                    dt = dts[f]
                    x = x0[i, l] + vx[i] * dt + shift[f, 0]
                    y = y0[i, l] + vy[i] * dt + shift[f, 1]
                    x = min(max(x, np.float32(-2)), np.float32(w + 1))
                    y = min(max(y, np.float32(-2)), np.float32(h + 1))
                    rx, ry = int(np.rint(x)), int(np.rint(y))
                    c0, c1, c2 = _clamp(rx - 1, w), _clamp(rx, w), _clamp(rx + 1, w)
                    r0 = img[_clamp(ry - 1, h)]
                    r1 = img[_clamp(ry, h)]
                    r2 = img[_clamp(ry + 1, h)]
                    s0 += min(r0[c0], cap)
                    s1 += min(r1[c0], cap)
                    s2 += min(r2[c0], cap)
                    s3 += min(r0[c1], cap)
                    s4 += min(r1[c1], cap)
                    s5 += min(r2[c1], cap)
                    s6 += min(r0[c2], cap)
                    s7 += min(r1[c2], cap)
                    s8 += min(r2[c2], cap)
                    f += 1
            o = 9 * l
            out[i, o], out[i, o + 1], out[i, o + 2] = s0, s1, s2
            out[i, o + 3], out[i, o + 4], out[i, o + 5] = s3, s4, s5
            out[i, o + 6], out[i, o + 7], out[i, o + 8] = s6, s7, s8
    return out


@jit
def _grid_sums(blocks, dts, shift, xs, ys, vxs, vys, cap, out):
    """Bilinear track sums of the 9 tracks (xs[a] + vxs[a] dt, ys[b] + vys[b] dt), a, b
    in 0..2, written to out[3 a + b] (float32 (9,)): a 3 x 3 grid in position or in
    velocity, whose tracks share 3 columns and 3 rows per frame; the sums are
    ``_track_sum``'s, each axis's index and weight computed once per frame."""
    one = np.float32(1)
    out[:] = 0
    f = 0
    for blk in blocks:
        h, w = blk.shape[1], blk.shape[2]
        for k in range(blk.shape[0]):
            img = blk[k]
            dt = dts[f]
            for b in range(3):
                iy0, iy1, ay = _row(ys[b] + vys[b] * dt + shift[f, 1], h)
                top_row, bottom_row = img[iy0], img[iy1]
                for a in range(3):
                    ix0, ix1, ax = _axis(xs[a] + vxs[a] * dt + shift[f, 0], w)
                    top = top_row[ix0] * (one - ax) + top_row[ix1] * ax
                    bottom = bottom_row[ix0] * (one - ax) + bottom_row[ix1] * ax
                    out[3 * a + b] += min(top * (one - ay) + bottom * ay, cap)
            f += 1


@jit
def climb(blocks, dts, shift, c, v, z, rows, norm, steps, rounds, screen, cap):
    """The refinement of ``irdetect.verify.track_significance``: a bilinear hill climb of
    each row's track, in place.

    Parameters
    ----------
    blocks, dts, shift, cap
        As ``track_sums``.
    c, v : float64 ndarray (n, 2)
        Tracks' positions (x, y) at the middle frame and velocities (px/frame); updated.
    z : float64 ndarray (n,)
        Their statistics (track sum / ``norm``); updated.
    rows : int64 ndarray (m,)
        The rows to refine (those whose coarse statistic passed the screen), in the
        order to visit them (``row_order``).
    norm : float
        sigma sqrt(F).
    steps : float64 ndarray (S, 2)
        (position step px, velocity step px/frame) of each refinement stage: the 3 x 3
        grids are -1, 0, 1 steps along x and y (``verify._GRID``: hypothesis 3 a + b at
        (a - 1, b - 1) steps).
    rounds : int
        Rounds per stage at most.
    screen : float
        A row whose statistic falls under it after a stage is not refined further.

    Notes
    -----
    A round samples the 9 positions c + dc grid at velocity v and the 9 velocities
    v + dv grid at position c (``_grid_sums``: each grid's tracks share 3 columns and
    3 rows per frame), moves c and v to
    their bests (the first of equal ones, as ``argmax``) and sets z to the larger best;
    the stage ends when neither moved or after ``rounds`` rounds, when z is resampled at
    the new c, v. It replaces the numpy code's rounds over all rows at once (``_climb``,
    one ``cv2.remap`` per round), with the same sums row by row.
    """
    f32 = np.float32
    sums, vsums = np.empty(9, f32), np.empty(9, f32)
    xs, ys, vxs, vys = np.empty(3, f32), np.empty(3, f32), np.empty(3, f32), np.empty(3, f32)
    for i in rows:
        for s in range(len(steps)):
            dc, dv = steps[s, 0], steps[s, 1]
            moved = True
            for _ in range(rounds):
                cx, cy, vx, vy = c[i, 0], c[i, 1], v[i, 0], v[i, 1]
                for a in range(3):
                    xs[a], ys[a] = f32(cx + dc * (a - 1)), f32(cy + dc * (a - 1))
                    vxs[a], vys[a] = f32(vx), f32(vy)
                _grid_sums(blocks, dts, shift, xs, ys, vxs, vys, cap, sums)
                for a in range(3):
                    xs[a], ys[a] = f32(cx), f32(cy)
                    vxs[a], vys[a] = f32(vx + dv * (a - 1)), f32(vy + dv * (a - 1))
                _grid_sums(blocks, dts, shift, xs, ys, vxs, vys, cap, vsums)
                bc, bv = np.argmax(sums), np.argmax(vsums)
                z[i] = max(sums[bc], vsums[bv]) / norm
                c[i, 0], c[i, 1] = cx + dc * (bc // 3 - 1), cy + dc * (bc % 3 - 1)
                v[i, 0], v[i, 1] = vx + dv * (bv // 3 - 1), vy + dv * (bv % 3 - 1)
                moved = bc != 4 or bv != 4           # 4: the grids' centre, (0, 0)
                if not moved:
                    break
            if moved:
                z[i] = _track_sum(blocks, dts, shift, f32(c[i, 0]), f32(c[i, 1]),
                                  f32(v[i, 0]), f32(v[i, 1]), cap) / norm
            if z[i] < screen:
                break


KERNELS = (track_sums, patch_sums, climb)


def row_order(y) -> np.ndarray:
    """The order (int64) that visits tracks by their row y, so that each frame's rows
    stay cached from one track to the next (the kernels' ``order`` and ``rows``; numpy's
    sort, so numba need not compile one)."""
    return np.argsort(np.asarray(y), kind="stable").astype(np.int64)


def warm_up() -> None:
    """Compile or load the kernels for the types the verification passes (3 blocks:
    ``irdetect.verify`` pads fewer)."""
    f32 = np.float32
    a = np.zeros((1, 1), f32)
    blocks = (np.zeros((1, 2, 2), f32),) * 3
    dts, shift = np.zeros(3, f32), np.zeros((3, 2), f32)
    first = np.zeros(1, np.int64)
    track_sums(blocks, dts, shift, a, a, a, a, f32(np.inf), first, np.zeros((1, 1), f32))
    patch_sums(blocks, dts, shift, a, a, a[0], a[0], f32(np.inf), first, np.zeros((1, 9), f32))
    climb(blocks, dts, shift, np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(1),
          np.zeros(1, np.int64), 1.0, np.zeros((1, 2)), 1, 0.0, f32(np.inf))
