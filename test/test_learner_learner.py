"""Tests of the Learner (paper II-B..E): importance ratios across modules and periods, rho = 1
on-policy, Sync identity, determinism, diagnostics, and a learning smoke test on a toy task."""

from __future__ import annotations

import copy
import math

from clis_learner.core.config import load_clis_params
from clis_learner.core.learner import DIAGNOSTIC_KEYS, Learner
from clis_learner.core.memory import EpisodeMemory
from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.modules import ModuleCore, PolicyParams, ValueParams, make_modules
from clis_modules.core.policy import GaussianPolicy
from clis_modules.core.value import LinearValue
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])
DT = 0.05


@pytest.fixture(scope='module')
def params():
    """The default CLIS parameters (config/clis.yaml)."""
    return load_clis_params()


def fake_episode(mods: list[ModuleCore], behaviour, seed: int, duration: float = 6.0,
                 goal: bool = True) -> EpisodeMemory:
    """A random episode on the simulator's tick grid: every module decides on its own period
    (random observations), ``behaviour`` (a name, or a function t -> name) acts, collisions
    now and then, the goal at the end."""
    rng = np.random.default_rng(seed)
    mem = EpisodeMemory([m.name for m in mods])
    ticks = int(round(duration / DT))
    for m in mods:
        m.reset()
    for k in range(ticks):
        t = k * DT
        actor = behaviour(t) if callable(behaviour) else behaviour
        for m in mods:
            if k % int(round(m.period / DT)) == 0:
                if m.localizer is not None:
                    m.localizer.predict(rng.normal(0, 0.05), rng.normal(0, 0.05), 0.1)
                    m.localizer.update(rng.uniform(-3, 3, 4))
                dest = math.nan if rng.random() < 0.2 else rng.uniform(-3.0, 3.0)
                b = m.features(dest, rng.uniform(0.0, 0.5), None)
                mem.record_decision(m.name, t, b)
                if m.name == actor:
                    mem.record_action(t, m.sample(b, rng), actor)
        if rng.random() < 0.03:
            mem.record_reward(t + DT, -0.1)                # stamped at the end of the tick
    if goal:
        mem.record_reward(ticks * DT, 1.0)
    mem.end(ticks * DT, reached=goal)
    return mem


# ------------------------------------------------------------------------------ ratios

@pytest.mark.parametrize('resample', ['spline', 'zoh'])
def test_rho_is_exactly_one_on_policy(params, resample):
    p = load_clis_params(overrides={'learner.resample': resample})
    for cond in ('innate', 'view', 'place'):
        mods = make_modules(p, cond, LANDMARKS, 1.5)
        d = Learner(mods, p).learn(fake_episode(mods, cond, seed=1))[cond]
        assert d['rho_mean'] == 1.0 and d['c_final'] == 1.0 and d['c_min'] == 1.0
        assert d['ess'] == d['n_steps'] and d['on_policy'] == 1.0
    mods = make_modules(p, 'async', LANDMARKS, 1.5)
    diag = Learner(mods, p).learn(fake_episode(mods, 'view', seed=2))
    assert diag['view']['rho_mean'] == 1.0 and diag['view']['c_final'] == 1.0
    assert diag['innate']['rho_mean'] != 1.0 and diag['place']['on_policy'] == 0.0


