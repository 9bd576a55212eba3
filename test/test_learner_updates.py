"""Tests of the learner's pure pieces: resampling (paper II-E), the truncated ratio (7), the
corrections registry, TD(lambda) with IS (8), the policy gradient with IS (9), the episode
memory."""

from __future__ import annotations

from clis_learner.core.corrections import (
    CORRECTIONS,
    NoCorrection,
    TruncatedRatio,
    make_correction,
)
from clis_learner.core.memory import EpisodeMemory
from clis_learner.core.resample import (
    ActionTrack,
    latest_index,
    resample_actions,
    sum_rewards,
)
from clis_learner.core.updates import (
    C_MAX,
    importance_products,
    pg_weights,
    policy_gradient_is,
    td_lambda_is,
)
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

# ------------------------------------------------------------------------------ resampling

def cubic(t: np.ndarray) -> np.ndarray:
    """Two cubic polynomials of time, shape (len(t), 2)."""
    return np.stack([0.3 - 0.2 * t + 0.05 * t ** 2 - 0.004 * t ** 3,
                     -0.1 + 0.4 * t - 0.03 * t ** 2 + 0.002 * t ** 3], axis=1)


def test_spline_is_exact_on_cubics():
    t_knots = np.arange(0, 25) * 0.25                 # behaviour every tau_i' = 250 ms
    t_query = np.arange(0, 6) * 1.2                   # module i every tau_i = 1200 ms
    got = resample_actions(t_knots, cubic(t_knots), t_query, 'spline')
    assert got == pytest.approx(cubic(t_query), abs=1e-12)
    t_query = np.arange(0, 12) * 0.5                  # off-knot queries too
    t_query = t_query + 0.1
    assert resample_actions(t_knots, cubic(t_knots), t_query, 'spline') == pytest.approx(
        cubic(t_query), abs=1e-12)


