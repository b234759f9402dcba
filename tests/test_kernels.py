"""The compiled kernels (``irdetect.kernels``) against the numpy / OpenCV code they
replaced, kept here as the reference; their cache; threads. Blocks go in as the
verification passes them (``verify._three``: the one type each kernel is compiled for)."""

import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from irdetect.io import write_sequence
from irdetect.kernels.peaks import local_maxima
from irdetect.kernels.sampling import climb, patch_sums, row_order, track_sums
from irdetect.pipeline import detect_sequence
from irdetect.simulate import simulate
from irdetect.verify import _three

ROOT = Path(__file__).resolve().parents[1]
f32 = np.float32


def remap_sums(blocks, dts, x0, y0, vx, vy, bilinear, shift, cap):
    """The numpy / OpenCV track sums the kernel replaced: maps x0 + vx dt + shift per
    frame, y clipped to the frame, one ``cv2.remap`` (border replicated) per frame."""
    frames = np.concatenate(blocks)
    h = frames.shape[1]
    total = np.zeros(x0.shape, f32)
    inter = cv2.INTER_LINEAR if bilinear else cv2.INTER_NEAREST
    for f, dt in enumerate(dts):
        mx = (vx * dt + x0 + shift[f, 0]).astype(f32)
        my = np.clip((vy * dt + y0 + shift[f, 1]).astype(f32), 0, h - 1)
        s = cv2.remap(frames[f], mx, my, inter, borderMode=cv2.BORDER_REPLICATE)
        total += np.minimum(s, cap)
    return total


def _tracks(rng, n, hyp, h, w, per_hypothesis=True):
    x0 = rng.uniform(-4, w + 4, (n, 1)) + rng.uniform(-2, 2, (n, hyp))
    y0 = rng.uniform(-4, h + 4, (n, 1)) + rng.uniform(-2, 2, (n, hyp))
    v = rng.uniform(-1.5, 1.5, (2, n, hyp if per_hypothesis else 1))
    return [np.ascontiguousarray(a, f32) for a in (x0, y0, v[0], v[1])]


@pytest.mark.parametrize("n_blocks", [1, 3])
def test_track_sums_match_remap(n_blocks):
    rng = np.random.default_rng(n_blocks)
    h, w = 40, 56
    blocks = tuple(rng.normal(size=(6, h, w)).astype(f32) for _ in range(n_blocks))
    n_f = 6 * n_blocks
    dts = (np.arange(n_f) - (n_f - 1) / 2).astype(f32)
    shift = rng.uniform(-3, 3, (n_f, 2)).astype(f32)
    for per_hypothesis in (True, False):
        x0, y0, vx, vy = _tracks(rng, 30, 7, h, w, per_hypothesis)
        for cap in (f32(np.inf), f32(1.5)):
            got = track_sums(_three(blocks), dts, shift, x0, y0, vx, vy, cap,
                             row_order(y0[:, 0]), np.zeros(x0.shape, f32))
            want = remap_sums(blocks, dts, x0, y0, np.broadcast_to(vx, x0.shape),
                              np.broadcast_to(vy, x0.shape), True, shift, cap)
            np.testing.assert_allclose(got, want, atol=2e-5 * n_f)
            if cap < np.inf:
                assert (got <= cap * n_f + 1e-4).all()


def test_patch_sums_are_the_grid_of_nearest_track_sums():
    rng = np.random.default_rng(3)
    h, w = 30, 45
    blocks = tuple(rng.normal(size=(5, h, w)).astype(f32) for _ in range(2))
    dts = (np.arange(10) - 4.5).astype(f32)
    shift = rng.uniform(-2, 2, (10, 2)).astype(f32)
    x0, y0, vx, vy = _tracks(rng, 50, 2, h, w)             # 2 starting points per track
    vx, vy = vx[:, 0].copy(), vy[:, 0].copy()
    got = patch_sums(_three(blocks), dts, shift, x0, y0, vx, vy, f32(2.0), row_order(y0[:, 0]),
                     np.zeros((50, 18), f32))
    d = np.arange(-1, 2, dtype=f32)
    gx, gy = (g.ravel() for g in np.meshgrid(d, d, indexing="ij"))
    for lead in range(2):
        want = remap_sums(blocks, dts, x0[:, lead, None] + gx, y0[:, lead, None] + gy,
                          np.repeat(vx[:, None], 9, 1), np.repeat(vy[:, None], 9, 1), False,
                          shift, f32(2.0))
        np.testing.assert_allclose(got[:, 9 * lead:9 * (lead + 1)], want, atol=1e-5)


