"""Robust statistics and the tiling every CFAR step uses, on frames of any size."""

import numpy as np
import pytest

from irdetect.verify import standardise
from irdetect.detect import detect
from irdetect.robust import median_mad_sigma, tile_grid, tile_map, tile_samples
from irdetect.suppress import noise_sigma

PRIMES = (1, 2, 3, 5, 31, 33, 37, 61, 97, 127, 211, 251, 509, 1021)
#: sizes 1-1024 where the tiles of 32 px have odd sides, 1-px remainders, or are one tile
SIZES = sorted(set(PRIMES) | {32, 63, 64, 65, 95, 100, 200, 213, 252, 336, 640, 1024})


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("tile", [4, 8, 32])
def test_tiles_cover_any_side(n, tile):
    ny, nx, th, tw = tile_grid(n, 2 * n + 1, tile)
    assert ny * th <= n < (ny + 1) * th and nx * tw <= 2 * n + 1 < (nx + 1) * tw
    a = np.arange(n * (2 * n + 1), dtype=np.float32).reshape(n, 2 * n + 1)
    for sample in (1, 2, 3):
        s = tile_samples(a, tile, sample)
        assert s.shape[:2] == (ny, nx)
        assert s.shape[2] == len(range(0, th, sample)) * len(range(0, tw, sample))
        # every sample of tile (i, j) lies in that tile
        rows, cols = np.divmod(s.astype(np.int64), 2 * n + 1)
        i, j = np.indices((ny, nx))
        assert ((rows // th == i[..., None]) & (cols // tw == j[..., None])).all()
    m = tile_map(np.ones((ny, nx)), n, 2 * n + 1)
    assert m.shape == (n, 2 * n + 1) and np.allclose(m, 1.0)


def test_tiles_of_a_stack_keep_the_leading_axes():
    a = np.random.default_rng(0).normal(size=(3, 4, 70, 45)).astype(np.float32)
    s = tile_samples(a, 32, 2)
    assert s.shape[:2] == (3, 4) and s.shape[2:4] == tile_grid(70, 45, 32)[:2]


def test_median_mad_sigma_of_a_gaussian():
    v = np.random.default_rng(1).normal(3.0, 2.0, (4, 20001))
    med, sig = median_mad_sigma(v)
    assert np.allclose(med, 3.0, atol=0.05) and np.allclose(sig, 2.0, rtol=0.03)


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1), (2, 2), (31, 33), (100, 100),
                                   (213, 252), (97, 1021), (336, 256)])
def test_cfar_steps_take_any_frame_size(shape):
    rng = np.random.default_rng(2)
    frames = [rng.normal(size=shape).astype(np.float32) for _ in range(6)]
    out = standardise([f.copy() for f in frames])
    assert all(np.isfinite(f).all() and f.shape == shape for f in out)
    assert np.isfinite(noise_sigma(frames[0], tile=32)).all()
    det = detect(np.pad(frames[0], ((1, 1), (1, 1)), mode="edge"))
    assert np.isfinite(det.response).all()
