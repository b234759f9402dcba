"""Groups and inverse-distance fusion."""

import numpy as np
import pytest

from irdetect.detect import DirectionalDetection, detect
from irdetect.fuse import fuse, group_labels
from irdetect.tables import CANDIDATE


def _det(mask, response=None):
    mask = np.asarray(mask, bool)
    resp = (mask * 5.0 if response is None else response).astype(np.float32)
    return DirectionalDetection(mask, np.where(mask, 2, -1).astype(np.int8), resp)


@pytest.mark.parametrize("cx, cy", [(10, 10), (30, 17)])
def test_symmetric_group_lands_on_its_centre(cx, cy):
    mask = np.zeros((40, 50), bool)
    for dx, dy in [(0, 0), (-2, 0), (2, 0), (0, -2), (0, 2), (-1, -1), (1, 1), (-1, 1), (1, -1)]:
        mask[cy + dy, cx + dx] = True          # a plus with a member on the centroid (d = 0)
    out = fuse(_det(mask), mask.astype(np.float32))
    assert out.dtype == CANDIDATE and len(out) == 1
    assert out["x"][0] == pytest.approx(cx) and out["y"][0] == pytest.approx(cy)
    assert out["n_members"][0] == 9 and out["direction"][0] == 2


def test_weights_favour_members_near_the_centroid():
    # members at x = 0, 1, 2, 6 (centroid 2.25): inverse-distance weights pull the fused
    # point towards the dense side, away from the plain centroid
    mask = np.zeros((5, 10), bool)
    mask[2, [0, 1, 2, 6]] = True
    out = fuse(_det(mask), mask.astype(np.float32), gap=3, peak_radius=0)
    d = np.abs(np.array([0, 1, 2, 6]) - 2.25)
    beta = (1 / np.maximum(d, 0.5)) / (1 / np.maximum(d, 0.5)).sum()
    assert out["x"][0] == pytest.approx((beta * [0, 1, 2, 6]).sum())
    assert out["intensity"][0] == pytest.approx(1.0)


def test_gap_joins_broken_streaks_and_separates_targets():
    mask = np.zeros((30, 30), bool)
    mask[5, 2:8] = True
    mask[5, 9:14] = True                        # one-pixel hole at x = 8
    mask[20, 20:23] = True                      # another target
    n0, _ = group_labels(mask, 0)
    n1, labels = group_labels(mask, 1)
    assert n0 == 3 and labels[5, 2] == labels[5, 13] != labels[20, 21]
    assert len(fuse(_det(mask), mask, gap=1, peak_radius=0)) == 2
    assert len(fuse(_det(mask), mask, gap=1, min_members=4, peak_radius=0)) == 1


def test_peak_split_keeps_two_close_targets_apart():
    # two bright blobs 6 px apart joined by a weak bridge: one group, two targets
    yy, xx = np.mgrid[0:20, 0:30]
    resp = (8 * np.exp(-((xx - 12) ** 2 + (yy - 10) ** 2) / 4.0)
            + 7 * np.exp(-((xx - 18) ** 2 + (yy - 10) ** 2) / 4.0)).astype(np.float32)
    mask = resp > 1.0
    det = DirectionalDetection(mask, np.where(mask, 0, -1).astype(np.int8), resp)
    assert len(fuse(det, resp, peak_radius=0)) == 1
    out = fuse(det, resp, peak_radius=2)
    assert len(out) == 2
    assert sorted(np.round(out["x"]).tolist()) == [12.0, 18.0]
    # a weak bump on the flank of a bright blob is not a second target
    resp2 = (8 * np.exp(-((xx - 12) ** 2 + (yy - 10) ** 2) / 4.0)
             + 2.5 * np.exp(-((xx - 16) ** 2 + (yy - 10) ** 2) / 2.0)).astype(np.float32)
    mask2 = resp2 > 1.0
    det2 = DirectionalDetection(mask2, np.where(mask2, 0, -1).astype(np.int8), resp2)
    assert len(fuse(det2, resp2, peak_radius=2)) == 1


def test_groups_from_detection_and_empty_result():
    rng = np.random.default_rng(0)
    img = rng.normal(0, 1, (60, 60)).astype(np.float32)
    for x, y in [(15, 15), (45, 40)]:
        img[y - 1:y + 2, x - 1:x + 2] += 6.0
    det = detect(img, window=3, k=5.0)
    out = fuse(det, img)
    found = sorted(zip(np.round(out["x"]), np.round(out["y"])))
    assert found == [(15.0, 15.0), (45.0, 40.0)]
    empty = fuse(detect(np.zeros((20, 20))), np.zeros((20, 20)))
    assert len(empty) == 0 and empty.dtype == CANDIDATE


@pytest.mark.parametrize("kwargs, name", [({"gap": -1}, "gap"), ({"d_min": 0}, "d_min"),
                                          ({"min_members": 0}, "min_members"),
                                          ({"peak_radius": -1}, "peak_radius")])
def test_bad_parameters_are_named(kwargs, name):
    mask = np.zeros((5, 5), bool)
    with pytest.raises(ValueError, match=name):
        fuse(_det(mask), mask, **kwargs)