def numpy_climb(blocks, dts, shift, c, v, z, rows, norm, steps, grid, rounds, screen, cap):
    """The numpy hill climb the kernel replaced: each round samples all rows' 9 positions
    and 9 velocities at once (``remap_sums``) and moves them to their ``argmax``."""
    live = rows
    for dc, dv in steps:
        moving = live
        for _ in range(rounds):
            if len(moving) == 0:
                break
            r = moving
            cc = np.concatenate([c[r, None] + dc * grid, np.repeat(c[r, None], 9, 1)], 1)
            vv = np.concatenate([np.repeat(v[r, None], 9, 1), v[r, None] + dv * grid], 1)
            total = remap_sums(blocks, dts, cc[..., 0], cc[..., 1], vv[..., 0], vv[..., 1],
                               True, shift, cap)
            bc, bv = total[:, :9].argmax(1), 9 + total[:, 9:].argmax(1)
            k = np.arange(len(r))
            z[r] = np.maximum(total[k, bc], total[k, bv]) / norm
            c[r], v[r] = cc[k, bc], vv[k, bv]
            moving = r[(grid[bc] != 0).any(1) | (grid[bv - 9] != 0).any(1)]
        if len(moving):
            z[moving] = remap_sums(blocks, dts, c[moving, None, 0], c[moving, None, 1],
                                   v[moving, None, 0], v[moving, None, 1], True, shift,
                                   cap)[:, 0] / norm
        live = live[z[live] >= screen]


def test_climb_matches_the_numpy_rounds():
    # targets planted on noise, chains started up to 2 px and 0.15 px/frame off their
    # tracks: the kernel climbs to the same tracks as the numpy rounds did
    from irdetect.verify import _GRID, _REFINE, REFINE_ROUNDS
    rng = np.random.default_rng(8)
    h, w, n_f = 48, 64, 24
    frames = rng.normal(size=(n_f, h, w)).astype(f32)
    dts = (np.arange(n_f) - (n_f - 1) / 2).astype(f32)
    yy, xx = np.mgrid[:h, :w]
    truth = np.column_stack([rng.uniform(10, w - 10, 6), rng.uniform(10, h - 10, 6)])
    speed = rng.uniform(-0.6, 0.6, (6, 2))
    for f, dt in enumerate(dts):
        for (x, y), (vx, vy) in zip(truth, speed):
            frames[f] += 3.0 * np.exp(-((xx - x - vx * dt) ** 2 + (yy - y - vy * dt) ** 2) / 2.0)
    blocks = (frames[:12], frames[12:])
    shift = np.zeros((n_f, 2), f32)
    c0 = truth + rng.uniform(-2, 2, truth.shape)
    v0 = speed + rng.uniform(-0.15, 0.15, speed.shape)
    rows = np.arange(6, dtype=np.int64)
    norm = float(np.sqrt(n_f))
    steps = np.array(_REFINE, np.float64)
    got = [c0.copy(), v0.copy(), np.zeros(6)]
    want = [c0.copy(), v0.copy(), np.zeros(6)]
    climb(_three(blocks), dts, shift, *got, rows, norm, steps, REFINE_ROUNDS, 0.5, f32(8))
    numpy_climb(blocks, dts, shift, *want, rows, norm, steps, _GRID, REFINE_ROUNDS, 0.5,
                f32(8))
    np.testing.assert_allclose(got[0], want[0], atol=1e-6)
    np.testing.assert_allclose(got[1], want[1], atol=1e-6)
    np.testing.assert_allclose(got[2], want[2], rtol=1e-5)
    assert np.abs(got[0] - c0).max() > 0.4                   # the chains did climb
    assert (got[2] > 5).all()


