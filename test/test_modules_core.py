"""Tests of the module cores (clis_modules.core): RBF features, the Gaussian policy (10) and
its gradient, the linear value (1)(2), gamma_i (11), the speed limits and the module factory."""

from __future__ import annotations

import math

from clis_learner.core.config import load_clis_params
from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.modules import make_modules, module_gamma, speed_limit
from clis_modules.core.policy import GaussianPolicy, log_density
from clis_modules.core.value import LinearValue, gamma_i
from clis_modules.plugins.innate import innate_target_mean
from clis_modules.plugins.place import place_projection
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])


@pytest.fixture(scope='module')
def params():
    """The default CLIS parameters (config/clis.yaml)."""
    return load_clis_params()


# ------------------------------------------------------------------------------ features

def test_uniform_centers():
    c = uniform_centers(-math.pi, math.pi, 9, periodic=True)
    assert c.shape == (9,)
    assert c[4] == pytest.approx(0.0, abs=1e-15)                   # straight ahead is a centre
    assert np.allclose(np.diff(c), 2 * math.pi / 9)
    assert np.allclose(uniform_centers(0.0, 0.5, 9, periodic=False), np.arange(9) * 0.0625)
    assert uniform_centers(0.0, 1.0, 1, periodic=False)[0] == 0.5


def test_rbf_hand_computed_1d():
    grid = RbfGrid([[0.0, 1.0]], [0.5], [False], normalize=False)
    b = grid([0.5])
    # b_j = exp(-(0.5 - x_j)^2 / 0.5) = exp(-0.5) for both; not-visible feature 0
    assert b == pytest.approx([math.exp(-0.5), math.exp(-0.5), 0.0])
    grid_n = RbfGrid([[0.0, 1.0]], [0.5], [False], normalize=True)
    assert grid_n([0.25]) == pytest.approx(
        np.r_[np.array([math.exp(-0.125), math.exp(-1.125)]) /
              (math.exp(-0.125) + math.exp(-1.125)), 0.0])


def test_rbf_2d_is_outer_product_and_blind_feature():
    grid = RbfGrid([[0.0, 1.0, 2.0], [0.0, 0.5]], [1.0, 0.1], [False, False], normalize=False)
    assert grid.n == 7
    x = np.array([0.3, 0.2])
    g0 = np.exp(-(x[0] - np.array([0.0, 1.0, 2.0])) ** 2 / 1.0)
    g1 = np.exp(-(x[1] - np.array([0.0, 0.5])) ** 2 / 0.1)
    assert grid(x)[:-1] == pytest.approx(np.outer(g0, g1).ravel())   # C order: dim 0 major
    for blind in ([math.nan, 0.2], [0.3, math.nan]):
        b = grid(blind)
        assert b[-1] == 1.0 and not b[:-1].any()                      # b = e_n


def test_rbf_periodic_wraps():
    grid = RbfGrid([uniform_centers(-math.pi, math.pi, 9, True)], [0.49], [True], True)
    assert grid([math.pi]) == pytest.approx(grid([-math.pi]))
    assert grid([math.pi - 0.01]) == pytest.approx(grid([-math.pi - 0.01]))
    b = grid([0.0])
    assert b.sum() == pytest.approx(1.0) and b[4] == b.max()
    # symmetric around the centre at 0
    assert b[3] == pytest.approx(b[5])


def test_rbf_normalised_stays_finite_far_outside():
    grid = RbfGrid([[0.0, 0.1]], [1e-4], [False], normalize=True)
    b = grid([50.0])
    assert np.all(np.isfinite(b)) and b.sum() == pytest.approx(1.0)
    assert b[1] == pytest.approx(1.0)


# ------------------------------------------------------------------------------ policy (10)

def test_log_density_hand_computed():
    u, mean, sigma = np.array([0.1, 0.2]), np.array([0.0, 0.0]), 0.5
    # (10): ln pi = -ln(2 pi sigma^2) - ||u - mu||^2 / (2 sigma^2), d = 2
    expected = -math.log(2 * math.pi * 0.25) - 0.05 / 0.5
    assert float(log_density(u, mean, sigma)) == pytest.approx(expected, rel=1e-14)
    pol = GaussianPolicy([[1.0, 0.0], [0.0, 2.0]], sigma=0.5, v_max=0.5)
    b = np.array([0.2, 0.2])
    assert pol.mean(b) == pytest.approx([0.1, 0.2])                 # v_max W b
    assert pol.density(b, [0.1, 0.2]) == pytest.approx(1.0 / (2 * math.pi * 0.25))
    assert pol.log_density(b, [0.4, 0.2]) == pytest.approx(
        -math.log(2 * math.pi * 0.25) - 0.09 / 0.5)


