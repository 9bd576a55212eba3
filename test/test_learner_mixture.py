"""The mixture behaviour ratio (``learner.behaviour = mixture``, Learner.mixture_terms and
corrections.mixture_density) against a hand computation: on every step, on-policy too,

    rho_l = (pi_i(x_i, u_l) + eps) / (sum_j Pr(j | x) pi_j(x_j, u_l) + eps),
    Pr(j | x) = exp(beta (1 - gamma_j) V_j) / sum_k exp(beta (1 - gamma_k) V_k)    (3)

with each module's features at its latest decision <= t_l, and Pr from the start state
(``arbiter.selection = episode``) or from each step's latest values (``decision``)."""

from __future__ import annotations

import math

from clis_learner.core.config import load_clis_params
from clis_learner.core.learner import Learner
from clis_learner.core.memory import EpisodeMemory
from clis_modules.core.modules import make_modules
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])


@pytest.mark.parametrize('selection', ['episode', 'decision'])
def test_mixture_ratio_is_the_hand_computed_balance_heuristic(selection):
    params = load_clis_params(overrides={'learner.behaviour': 'mixture',
                                         'learner.resample': 'zoh',
                                         'arbiter.selection': selection,
                                         'common.beta': 3.0})
    inn, view, _ = make_modules(params, 'async', LANDMARKS, 1.5)
    rng = np.random.default_rng(7)
    view.W = rng.normal(0, 0.5, (2, view.n))
    inn.w = rng.normal(0, 2.0, inn.n)                 # values that differ step by step
    view.w = rng.normal(0, 2.0, view.n)
    eps, beta = params.common.epsilon, params.common.beta
    mem = EpisodeMemory(['innate', 'view'])
    b_in = [inn.features(th) for th in (0.3, 0.2, math.nan, -0.1)]
    b_vi = [view.features(th, d) for th, d in ((0.3, 0.1), (math.nan, 0.4))]
    u = np.array([[0.3, 0.4], [0.5, 0.2], [0.1, 0.1], [0.0, 0.3]])
    for k in range(4):                                # innate decides and acts every 0.25 s
        mem.record_decision('innate', 0.25 * k, b_in[k])
        mem.record_action(0.25 * k, u[k], 'innate')
    for k in range(2):                                # view decides every 0.5 s
        mem.record_decision('view', 0.5 * k, b_vi[k])
    mem.end(1.0, reached=False)
    learner = Learner([inn, view], params)

    def pr(k_in: int, k_vi: int) -> np.ndarray:
        z = np.array([beta * (1 - inn.gamma) * float(b_in[k_in] @ inn.w),
                      beta * (1 - view.gamma) * float(b_vi[k_vi] @ view.w)])
        e = np.exp(z - z.max())
        return e / e.sum()

    def want(target, steps) -> list[float]:
        out = []
        for k_in, k_vi, uk in steps:
            p = pr(0, 0) if selection == 'episode' else pr(k_in, k_vi)
            dens = np.array([inn.density(b_in[k_in], uk), view.density(b_vi[k_vi], uk)])
            mix = float(p @ dens)
            out.append((dens[target] + eps) / (mix + eps))
        return out

    # view's grid 0, 0.5: the actions in force u[0], u[2]; innate's features at 0 and 0.5
    rp = learner.replay(view, mem)
    assert np.array_equal(rp.U, u[[0, 2]])
    assert rp.rho == pytest.approx(want(1, [(0, 0, u[0]), (2, 1, u[2])]), rel=1e-12)
    # innate's grid 0, 0.25, 0.5, 0.75: on-policy, yet the mixture ratio (not 1)
    rp_in = learner.replay(inn, mem)
    assert rp_in.on.all()
    steps = [(k, k // 2, u[k]) for k in range(4)]
    assert rp_in.rho == pytest.approx(want(0, steps), rel=1e-12)
    assert np.all(rp_in.rho != 1.0)
    # and the probabilities differ from a uniform mixture (the test can tell (3) apart)
    p = pr(2, 1)
    assert abs(p[0] - 0.5) > 0.05 and not np.allclose(p, pr(0, 0)), (p, pr(0, 0))
