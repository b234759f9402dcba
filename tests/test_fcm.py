"""Fuzzy c-means: memberships by hand and against scikit-fuzzy (test extra)."""

import numpy as np
import pytest

from irdetect.track.fcm import fcm, fcm_memberships


def test_memberships_hand_computed():
    # point 0: distances 1 and 2 -> weights 1, 1/4 -> (0.8, 0.2); point 1: distance 0 to centre 1
    d = np.array([[1.0, 3.0], [2.0, 0.0]])
    u = fcm_memberships(d, m=2.0)
    np.testing.assert_allclose(u, [[0.8, 0.0], [0.2, 1.0]], atol=1e-12)
    # m = 3: exponent 2/(m-1) = 1 -> weights 1, 1/2 -> (2/3, 1/3)
    np.testing.assert_allclose(fcm_memberships(d[:, :1], m=3.0)[:, 0], [2 / 3, 1 / 3], atol=1e-12)


def test_noise_cluster_and_gated_out_centres():
    d = np.array([[1.0, np.inf, np.inf], [np.inf, 10.0, np.inf]])
    u = fcm_memberships(d, m=2.0, noise_distance=2.0)
    assert u.shape == (3, 3)
    np.testing.assert_allclose(u.sum(axis=0), 1.0)
    np.testing.assert_allclose(u[:, 0], [0.8, 0.0, 0.2])       # 1 vs noise 1/4
    assert np.argmax(u[:, 1]) == 2                              # far from its only centre
    np.testing.assert_allclose(u[:, 2], [0, 0, 1])              # no candidate at all
    assert fcm_memberships(np.zeros((2, 0))).shape == (2, 0)


@pytest.mark.parametrize("kwargs, match", [({"m": 1.0}, "m must be > 1"),
                                           ({"noise_distance": 0.0}, "noise_distance")])
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        fcm_memberships(np.ones((2, 2)), **kwargs)
    with pytest.raises(ValueError, match="non-negative"):
        fcm_memberships(-np.ones((2, 2)))


def test_fcm_recovers_two_blobs():
    rng = np.random.default_rng(3)
    data = np.vstack([rng.normal(0, 0.3, (40, 2)), rng.normal(5, 0.3, (40, 2))])
    centres, u = fcm(data, 2, rng=1)
    centres = centres[np.argsort(centres[:, 0])]
    np.testing.assert_allclose(centres, [[0, 0], [5, 5]], atol=0.2)
    np.testing.assert_allclose(u.sum(axis=0), 1.0)


def test_matches_scikit_fuzzy():
    import skfuzzy  # the reference, installed by the test extra
    rng = np.random.default_rng(7)
    data = np.vstack([rng.normal(0, 1, (30, 3)), rng.normal(4, 1, (30, 3))])
    centres = np.array([[0.5, 0.0, 0.2], [3.5, 4.1, 3.9], [2.0, 2.0, 2.0]])
    d = np.linalg.norm(data[None, :, :] - centres[:, None, :], axis=2)
    for m in (1.5, 2.0, 3.0):
        ref = skfuzzy.cmeans_predict(data.T, centres, m, error=1e-12, maxiter=1)[0]
        np.testing.assert_allclose(fcm_memberships(d, m=m), ref, atol=1e-6)
    init = rng.random((2, len(data)))
    mine_c, mine_u = fcm(data, 2, m=2.0, tol=1e-10, init=init)
    ref_c, ref_u = skfuzzy.cmeans(data.T, 2, 2.0, error=1e-10, maxiter=1000, init=init)[:2]
    np.testing.assert_allclose(mine_c, ref_c, atol=1e-5)
    np.testing.assert_allclose(mine_u, ref_u, atol=1e-5)