def _finite_difference(f, x, h=1e-6):
    g = np.zeros_like(x)
    for idx in np.ndindex(x.shape):
        xp, xm = x.copy(), x.copy()
        xp[idx] += h
        xm[idx] -= h
        g[idx] = (f(xp) - f(xm)) / (2 * h)
    return g


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_score_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    n, v_max, sigma = 6, 0.3, 0.12
    W = rng.normal(size=(2, n))  # noqa: N806
    b, u = rng.random(n), rng.normal(0.0, 0.3, 2)
    pol = GaussianPolicy(W, sigma, v_max)

    def ll_w(w_mat):
        return GaussianPolicy(w_mat, sigma, v_max).log_density(b, u)

    def ll_s(s):
        return GaussianPolicy(W, float(s[0]), v_max).log_density(b, u)

    assert pol.score_W(b, u) == pytest.approx(_finite_difference(ll_w, W), rel=1e-6, abs=1e-6)
    assert pol.score_sigma(b, u) == pytest.approx(
        _finite_difference(ll_s, np.array([sigma]))[0], rel=1e-6)
    # analytic forms: v_max (u - mu) b^T / sigma^2 and -d/sigma + ||u - mu||^2 / sigma^3
    r = u - v_max * W @ b
    assert pol.score_W(b, u) == pytest.approx(v_max * np.outer(r, b) / sigma ** 2)
    assert pol.score_sigma(b, u) == pytest.approx(-2 / sigma + r @ r / sigma ** 3)


def test_weighted_scores_equal_sum_of_scores():
    rng = np.random.default_rng(3)
    pol = GaussianPolicy(rng.normal(size=(2, 5)), 0.2, 0.6)
    B, U, g = rng.random((7, 5)), rng.normal(size=(7, 2)), rng.normal(size=7)  # noqa: N806
    d_w, d_s = pol.weighted_scores(B, U, g)
    assert d_w == pytest.approx(sum(g[k] * pol.score_W(B[k], U[k]) for k in range(7)))
    assert d_s == pytest.approx(sum(g[k] * pol.score_sigma(B[k], U[k]) for k in range(7)))
    assert pol.density_batch(B, U) == pytest.approx([pol.density(B[k], U[k]) for k in range(7)])


def test_sigma_blind_and_sampling_statistics():
    pol = GaussianPolicy(np.array([[1.0, 0.5], [1.0, 0.5]]), 0.1, 0.6, sigma_blind=0.3)
    seen, blind = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    assert pol.sigma_at(seen) == 0.1 and pol.sigma_at(blind) == 0.3
    assert pol.score_sigma(blind, [0.0, 0.0]) == 0.0
    rng = np.random.default_rng(0)
    u = np.array([pol.sample(blind, rng) for _ in range(4000)])
    assert u.mean(axis=0) == pytest.approx([0.3, 0.3], abs=0.02)
    assert u.std(axis=0) == pytest.approx([0.3, 0.3], rel=0.05)
    assert pol.density_batch(np.array([seen, blind]), np.zeros((2, 2))) == pytest.approx(
        [pol.density(seen, [0, 0]), pol.density(blind, [0, 0])])


# ------------------------------------------------------------------------------ value, (11)

def test_gamma_i_hand_computed(params):
    # (11) gamma_i = gamma^(tau_i / Delta): 0.995^(0.25/0.05) = 0.995^5
    assert gamma_i(0.995, 0.25, 0.05) == pytest.approx(0.975248753121875, rel=1e-14)
    assert gamma_i(0.995, 1.2, 0.05) == pytest.approx(0.995 ** 24, rel=1e-14)
    assert module_gamma(params.common, 0.5) == pytest.approx(0.995 ** 10)
    # one second is discounted alike by every module
    assert gamma_i(0.995, 0.25, 0.05) ** 4 == pytest.approx(gamma_i(0.995, 0.5, 0.05) ** 2)