@pytest.mark.parametrize("seed", range(3))
def test_local_maxima_match_the_dilation(seed):
    rng = np.random.default_rng(seed)
    m = cv2.GaussianBlur(rng.normal(size=(37, 53)).astype(f32), (0, 0), 1.0)
    m[5, 7:9] = 3.0                          # a plateau: both pixels are maxima
    peak = (m >= 0.3) & (m >= cv2.dilate(m, np.ones((3, 3), np.uint8)))
    peak[[0, -1], :] = peak[:, [0, -1]] = False
    ys, xs = np.empty(m.size, np.int64), np.empty(m.size, np.int64)
    n = local_maxima(m, f32(0.3), ys, xs)
    want_y, want_x = np.nonzero(peak)
    assert n == len(want_y) > 3
    np.testing.assert_array_equal(ys[:n], want_y)
    np.testing.assert_array_equal(xs[:n], want_x)


def test_one_and_two_threads_give_the_same_tables():
    # the kernels release the GIL: the correlation of a triple runs beside the next
    # windows' front end on the other core; results must not depend on it
    # (100 frames: 8 windows and the tail window over frames 88-99)
    frames, _ = simulate("clutter", rng=4, n_frames=100)
    one = detect_sequence(frames, workers=1)
    two = detect_sequence(frames, workers=2)
    assert len(one["detections"]) > 0 and one["detections"]["combined_frame"].max() == 8
    for name, rows in one.items():
        assert rows.tobytes() == two[name].tobytes(), name


def _run_as(user, *args, env, cwd):
    """``python -S -c args[0] args[1:]`` as ``user`` (setpriv's options, or none)."""
    return subprocess.run([*user, sys.executable, "-S", "-c", *args], env=env, cwd=cwd,
                          capture_output=True, text=True)


@pytest.mark.slow
def test_read_only_install_caches_kernels_in_the_user_cache(tmp_path):
    # irdetect installed into a prefix nobody may write: numba cannot cache beside the
    # modules, so the first run compiles into the user's cache directory and says so
    # once; the second run loads them and says nothing. Root writes where the mode says
    # no: as root the runs are nobody's, in a folder nobody can reach (pytest's tmp_path
    # lies under a folder only its owner may enter)
    user = []
    base = tmp_path
    if os.geteuid() == 0:
        user = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
        base = Path(tempfile.mkdtemp(prefix="irdetect-ro-"))
        base.chmod(0o777)
    prefix, cache = base / "site", base / "cache"
    try:
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                        "--disable-pip-version-check", "--target", str(prefix), str(ROOT)],
                       check=True, capture_output=True)
        seq = base / "seq.h5"
        write_sequence(seq, simulate("wan2008", snr=4.0, rng=2, n_frames=48)[0])
        seq.chmod(0o644)
        cache.mkdir(mode=0o777)
        cache.chmod(0o777)
        for p in [prefix, *prefix.rglob("*")]:
            p.chmod(p.stat().st_mode & ~0o222)
        # -S: no .pth files, so not the development checkout's editable install; the
        # prefix first, then the environment's other packages (numpy, numba...)
        env = {**os.environ, "XDG_CACHE_HOME": str(cache), "HOME": str(base),
               "PYTHONPATH": os.pathsep.join([str(prefix), sysconfig.get_paths()["purelib"]])}
        env.pop("NUMBA_CACHE_DIR", None)
        where = _run_as(user, "import irdetect; print(irdetect.__file__)", env=env, cwd=base)
        assert where.stdout.startswith(str(prefix)), where.stderr     # the installed copy
        logs = []
        for k in range(2):
            r = _run_as(user, "import sys; from irdetect.cli import main; "
                        "sys.exit(main(sys.argv[1:]))", "process", str(seq),
                        "-o", str(base / f"r{k}.h5"), env=env, cwd=base)
            assert r.returncode == 0, r.stderr
            logs.append(r.stderr)
        assert "compiling kernels, once" in logs[0]
        assert "compiling kernels" not in logs[1]
        assert list(cache.rglob("*.nbi")), "no kernel cached in the user cache directory"
        assert not list(prefix.rglob("*.nbi"))
    finally:
        for p in [prefix, *prefix.rglob("*")] if prefix.exists() else []:
            p.chmod(p.stat().st_mode | 0o200)
        if base != tmp_path:
            shutil.rmtree(base, ignore_errors=True)
