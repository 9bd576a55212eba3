"""The `paper` preset is the paper as printed (docs/design.md §2): the step of (9) on the
Gaussian (10) with its mean in m/s, and the two densities of (6)(7) scored at the same
resampled data point ``(x(l tau_i), u(l tau_i))``.

Each test compares the learner's production path (``Learner.learn``: ``pg_weights`` and
``GaussianPolicy.weighted_scores``, or ``Learner.replay``) with a computation by hand or by
finite differences, so a wrong factor (v_max, v_max^2, sigma^2) or a held state fails it.
"""

from __future__ import annotations

import copy
import math

from clis_learner.core.config import load_clis_params
from clis_learner.core.learner import Learner
from clis_learner.core.memory import EpisodeMemory
from clis_modules.core.decider import Decider, Percept
from clis_modules.core.modules import make_modules
from clis_modules.plugins.place import place_projection
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])


def log_pi(u, mean_ms, sigma):
    """ln of (10) with the mean in m/s, written out: d = 2."""
    r = np.asarray(u) - np.asarray(mean_ms)
    return -math.log(2.0 * math.pi * sigma ** 2) - float(r @ r) / (2.0 * sigma ** 2)


def fd_gradient(f, W_ms, b, h=1e-6):  # noqa: N803
    """Central finite differences of ``f(W_ms)`` in each entry of ``W_ms`` (2, n) at the
    features ``b``'s nonzero entries (the others do not change the mean ``W_ms b``)."""
    grad = np.zeros_like(W_ms)
    for a in range(2):
        for j in np.flatnonzero(b > 1e-12):
            Wp, Wm = W_ms.copy(), W_ms.copy()  # noqa: N806
            Wp[a, j] += h
            Wm[a, j] -= h
            grad[a, j] = (f(Wp) - f(Wm)) / (2 * h)
    return grad


def one_step(view, b, u, r, behaviour='view'):
    """A one-decision episode of the view module: features ``b``, action ``u``, reward ``r``
    at the end of its period."""
    mem = EpisodeMemory(['view'])
    mem.record_decision('view', 0.0, b)
    mem.record_action(0.0, u, behaviour)
    mem.record_reward(view.period, r)
    mem.end(view.period, reached=False)
    return mem


@pytest.fixture(scope='module')
def paper():
    return load_clis_params()


def test_paper_preset_names_the_literal_rules(paper):
    assert paper.learner.policy_step == 'paper'
    assert paper.learner.behaviour_state == 'resampled'


def test_step_of_9_is_the_finite_difference_gradient_of_ln_pi_in_m_per_s(paper):
    """(9) for one step: W_i <- W_i + alpha r c d ln pi / d W_i with W_i = v_max W in m/s."""
    (view,) = make_modules(paper, 'view', LANDMARKS, 1.5)
    rng = np.random.default_rng(0)
    view.W = rng.normal(0.0, 0.3, view.W.shape)
    b = view.features(0.4, 0.3, None)
    u = np.array([0.12, -0.05])
    r = 0.7
    W_ms = view.v_max * view.W  # noqa: N806 - the paper's W_i [m/s per unit feature]
    # central finite differences of ln pi in W_i (m/s)
    grad = fd_gradient(lambda W: log_pi(u, W @ b, view.sigma), W_ms, b)  # noqa: N803
    before = view.W.copy()
    Learner([view], paper).learn(one_step(view, b, u, r))
    step_ms = view.v_max * (view.W - before)          # the change of W_i in m/s
    alpha = paper.view.policy.alpha
    np.testing.assert_allclose(step_ms, alpha * r * grad, rtol=1e-5, atol=1e-9)


def test_other_policy_steps_are_the_named_multiples_of_the_paper_step(paper):
    (view,) = make_modules(paper, 'view', LANDMARKS, 1.5)
    b = view.features(-0.2, 0.25, None)
    u = np.array([0.2, 0.1])
    steps = {}
    for name in ('paper', 'dimensionless', 'scaled'):
        p = load_clis_params(overrides={'learner.policy_step': name})
        m = copy.deepcopy(view)
        Learner([m], p).learn(one_step(m, b, u, 1.0))
        steps[name] = m.W - view.W
    v, s = view.v_max, view.sigma
    np.testing.assert_allclose(steps['dimensionless'], steps['paper'] * v ** 2, rtol=1e-12)
    np.testing.assert_allclose(steps['scaled'], steps['paper'] * s ** 2, rtol=1e-12)