def test_off_policy_ratio_hand_computed(params):
    """Async, behaviour = innate (250 ms), target = view (500 ms) and the reverse: rho_l uses
    the action in force at t_l and the behaviour's features at its latest decision <= t_l."""
    inn, view, _ = make_modules(params, 'async', LANDMARKS, 1.5)
    eps = params.common.epsilon
    mem = EpisodeMemory(['innate', 'view'])
    b_in = [inn.features(th) for th in (0.3, 0.2, math.nan, -0.1)]
    b_vi = [view.features(th, d) for th, d in ((0.3, 0.1), (math.nan, 0.4))]
    u = np.array([[0.3, 0.4], [0.5, 0.2], [0.1, 0.1], [0.0, 0.3]])
    for k in range(4):
        mem.record_decision('innate', 0.25 * k, b_in[k])
        mem.record_action(0.25 * k, u[k], 'innate')
    for k in range(2):
        mem.record_decision('view', 0.5 * k, b_vi[k])
    mem.end(1.0, reached=False)
    view.W = np.random.default_rng(0).normal(0, 0.5, (2, view.n))
    learner = Learner([inn, view], params)
    rp = learner.replay(view, mem)
    # zoh and spline agree on knots: view's grid (0, 0.5) is on the innate's knots
    assert np.array_equal(rp.U, u[[0, 2]])
    want = [(view.density(b_vi[0], u[0]) + eps) / (inn.density(b_in[0], u[0]) + eps),
            (view.density(b_vi[1], u[2]) + eps) / (inn.density(b_in[2], u[2]) + eps)]
    assert rp.rho == pytest.approx(want, rel=1e-12)
    assert np.all(rp.rho != 1.0) and not rp.on.any()

    # reverse roles: view acts at 0 and 0.5; innate's grid 0, 0.25, 0.5, 0.75
    mem2 = EpisodeMemory(['innate', 'view'])
    for k in range(4):
        mem2.record_decision('innate', 0.25 * k, b_in[k])
    for k in range(2):
        mem2.record_decision('view', 0.5 * k, b_vi[k])
        mem2.record_action(0.5 * k, u[k], 'view')
    mem2.end(1.0, reached=False)
    rp2 = Learner([inn, view], load_clis_params(overrides={'learner.resample': 'zoh'})).replay(
        inn, mem2)
    held = u[[0, 0, 1, 1]]                                      # zero-order hold
    assert np.array_equal(rp2.U, held)
    want2 = [(inn.density(b_in[k], held[k]) + eps) /
             (view.density(b_vi[k // 2], held[k]) + eps) for k in range(4)]
    assert rp2.rho == pytest.approx(want2, rel=1e-12)


def test_decision_mode_mixed_behaviours(params):
    mods = make_modules(params, 'async', LANDMARKS, 1.5)
    mem = fake_episode(mods, lambda t: 'innate' if t < 2.0 - 1e-9 else 'view', seed=3)
    learner = Learner(mods, params)
    rp = learner.replay(mods[1], mem)                            # view: grid every 0.5 s
    assert list(rp.on) == [t >= 2.0 - 1e-9 for t in rp.t]
    assert np.all(rp.rho[rp.on] == 1.0) and np.all(rp.rho[~rp.on] != 1.0)
    rp_in = learner.replay(mods[0], mem)
    assert np.all(rp_in.rho[rp_in.on] == 1.0) and np.all(rp_in.rho[~rp_in.on] != 1.0)
    assert rp_in.on.sum() == 8                                   # innate acted for 2 s


def test_sync_grid_needs_no_resampling(params):
    mods = make_modules(params, 'sync', LANDMARKS, 1.5)
    mem = fake_episode(mods, 'view', seed=4)
    t_a, u_a, _ = mem.actions()
    for m in mods:
        rp = Learner(mods, params).replay(m, mem)
        assert np.array_equal(rp.t, t_a) and np.array_equal(rp.U, u_a)     # identity
    assert rp.r.sum() == pytest.approx(mem.rewards()[1].sum())


# ------------------------------------------------------------------------------ learning

def test_learning_is_deterministic_and_order_free(params):
    mods_a = make_modules(params, 'async', LANDMARKS, 1.5)
    mods_b = copy.deepcopy(mods_a)
    mem = fake_episode(mods_a, 'innate', seed=5)
    d_a = Learner(mods_a, params).learn(mem)
    d_b = Learner(mods_b[::-1], params).learn(mem)
    assert d_a == d_b
    for a, b in zip(mods_a, mods_b):
        assert np.array_equal(a.w, b.w) and np.array_equal(a.W, b.W) and a.sigma == b.sigma
    assert not np.array_equal(mods_a[0].w, make_modules(params, 'innate', LANDMARKS, 1.5)[0].w)


def test_diagnostics_and_evaluation_mode(params):
    mods = make_modules(params, 'async', LANDMARKS, 1.5)
    before = [(m.w.copy(), m.W.copy()) for m in mods]
    diag = Learner(mods, params).learn(fake_episode(mods, 'place', seed=6), update=False)
    for (w, W), m in zip(before, mods):  # noqa: N806
        assert np.array_equal(w, m.w) and np.array_equal(W, m.W)
    assert set(diag) == {'innate', 'view', 'place'}
    for d in diag.values():
        assert tuple(d) == DIAGNOSTIC_KEYS
        assert all(isinstance(v, float) for v in d.values())
    assert diag['innate']['n_steps'] == 24 and diag['view']['n_steps'] == 12
    assert diag['place']['n_steps'] == 5
    assert diag['innate']['v_start'] == pytest.approx(params.innate.value.v_init)
    assert diag['innate']['grad_norm'] == 0.0 and diag['view']['grad_norm'] > 0.0
    assert 0.0 < diag['view']['ess'] <= 12 and diag['view']['c_min'] <= diag['view']['c_median']


def test_divergence_is_not_applied(params):
    view = make_modules(params, 'view', LANDMARKS, 1.5)[0]
    mem = fake_episode([view], 'view', seed=7)
    view.value_params = ValueParams(alpha=1e308, v_init=0.0)      # beyond any sane range
    view.w = np.full(view.n, 1.0)
    W = view.W.copy()  # noqa: N806
    with np.errstate(over='ignore', invalid='ignore'):
        diag = Learner([view], params).learn(mem)['view']
    assert diag['diverged'] == 1.0 and np.all(view.w == 1.0) and np.array_equal(view.W, W)


def test_module_without_decisions(params):
    mods = make_modules(params, 'async', LANDMARKS, 1.5)
    mem = EpisodeMemory([m.name for m in mods])
    mem.record_decision('innate', 0.0, mods[0].features(0.1))
    mem.record_action(0.0, [0.1, 0.1], 'innate')
    mem.end(0.05, reached=False)
    diag = Learner(mods, params).learn(mem)
    assert diag['innate']['n_steps'] == 1 and diag['place']['n_steps'] == 0
    with pytest.raises(RuntimeError):
        Learner(mods, params).learn(EpisodeMemory(['innate']))


# ------------------------------------------------------------------------------ smoke test

GOAL, HORIZON = 0.25, 12


def toy_module(name: str, fixed_forward: float | None = None) -> ModuleCore:
    """A module on a 1-D corridor: state s in [0, 1] coded by 5 RBFs; each step moves the
    robot by 0.1 (u_left + u_right) / 2. Learned policy from W = 0, or a fixed forward one."""
    grid = RbfGrid([uniform_centers(0.0, 1.0, 5, False)], [0.06], [False], True)
    W = np.full((2, grid.n), 0.0 if fixed_forward is None else fixed_forward)  # noqa: N806
    pp = None if fixed_forward is not None else PolicyParams(
        alpha=0.5, sigma=0.5, learn_sigma=False, sigma_min=0.01, sigma_max=1.0, alpha_sigma=0.0)
    return ModuleCore(name, 1.0, 0.95, 1.0, grid.n, lambda p: grid([p.dest_bearing]),
                      GaussianPolicy(W, 0.5, 1.0), LinearValue(grid.n, 0.0),
                      ValueParams(alpha=0.1, v_init=0.0), pp)


def toy_episode(mods: list[ModuleCore], actor: str, rng: np.random.Generator) -> EpisodeMemory:
    """Reach s >= GOAL within HORIZON steps: reward 1 and the episode ends."""
    mem = EpisodeMemory([m.name for m in mods])
    s = 0.0
    for k in range(HORIZON):
        for m in mods:
            b = m.features(s)
            mem.record_decision(m.name, float(k), b)
            if m.name == actor:
                u = m.sample(b, rng)
                mem.record_action(float(k), u, actor)
        s += 0.1 * 0.5 * (u[0] + u[1])
        if s >= GOAL:
            mem.record_reward(k + 1.0, 1.0)                # at the end of the step
            mem.end(k + 1.0, reached=True)
            return mem
    mem.end(float(HORIZON), reached=False)
    return mem


def success_rate(mods: list[ModuleCore], actor: str, seed: int, n: int = 200) -> float:
    rng = np.random.default_rng(seed)
    return float(np.mean([toy_episode(mods, actor, rng).reached for _ in range(n)]))


@pytest.fixture
def scaled():
    """The toy's step sizes are set for the scaled policy step (inverse Fisher)."""
    return load_clis_params(overrides={'learner.policy_step': 'scaled'})


def test_policy_gradient_learns_on_policy(scaled):
    """A module trained by (9) from its own episodes reaches the goal far more often."""
    params = scaled
    view = toy_module('view')
    before = success_rate([view], 'view', seed=100)
    learner, rng = Learner([view], params), np.random.default_rng(0)
    for _ in range(150):
        learner.learn(toy_episode([view], 'view', rng))
    after = success_rate([view], 'view', seed=100)
    assert before < 0.2 and after > before + 0.5, (before, after)


def test_policy_gradient_learns_off_policy_by_importance_sampling(scaled):
    """The cooperation of CLIS: a learned module that never acts improves from the episodes
    of a fixed forward-biased (innate-like) module, through the truncated ratios (7)."""
    params = scaled
    inn, view = toy_module('innate', fixed_forward=0.4), toy_module('view')
    before = success_rate([inn, view], 'view', seed=100)
    learner, rng = Learner([inn, view], params), np.random.default_rng(1)
    for _ in range(150):
        diag = learner.learn(toy_episode([inn, view], 'innate', rng))
        assert diag['innate']['rho_mean'] == 1.0 and diag['view']['on_policy'] == 0.0
    after = success_rate([inn, view], 'view', seed=100)
    assert before < 0.2 and after > before + 0.5, (before, after)
    # the same episodes with no learning signal for the target (alpha = 0) change nothing
    frozen = toy_module('view')
    frozen.policy_params = PolicyParams(alpha=0.0, sigma=0.5, learn_sigma=False, sigma_min=0.01,
                                        sigma_max=1.0, alpha_sigma=0.0)
    learner, rng = Learner([inn, frozen], params), np.random.default_rng(1)
    for _ in range(20):
        learner.learn(toy_episode([inn, frozen], 'innate', rng))
    assert success_rate([inn, frozen], 'view', seed=100) == before


# ------------------------------------------------------------------------------ options

def test_policy_step_options_and_learned_sigma(scaled):
    params = scaled
    raw = load_clis_params(overrides={'learner.policy_step': 'dimensionless'})
    mods_s = make_modules(params, 'view', LANDMARKS, 1.5)
    mods_r = copy.deepcopy(mods_s)
    mem = fake_episode(mods_s, 'view', seed=8)
    g_s = Learner(mods_s, params).learn(mem)['view']['grad_norm']
    g_r = Learner(mods_r, raw).learn(mem)['view']['grad_norm']
    v = mods_s[0]
    # scaled = dimensionless x sigma^2 / v_max^2 (inverse Fisher information of the mean);
    # the paper's step against finite differences: test_paper_rules.py
    assert g_s == pytest.approx(g_r * v.sigma ** 2 / v.v_max ** 2, rel=1e-12)
    learn_s = load_clis_params(overrides={'view.policy.learn_sigma': True,
                                          'view.policy.alpha_sigma': 10.0})
    mods = make_modules(learn_s, 'view', LANDMARKS, 1.5)
    sigmas = []
    for seed in range(5):
        Learner(mods, learn_s).learn(fake_episode(mods, 'view', seed=seed))
        sigmas.append(mods[0].sigma)
    pp = learn_s.view.policy
    assert len(set(sigmas)) > 1 and all(pp.sigma_min <= s <= pp.sigma_max for s in sigmas)


def test_no_correction_is_on_policy_everywhere():
    p = load_clis_params(overrides={'learner.correction': 'none'})
    mods = make_modules(p, 'async', LANDMARKS, 1.5)
    diag = Learner(mods, p).learn(fake_episode(mods, 'innate', seed=9))
    assert all(d['rho_mean'] == 1.0 and d['c_final'] == 1.0 for d in diag.values())
