"""The exploration bonus (``arbiter.bonus``, clis_modules.core.arbiter): the counts, the draw,
the learner's mixture with the same probabilities, single-module runs unchanged, evaluation
without it, and the node graph refusing it."""

from __future__ import annotations

import math

from clis_app.experiments.runner import Agent, run_episode
from clis_base.params import ConfigError, identity_dict
from clis_learner.core.config import load_clis_params, params_hash, preset_overrides
from clis_modules.core.arbiter import selection_probs, uncertainty
from cr_sim.core.arena import load_arena
from cr_sim.core.sim import Simulator, load_sim_params
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

KAPPA = 0.5


def _params(kappa: float = KAPPA, **more):
    return load_clis_params(overrides={**preset_overrides('improved'), 'arbiter.bonus': kappa,
                                       **more})


def _setup(condition: str, params, seed: int = 0):
    sim_params = load_sim_params()
    arena = load_arena(None, sim_params.robot.radius)
    sim = Simulator(arena, sim_params, np.random.default_rng([seed, 0]))
    agent = Agent(params, condition, arena, np.random.default_rng([seed, 2]),
                  sim_params.robot.wheel_base)
    return sim, agent


def test_uncertainty_counts_one_hot_cells_and_weights_overlaps():
    visits = np.array([3.0, 0.0, 1.0])
    assert uncertainty(np.array([1.0, 0.0, 0.0]), visits) == 1.0 / math.sqrt(4.0)
    assert uncertainty(np.array([0.0, 1.0, 0.0]), visits) == 1.0
    # half on each of two cells: the mean of their counts, 2
    assert uncertainty(np.array([0.5, 0.0, -0.5]), visits) == 1.0 / math.sqrt(3.0)
    assert uncertainty(np.zeros(3), visits) == 1.0


def test_bonus_raises_the_uncertain_module_and_zero_bonus_changes_nothing():
    v, g = np.array([1.0, 0.8]), np.array([0.9, 0.9])
    plain = selection_probs(v, g, 5.0, rule='normalized')
    assert np.array_equal(selection_probs(v, g, 5.0, rule='normalized', bonus=np.zeros(2)),
                          plain)
    pushed = selection_probs(v, g, 5.0, rule='normalized', bonus=np.array([0.0, 0.5]))
    # beta (0.8 + 0.5) against beta 1.0: the second module now ahead
    assert pushed[1] > 0.5 > plain[1]
    assert pushed[1] / pushed[0] == pytest.approx(math.exp(5.0 * 0.3))


def test_the_learner_sees_the_probabilities_the_episode_was_drawn_with():
    sim, agent = _setup('async', _params())
    for ep in range(6):
        before = [(m.w.copy(), m.visits.copy()) for m in agent.modules]
        run_episode(sim, agent, 'wander', None, learn=True)
        drawn = agent.selector.start_probs
        after = [(m.w, m.visits) for m in agent.modules]
        acting = [k for k, (a, b) in enumerate(zip(before, after))
                  if not np.array_equal(a[1], b[1])]
        # only the module chosen at the start counted it, by one start
        assert len(acting) == 1
        assert sum(after[acting[0]][1]) == pytest.approx(sum(before[acting[0]][1]) + 1.0)
        for m, (w, visits) in zip(agent.modules, before):
            m.w, m.visits = w, visits         # what the episode was played with
        mem = agent.episodes.memory
        t, _ = mem.decisions(agent.names[0])
        _, probs = agent.learner.mixture_terms(mem, t, np.zeros((len(t), 2)))
        assert np.array_equal(probs, drawn), ep
        _, plain = agent.learner.mixture_terms(mem, t, np.zeros((len(t), 2)), kappa=0.0)
        # equal counts (the first episode) give every module the same bonus
        assert np.allclose(plain, drawn) == (ep == 0)
        for m, (w, visits) in zip(agent.modules, after):
            m.w, m.visits = w, visits


def test_evaluation_episodes_draw_without_the_bonus_and_count_nothing():
    sim, agent = _setup('async', _params())
    run_episode(sim, agent, 'wander', None, learn=True)
    counts = [m.visits.copy() for m in agent.modules]
    run_episode(sim, agent, 'A', None, learn=False)
    assert not agent.selector.explore_now
    values = agent.selector.start_values
    arb = agent.params.arbiter
    assert np.array_equal(agent.selector.start_probs, selection_probs(
        values, agent.gammas, agent.params.common.beta, None, arb.rule, arb.scale_min,
        arb.explore))
    assert all(np.array_equal(a, m.visits) for a, m in zip(counts, agent.modules))


@pytest.mark.parametrize('condition', ['view', 'innate'])
def test_a_single_module_run_is_the_same_with_and_without_the_bonus(condition):
    rows = []
    for kappa in (0.0, KAPPA):
        sim, agent = _setup(condition, _params(kappa), seed=3)
        rows.append([run_episode(sim, agent, 'wander', None) for _ in range(15)])
        rows[-1].append({'w': agent.modules[0].w.tolist(), 'W': agent.modules[0].W.tolist()})
    assert rows[0] == rows[1]


def test_bad_settings_name_the_key():
    with pytest.raises(ConfigError, match='arbiter.bonus.*selection = episode'):
        _params(**{'arbiter.selection': 'decision'})
    with pytest.raises(ConfigError, match=r'arbiter\.bonus.*out of range'):
        _params(-1.0)


def test_the_node_graph_refuses_it_before_anything_starts(tmp_path):
    from clis_app.graph.plan import plan_graph
    with pytest.raises(ConfigError, match='headless runner only'):
        plan_graph('async', 0, tmp_path, 1.0, clis_overrides={'arbiter.bonus': KAPPA})


def test_configurations_without_it_keep_their_identity():
    params = load_clis_params()
    assert 'bonus' not in identity_dict(params)['arbiter']
    assert params_hash(_params(KAPPA)) != params_hash(_params(0.0))
    assert params_hash(_params(0.0)) == params_hash(
        load_clis_params(overrides=preset_overrides('improved')))