def test_expected_update_on_a_one_step_gaussian_bandit_is_alpha_grad_j(paper):
    """On-policy, E[Delta W_i] = alpha dJ/dW_i for J(W_i) = E_u~pi[r(u)] (REINFORCE): the
    learner's update averaged over many one-step episodes against a finite-difference
    gradient of the exact J of a quadratic reward."""
    (view,) = make_modules(paper, 'view', LANDMARKS, 1.5)
    view.W = np.random.default_rng(1).normal(0.0, 0.2, view.W.shape)
    b = view.features(0.3, 0.35, None)
    u_star = np.array([0.25, 0.15])
    sigma = view.sigma

    def J(W_ms):  # noqa: N802, N803 - E ||u - u*||^2 = ||mu - u*||^2 + 2 sigma^2
        mu = W_ms @ b
        return -(float((mu - u_star) @ (mu - u_star)) + 2.0 * sigma ** 2)

    W_ms = view.v_max * view.W  # noqa: N806
    grad = fd_gradient(J, W_ms, b)
    rng = np.random.default_rng(2)
    learner = Learner([view], paper)
    W0 = view.W.copy()  # noqa: N806
    total = np.zeros_like(W0)
    n = 4000
    for _ in range(n // 2):
        eps = sigma * rng.standard_normal(2)
        for u in (W_ms @ b + eps, W_ms @ b - eps):    # antithetic pairs
            view.W = W0
            learner.learn(one_step(view, b, u, -float((u - u_star) @ (u - u_star))))
            total += view.v_max * (view.W - W0)
    mean_step = total / n / paper.view.policy.alpha
    big = np.abs(grad) > 0.05 * np.abs(grad).max()
    np.testing.assert_allclose(mean_step[big], grad[big], rtol=0.1)


def test_behaviour_density_is_scored_at_the_resampled_state(paper):
    """Innate (0.25 s) learns from view's (0.5 s) episode: at innate's instant 0.25 s the
    ratio (7) scores pi_vi at view's features of 0.25 s (from the readings of that instant),
    not at those of its decision at 0 s; 'held' keeps the latter."""
    innate, view = make_modules(paper, 'async', LANDMARKS, 1.5)[:2]
    view.W = np.random.default_rng(3).normal(0.0, 0.5, view.W.shape)
    readings = {0.0: (0.5, 0.30), 0.25: (0.1, 0.12), 0.5: (-0.3, 0.45), 0.75: (-0.6, 0.2)}
    u_view = {0.0: np.array([0.10, 0.22]), 0.5: np.array([0.25, -0.05])}
    mem = EpisodeMemory(['innate', 'view'])
    for t, (dest, d_o) in readings.items():
        mem.record_decision('innate', t, innate.features(dest, d_o, None))
        if t in u_view:
            mem.record_decision('view', t, view.features(dest, d_o, None))
            mem.record_action(t, u_view[t], 'view')
        else:
            mem.record_observation('view', t, view.features(dest, d_o, None))
    mem.end(1.0, reached=False)
    eps = paper.common.epsilon
    # the executed actions resampled at 0.25 s by the cubic spline through the change points
    u_025 = CubicSpline([0.0, 0.5], np.stack([u_view[0.0], u_view[0.5]]), axis=0)(0.25)

    def pi(m, dest, d_o, u):
        b = m.features(dest, d_o, None)
        return math.exp(log_pi(u, m.v_max * (m.W @ b), m.policy.sigma_at(b)))

    pi_in = pi(innate, *readings[0.25], u_025)
    rp = Learner([innate, view], paper).replay(innate, mem)
    assert rp.t[1] == 0.25
    np.testing.assert_allclose(rp.U[1], u_025, rtol=1e-12)
    want = (pi_in + eps) / (pi(view, *readings[0.25], u_025) + eps)
    assert rp.rho[1] == pytest.approx(want, rel=1e-10)
    held = load_clis_params(overrides={'learner.behaviour_state': 'held'})
    rp_held = Learner([innate, view], held).replay(innate, mem)
    want_held = (pi_in + eps) / (pi(view, *readings[0.0], u_025) + eps)
    assert rp_held.rho[1] == pytest.approx(want_held, rel=1e-10)
    assert abs(want - want_held) > 1e-3 * want          # the two rules differ here


def test_observe_scores_the_place_belief_of_that_instant_and_leaves_the_module_as_it_was(paper):
    place = make_modules(paper, 'place', LANDMARKS, 1.5)[0]
    d = Decider(place, np.random.default_rng(0), wheel_base=0.1)
    d.reset()
    first = np.array([0.3, 1.9, -2.0, -1.1])
    d.decide(Percept(0.0, math.nan, 0.4, first))
    d.on_wheels(0.1, 0.12, 0.25)
    before = place.localizer.belief.copy()
    odo = d._odo
    later = np.array([0.25, 1.8, -2.1, -1.2])
    b = d.observe(Percept(0.25, math.nan, 0.4, later))
    np.testing.assert_array_equal(place.localizer.belief, before)   # not committed
    assert d._odo == odo
    twin = copy.deepcopy(place.localizer)
    twin.predict(*odo)
    twin.update(later)
    np.testing.assert_array_equal(b, twin.belief)


def test_observe_gives_the_rbf_features_of_that_belief_as_decide_does():
    # with place.features.kind rbf the behaviour's density needs the 288 features, not the
    # 4800-cell belief (the paper rules' Async crashed in memory.states on the mismatch)
    rbf = load_clis_params(overrides={'place.features.kind': 'rbf'})
    place = make_modules(rbf, 'place', LANDMARKS, 1.5)[0]
    d = Decider(place, np.random.default_rng(0), wheel_base=0.1)
    d.reset()
    d.decide(Percept(0.0, math.nan, 0.4, np.array([0.3, 1.9, -2.0, -1.1])))
    d.on_wheels(0.1, 0.12, 0.25)
    odo = d._odo
    later = np.array([0.25, 1.8, -2.1, -1.2])
    b = d.observe(Percept(0.25, math.nan, 0.4, later))
    assert b.shape == (place.n,) and place.n < place.localizer.size
    twin = copy.deepcopy(place.localizer)
    twin.predict(*odo)
    twin.update(later)
    P = place_projection(twin, rbf.place.features)  # noqa: N806 - (288, 4800)
    np.testing.assert_allclose(b, P @ twin.belief, rtol=1e-12)