def test_zoh_is_exact_on_piecewise_constant():
    t_knots = np.arange(0, 10) * 0.5
    u = np.random.default_rng(0).normal(size=(10, 2))
    t_query = np.arange(0, 19) * 0.25
    got = resample_actions(t_knots, u, t_query, 'zoh')
    assert np.array_equal(got, u[np.arange(19) // 2])
    # float times that miss a knot by rounding are still on it (15 * 0.05 vs 0.75)
    assert np.array_equal(resample_actions([0.0, 0.75], [[0, 0], [1, 1]], [15 * 0.05], 'zoh'),
                          [[1.0, 1.0]])


@pytest.mark.parametrize('method', ['spline', 'zoh'])
def test_same_grid_is_the_identity(method):
    t = np.arange(0, 30) * 1.2                         # Sync: one common grid
    u = np.random.default_rng(1).normal(size=(30, 2))
    assert np.array_equal(resample_actions(t, u, t, method), u)      # bit for bit


def test_resample_edges():
    t, u = np.array([0.0, 1.0, 2.0, 3.0]), cubic(np.array([0.0, 1.0, 2.0, 3.0]))
    # after the last knot the last command stays in force; before the first: the first
    got = resample_actions(t, u, [-0.5, 3.7], 'spline')
    assert np.array_equal(got, u[[0, 3]])
    assert np.array_equal(resample_actions([0.0], [[0.2, 0.3]], [0.0, 5.0], 'spline'),
                          [[0.2, 0.3], [0.2, 0.3]])
    with pytest.raises(ValueError):
        resample_actions(t, u, [1.0], 'linear')


def test_latest_index():
    grid = [0.0, 0.5, 1.0]
    assert list(latest_index(grid, [0.0, 0.49, 0.5, 0.9999999999, 2.0, -1.0])) == \
        [0, 0, 1, 2, 2, 0]


def test_reward_sums_hand_computed_and_total_preserved():
    grid = np.array([0.0, 0.5, 1.0])
    t_r = np.array([0.0, 0.45, 10 * 0.05, 15 * 0.05, 1.0, 1.3])
    r = np.array([-0.1, -0.1, -0.1, 0.2, 1.0, 5.0])
    # rewards stamped at the end of their step: (.., 0.5]: -0.3 (0.0 goes to the first);
    # (0.5, 1.0]: 0.2 + 1.0; (1.0, end]: 5
    assert sum_rewards(t_r, r, grid) == pytest.approx([-0.3, 1.2, 5.0])
    rng = np.random.default_rng(2)
    t_r, r = np.sort(rng.uniform(-0.1, 60.0, 500)), rng.normal(size=500)
    grid = np.arange(0, 50) * 1.2
    sums = sum_rewards(t_r, r, grid)
    assert sums.shape == (50,) and sums.sum() == pytest.approx(r.sum(), abs=1e-9)
    assert np.array_equal(sum_rewards([], [], grid), np.zeros(50))


# ------------------------------------------------------------------------------ (7)

def test_truncated_ratio_hand_computed():
    corr = TruncatedRatio(0.2)
    # (7): (pi_i + eps) / (pi_i' + eps) = 1.2 / 3.2
    assert corr.ratio([1.0], [3.0]) == pytest.approx([0.375], rel=1e-15)
    assert corr.ratio([0.0, 5.0], [0.0, 0.0]) == pytest.approx([1.0, 26.0])
    dens = np.random.default_rng(3).random(20) * 10
    assert np.array_equal(corr.ratio(dens, dens), np.ones(20))         # equal densities
    assert TruncatedRatio(0.0).ratio([2.0], [4.0]) == pytest.approx([0.5])   # plain (6)


def test_corrections_registry():
    assert set(CORRECTIONS) >= {'paper', 'none'}
    assert isinstance(make_correction('paper', 0.2), TruncatedRatio)
    assert make_correction('paper', 0.2).epsilon == 0.2
    assert np.array_equal(make_correction('none', 0.2).ratio([1.0, 9.0], [3.0, 0.1]), [1, 1])
    assert isinstance(make_correction('none', 0.2), NoCorrection)
    clipped = make_correction('clipped', 0.2)
    # min(1, (7)): (1 + 0.2) / (3 + 0.2) = 0.375 stays, (9 + 0.2) / (0.1 + 0.2) -> 1
    assert np.allclose(clipped.ratio([1.0, 9.0], [3.0, 0.1]), [0.375, 1.0])
    with pytest.raises(ValueError, match='unknown correction'):
        make_correction('bogus', 0.2)


# ------------------------------------------------------------------------------ (8)

def _td_lambda_is_reference(w, B, r, rho, gamma_i, lambda_, alpha):  # noqa: N803
    """(8) as numpy code, step by step (the implementation before it was compiled)."""
    w = np.array(w, dtype=np.float64)
    c = importance_products(rho)
    e = np.zeros_like(w)
    delta = np.empty(len(B))
    alpha = np.broadcast_to(alpha, (len(B),))
    for l in range(len(B)):  # noqa: E741
        v_next = float(w @ B[l + 1]) if l + 1 < len(B) else 0.0
        d = r[l] + gamma_i * c[l] * v_next - float(w @ B[l])
        e *= lambda_ * gamma_i * rho[l]
        e += c[l] * B[l]
        w += (alpha[l] * d) * e
        delta[l] = d
    return w, delta, c


def test_td_lambda_is_is_the_numpy_reference_bit_for_bit():
    rng = np.random.default_rng(11)
    for n, steps in [(1, 3), (10, 240), (82, 120), (4801, 50), (7, 1)]:
        B = rng.random((steps, n))  # noqa: N806
        r = rng.normal(size=steps) * (rng.random(steps) < 0.1)
        rho = rng.uniform(0.3, 2.0, steps)
        w = rng.normal(size=n)
        for alpha in (0.1, rng.uniform(0.01, 0.2, steps)):
            got = td_lambda_is(w, B, r, rho, 0.99, 0.9, alpha)
            with np.errstate(over='ignore', invalid='ignore'):   # diverging, as (8) can
                want = _td_lambda_is_reference(w, B, r, rho, 0.99, 0.9, alpha)
            for a, b in zip(got, want):
                np.testing.assert_array_equal(a, b)


def test_td_lambda_is_hand_computed():
    w0 = np.array([0.5, 0.0])
    B = np.array([[1.0, 0.0], [0.0, 1.0]])  # noqa: N806
    r, rho = np.array([0.0, 1.0]), np.array([2.0, 0.5])
    w, delta, c = td_lambda_is(w0, B, r, rho, gamma_i=0.9, lambda_=0.8, alpha=0.1)
    # step 0: c = 2; delta = 0 + 0.9*2*V(x1)=0 - V(x0)=0.5 -> -0.5; e = (2, 0);
    #         w = (0.5, 0) + 0.1 * -0.5 * (2, 0) = (0.4, 0)
    # step 1: c = 1; delta = 1 + 0 (terminal) - V(x1)=0 -> 1;
    #         e = 0.8*0.9*0.5*(2, 0) + 1*(0, 1) = (0.72, 1); w = (0.4, 0) + 0.1*(0.72, 1)
    assert c == pytest.approx([2.0, 1.0])
    assert delta == pytest.approx([-0.5, 1.0])
    assert w == pytest.approx([0.472, 0.1], rel=1e-14)
    assert np.array_equal(w0, [0.5, 0.0])                              # input not modified


def test_td_lambda_on_policy_converges_to_discounted_return():
    """Deterministic 5-state chain with reward 1 at the end: V(x_l) -> gamma^(4 - l)."""
    B = np.eye(5)  # noqa: N806
    r = np.array([0, 0, 0, 0, 1.0])
    w = np.zeros(5)
    for _ in range(300):
        w, _, _ = td_lambda_is(w, B, r, np.ones(5), gamma_i=0.9, lambda_=0.5, alpha=0.2)
    assert w == pytest.approx(0.9 ** np.arange(4, -1, -1), abs=1e-6)


def test_importance_products_clip():
    assert importance_products([2.0, 0.5, 3.0]) == pytest.approx([2.0, 1.0, 3.0])
    c = importance_products(np.full(400, 1e3))
    assert np.all(np.isfinite(c)) and c[-1] == C_MAX


# ------------------------------------------------------------------------------ (9)

def test_policy_gradient_is_hand_computed():
    scores = np.array([[1.0, 0.0], [0.0, 2.0]])
    r, rho = np.array([-0.1, 1.0]), np.array([2.0, 0.5])
    # c = (2, 1); step 0: e = (1, 0), dW = 0.1 * 0.9^0 * -0.1 * 2 * (1, 0) = (-0.02, 0)
    #             step 1: e = (1, 2), dW = 0.1 * 0.9^1 * 1 * 1 * (1, 2) = (0.09, 0.18)
    assert policy_gradient_is(scores, r, rho, 0.9, 0.1) == pytest.approx([0.07, 0.18])
    assert pg_weights(r, [2.0, 1.0], 0.9) == pytest.approx([0.7, 0.9])


def test_policy_gradient_equals_the_literal_loop():
    rng = np.random.default_rng(4)
    n_steps, p = 40, 7
    scores, r = rng.normal(size=(n_steps, p)), rng.normal(size=n_steps)
    rho, gamma, alpha = rng.uniform(0.2, 2.0, n_steps), 0.95, 0.03
    c, e, total = 1.0, np.zeros(p), np.zeros(p)
    for t in range(n_steps):
        c = rho[t] * c                                  # (9) c <- rho c
        e = e + scores[t]                               # (9) e <- e + dln pi/dW
        total += alpha * gamma ** t * r[t] * c * e      # (9) W <- W + alpha gamma^t r c e
    assert policy_gradient_is(scores, r, rho, gamma, alpha) == pytest.approx(total, rel=1e-10)


# ------------------------------------------------------------------------------ memory

def test_memory_records_and_validates():
    mem = EpisodeMemory(['innate', 'view'])
    mem.record_decision('innate', 0.0, np.ones(3))
    mem.record_decision('innate', 0.25, np.zeros(3))
    mem.record_decision('view', 0.0, np.ones(2))
    with pytest.raises(ValueError):
        mem.record_decision('view', 0.0, np.ones(2))          # times must increase
    mem.record_action(0.0, [0.1, 0.2], 'view')
    mem.record_action(0.0, [0.3, 0.4], 'innate')              # same instant: replaces
    mem.record_action(0.25, [0.5, 0.6], 'innate')
    mem.record_reward(0.1, -0.1)
    mem.record_reward(0.2, 0.0)
    mem.record_decision('innate', 0.5, np.ones(3))            # at the end: ignored
    mem.end(0.5, reached=True)
    with pytest.raises(RuntimeError):
        mem.record_reward(0.6, 1.0)
    t, B = mem.decisions('innate')  # noqa: N806
    assert list(t) == [0.0, 0.25] and B.shape == (2, 3)
    ta, ua, who = mem.actions()
    assert list(ta) == [0.0, 0.25] and ua[0] == pytest.approx([0.3, 0.4])
    assert list(who) == [0, 0]
    assert list(mem.rewards()[1]) == [-0.1] and mem.reached
    mem.clear()
    assert not mem.ended and mem.decisions('view')[1] is None


@pytest.mark.parametrize('method', ['spline', 'zoh'])
def test_action_track_shared_by_grids_is_resample_actions_bit_for_bit(method):
    """One track (one spline fit) queried on every module's grid = resample_actions per grid."""
    rng = np.random.default_rng(4)
    t_knots = np.cumsum(rng.uniform(0.2, 1.3, 60))
    u_knots = rng.normal(size=(60, 2))
    track = ActionTrack(t_knots, u_knots, method)
    for period in (0.25, 0.5, 1.2, 0.35):
        grid = np.arange(0.0, t_knots[-1] + 2.0, period)
        assert np.array_equal(track.at(grid), resample_actions(t_knots, u_knots, grid, method))
