import math

import numpy as np
import pytest

from irdetect.cluster import subtractive_cluster


def _potentials(u, r):
    d2 = ((u[:, None, :] - u[None, :, :]) ** 2 / r ** 2).sum(-1)
    return np.exp(-4 * d2).sum(1)


def test_hand_computed_centres():
    # two tight pairs far apart; potentials by hand: P = 1 + exp(-4 d^2 / r^2)
    x = np.array([[0.0, 0.0], [0.1, 0.0], [1.0, 1.0], [1.0, 0.9], [1.0, 0.95]])
    cl = subtractive_cluster(x, radii=0.3, bounds=[[0, 0], [1, 1]])
    pot = _potentials(x, 0.3)
    assert cl.index[0] == int(np.argmax(pot)) == 4           # the middle of the triple
    assert cl.potential[0] == pytest.approx(pot.max())
    # second centre: the pair, after subtracting P1 exp(-4 d^2 / (1.25 r)^2)
    rest = pot - pot[4] * np.exp(-4 * ((x - x[4]) ** 2).sum(1) / (1.25 * 0.3) ** 2)
    assert cl.index[1] == int(np.argmax(np.maximum(rest, 0)))
    assert cl.potential[1] == pytest.approx(rest.max())
    assert len(cl.centres) == 2
    assert set(cl.labels[:2]) == {1} and set(cl.labels[2:]) == {0}


def test_paper_delta_is_accept_equals_reject():
    rng = np.random.default_rng(0)
    x = np.r_[rng.normal(0.2, 0.02, (20, 2)), rng.normal(0.8, 0.02, (5, 2))]
    strict = subtractive_cluster(x, radii=0.2, accept_ratio=0.5, reject_ratio=0.5)
    loose = subtractive_cluster(x, radii=0.2, accept_ratio=0.1, reject_ratio=0.1)
    assert len(strict.centres) == 1          # the small cluster's ratio 5/20 < 0.5
    assert len(loose.centres) == 2


def test_wrap_merges_lines_across_theta_pi():
    # the same line written near theta = 0 (rho = 50) and near theta = pi (rho = -50)
    d = 0.01
    x = np.array([[50.0, d], [50.5, 2 * d], [-50.0, math.pi - d], [-50.5, math.pi - 2 * d]])
    bounds = [[-100, 0], [100, math.pi]]
    plain = subtractive_cluster(x, radii=[0.05, 0.05], bounds=bounds)
    wrapped = subtractive_cluster(x, radii=[0.05, 0.05], bounds=bounds, wrap_lines=True)
    assert len(plain.centres) == 2
    assert len(wrapped.centres) == 1


@pytest.mark.parametrize("bad", [dict(radii=0), dict(squash=0), dict(accept_ratio=0.1,
                                 reject_ratio=0.5), dict(weights=[-1, 1])])
def test_bad_parameters(bad):
    with pytest.raises(ValueError):
        subtractive_cluster(np.zeros((2, 2)), **bad)


def test_empty_single_identical_nan():
    assert len(subtractive_cluster(np.zeros((0, 2))).centres) == 0
    assert len(subtractive_cluster(np.ones((1, 2))).centres) == 1
    assert len(subtractive_cluster(np.ones((7, 2))).centres) == 1
    with pytest.raises(ValueError, match="NaN"):
        subtractive_cluster(np.array([[np.nan, 0.0]]))


def test_groups_give_what_separate_calls_give():
    # three independent problems (tiles) solved in one call, line wrap included
    rng = np.random.default_rng(11)
    parts = [np.column_stack([rng.normal(c, 3.0, 30), rng.uniform(0, math.pi, 30)])
             for c in (-40.0, 0.0, 55.0)]
    bounds = [[-100, 0], [100, math.pi]]
    kw = dict(radii=[0.04, 0.08], bounds=bounds, wrap_lines=True)
    together = subtractive_cluster(np.concatenate(parts), groups=np.repeat([0, 1, 2], 30), **kw)
    for g, x in enumerate(parts):
        alone = subtractive_cluster(x, **kw)
        mine = together.index[(together.index >= 30 * g) & (together.index < 30 * (g + 1))]
        assert sorted(mine - 30 * g) == sorted(alone.index)
        # every point is labelled with a centre of its own group
        own = np.flatnonzero(np.isin(together.index, mine))
        assert set(together.labels[30 * g:30 * (g + 1)]) <= set(own.tolist())