def test_linear_value():
    v = LinearValue(3, 0.5)
    assert v([1.0, 2.0, 0.0]) == pytest.approx(1.5)
    v.w[:] = [1.0, -1.0, 2.0]
    assert v.batch(np.eye(3)) == pytest.approx([1.0, -1.0, 2.0])


def test_speed_limits(params):
    c = params.common
    assert speed_limit(c, 0.25) == pytest.approx(0.6)
    assert speed_limit(c, 1.2) == pytest.approx(0.125)
    assert speed_limit(c, 0.01) == c.v_wheel_max


# ------------------------------------------------------------------------------ modules

def test_make_modules_conditions(params):
    for cond, names in [('innate', ['innate']), ('view', ['view']), ('place', ['place']),
                        ('sync', ['innate', 'view', 'place']),
                        ('async', ['innate', 'view', 'place'])]:
        mods = make_modules(params, cond, LANDMARKS, 1.5)
        assert [m.name for m in mods] == names
    sync = make_modules(params, 'sync', LANDMARKS, 1.5)
    assert [m.period for m in sync] == [1.2] * 3
    assert [m.v_max for m in sync] == pytest.approx([0.125] * 3)
    assert [m.gamma for m in sync] == pytest.approx([0.995 ** 24] * 3)
    inn, view, place = make_modules(params, 'async', LANDMARKS, 1.5)
    assert (inn.period, view.period, place.period) == (0.25, 0.5, 1.2)
    assert (inn.n, view.n, place.n) == (10, 82, 4800)
    assert view.W.shape == (2, 82) and place.W.shape == (2, 4800)
    assert not inn.learned and view.learned and place.learned
    with pytest.raises(ValueError, match='unknown condition'):
        make_modules(params, 'both', LANDMARKS, 1.5)


def test_innate_heads_to_destination(params):
    inn = make_modules(params, 'innate', LANDMARKS, 1.5)[0]
    v = inn.v_max
    b0 = inn.features(0.0, 0.3)
    assert inn.value(b0) == pytest.approx(params.innate.value.v_init)   # V_in starts high
    mu0 = inn.policy_mean(b0)
    assert mu0[0] == pytest.approx(mu0[1]) and mu0[0] > 0.5 * v            # straight ahead
    left, right = inn.policy_mean(inn.features(0.5)), inn.policy_mean(inn.features(-0.5))
    assert left[1] - left[0] > 0.2 * v                                     # turns left (ccw)
    assert right == pytest.approx(left[::-1])                               # mirror image
    # the fitted mean follows the hand-made target (9 RBFs smooth its kinks and the jump at pi)
    th = np.linspace(-2.5, 2.5, 101)
    got = np.array([inn.policy_mean(inn.features(t)) for t in th]) / v
    want = innate_target_mean(th, params.innate.forward,
                              math.radians(params.innate.turn_angle_deg))
    err = np.abs(got - want).max(axis=1)
    assert err.mean() < 0.1 and err.max() < 0.25
    # not visible: slow forward random search with the wide sigma
    bb = inn.features(math.nan, 0.3)
    assert inn.policy_mean(bb) == pytest.approx([params.innate.blind_forward * v] * 2)
    assert inn.policy.sigma_at(bb) == params.innate.sigma_blind


def test_view_and_place_features(params):
    _, view, place = make_modules(params, 'async', LANDMARKS, 1.5)
    assert view.features(math.nan, 0.1)[-1] == 1.0
    assert np.array_equal(view.features(math.nan, 0.1), view.features(math.nan, 0.4))
    b = view.features(0.2, 0.1)
    assert b.sum() == pytest.approx(1.0) and b[-1] == 0.0
    assert view.value(b) == 0.0 and np.all(view.policy_mean(b) == 0.0)
    place.localizer.update(np.array([0.1, 1.0, 2.0, -2.0]))
    bp = place.features(0.0, 0.1, None)
    assert bp.shape == (4800,) and bp.sum() == pytest.approx(1.0)
    bp[:] = 0.0                                              # a copy: the belief is untouched
    assert place.localizer.belief.sum() == pytest.approx(1.0)
    place.reset()
    assert np.ptp(place.localizer.belief) == 0.0


def test_view_lost_side_splits_not_visible_by_where_it_was_last_seen():
    """``view.lost_side`` (a forward camera's profile): the RBFs as they are where the
    destination is seen; where it is not, *not yet* until a decision has seen it, then the
    side of the last decision that did (its ``sense``, through the Decider as the runner and
    the nodes call it); an episode's start forgets it."""
    from clis_modules.core.decider import Decider
    from clis_modules.core.plugin import Percept
    plain = make_modules(load_clis_params(), 'view', LANDMARKS, 1.5)[0]
    (view,) = make_modules(load_clis_params(overrides={'view.lost_side': True}), 'view',
                           LANDMARKS, 1.5)
    assert view.n == plain.n + 2
    lm = np.full(4, math.nan)
    decider = Decider(view, np.random.default_rng(0), 0.16)

    def column(dest: float) -> int | None:
        b = decider.decide(Percept(0.0, dest, 0.3, lm)).b
        hot = np.flatnonzero(b == 1.0)
        return None if hot.size == 0 else int(hot[0]) - plain.n + 1

    assert [column(d) for d in (math.nan, 0.4, math.nan, math.nan, -0.1, math.nan, 0.0,
                                math.nan)] == [0, None, 1, 1, None, 2, None, 1]
    b = decider.decide(Percept(0.0, -0.3, 0.2, lm)).b
    assert np.array_equal(b[:plain.n], plain.features(-0.3, 0.2)) and not b[plain.n:].any()
    assert decider.observe(Percept(0.0, math.nan, 0.2, lm))[plain.n + 1] == 1.0   # right
    decider.reset()
    assert column(math.nan) == 0


def test_place_rbf_features_project_the_belief_and_generalise_to_neighbouring_cells():
    """place.features.kind = rbf: b = P belief with P's columns normalised; a belief on one
    cell shares features with the neighbouring cell (what is learned carries over), which
    the per-cell belief features never do."""
    rbf = load_clis_params(overrides={'place.features.kind': 'rbf'})
    place = make_modules(rbf, 'place', LANDMARKS, 1.5)[0]
    fp = rbf.place.features
    assert place.n == fp.n_xy ** 2 * fp.n_theta
    loc = place.localizer

    def at_cell(x, y, theta):
        one = np.zeros(loc.shape)
        one[loc.cell_of(x, y, theta)] = 1.0
        loc.set_belief(one)
        return place.features(0.0, 0.1, None)

    a, b = at_cell(0.5, 0.5, 0.3), at_cell(0.65, 0.5, 0.3)
    far = at_cell(-1.0, -1.0, 0.3)
    assert a.sum() == pytest.approx(1.0) and b.sum() == pytest.approx(1.0)
    assert a @ b > 0.5 * (a @ a)                  # neighbours: mostly the same RBFs
    assert a @ far < 0.05 * (a @ a)               # 2 m apart: little in common
    P = place_projection(loc, fp).toarray()  # noqa: N806
    np.testing.assert_allclose(P.sum(axis=0), 1.0)
    loc.reset()
    np.testing.assert_allclose(place.features(0.0, 0.1, None), P @ loc.belief)
    cells = load_clis_params()                     # the paper: one feature per cell
    grid = make_modules(cells, 'place', LANDMARKS, 1.5)[0]
    loc = grid.localizer
    one = np.zeros(loc.shape)
    one[loc.cell_of(0.5, 0.5, 0.3)] = 1.0
    loc.set_belief(one)
    ga = grid.features(0.0, 0.1, None)
    one[:] = 0.0
    one[loc.cell_of(0.65, 0.5, 0.3)] = 1.0
    loc.set_belief(one)
    assert ga @ grid.features(0.0, 0.1, None) == 0.0


def test_module_parameter_setters_validate(params):
    view = make_modules(params, 'view', LANDMARKS, 1.5)[0]
    with pytest.raises(ValueError, match='shape'):
        view.W = np.zeros((2, 3))
    with pytest.raises(ValueError, match='non-finite'):
        view.w = np.full(82, np.nan)
    with pytest.raises(ValueError):
        view.sigma = 0.0
    view.W = np.ones((2, 82))
    assert view.policy.W.sum() == 164.0
