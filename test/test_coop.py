"""The corrections beyond the paper (Retrace / V-trace values, the off-policy
actor-critic, the selection mixture as behaviour, normalised selection, feature-normalised
steps), hand-computed; the periodic evaluation (Fig. 3a) and the presets."""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

from clis_app.cli import main as clis
from clis_app.experiments.experiment import ablation_conditions
from clis_app.experiments.runner import JobSpec, run_job
from clis_base.params import config_dir
from clis_learner.core.config import load_clis_params, preset_groups, preset_overrides
from clis_learner.core.corrections import mixture_density
from clis_learner.core.updates import (
    discounted_returns,
    imitation_weights,
    offpac_weights,
    step_sizes,
    td_lambda_is,
    td_retrace,
    vtrace_targets,
)
from clis_modules.core.arbiter import selection_probs
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

# ------------------------------------------------------------------------------ retrace


def test_retrace_hand_computed_two_steps():
    # one-hot features, w = 0, r = (0, 1), rho = (0.5, 2.0): weights min(1, rho) = (0.5, 1)
    B = np.eye(2)  # noqa: N806
    g, lam, a = 0.9, 0.8, 0.5
    w, delta, weight = td_retrace(np.zeros(2), B, [0.0, 1.0], [0.5, 2.0], g, lam, a)
    assert weight.tolist() == [0.5, 1.0]
    # step 0: delta = 0 + 0.9 * 0 - 0 = 0, e = b0, no change
    # step 1: e = 0.9 * 0.8 * 0.5 * b0 + b1 = (0.36, 1); delta = 1 - 0 = 1; w += 0.5 * 1 * 1 * e
    assert delta.tolist() == [0.0, 1.0]
    assert w == pytest.approx([0.18, 0.5])


def test_retrace_without_off_policy_steps_is_td_lambda_of_8():
    rng = np.random.default_rng(0)
    B = rng.random((7, 4))  # noqa: N806
    r = rng.normal(size=7)
    ones = np.ones(7)
    w8, d8, _ = td_lambda_is(np.zeros(4), B, r, ones, 0.95, 0.7, 0.05)
    wr, dr, _ = td_retrace(np.zeros(4), B, r, ones, 0.95, 0.7, 0.05)
    assert wr == pytest.approx(w8, abs=1e-12) and dr == pytest.approx(d8, abs=1e-12)


def test_retrace_stays_bounded_where_the_product_of_8_explodes():
    # ratios of 3 every step: (8)'s c = 3^l blows the update up, the truncated weights do not
    B = np.tile(np.eye(3), (10, 1))  # noqa: N806
    r = np.r_[np.zeros(29), 1.0]
    rho = np.full(30, 3.0)
    w8, _, c8 = td_lambda_is(np.zeros(3), B, r, rho, 0.95, 0.9, 0.1)
    wr, _, wt = td_retrace(np.zeros(3), B, r, rho, 0.95, 0.9, 0.1)
    assert c8[-1] > 1e14 and np.abs(w8).max() > 1e10
    assert wt.max() == 1.0 and np.abs(wr).max() <= 1.0


def test_vtrace_targets_hand_computed():
    # V = (0.2, 0.4), r = (0, 1), rho = (0.5, 2): truncated (0.5, 1), gamma 0.9, lambda 1
    v = vtrace_targets([0.2, 0.4], [0.0, 1.0], [0.5, 2.0], 0.9, 1.0)
    # v_1 = 0.4 + 1 * (1 + 0 - 0.4) = 1.0
    # v_0 = 0.2 + 0.5 (0 + 0.9 * 0.4 - 0.2) + 0.9 * 0.5 (1.0 - 0.4) = 0.2 + 0.08 + 0.27
    assert v == pytest.approx([0.55, 1.0, 0.0])
    # on-policy with lambda = 1 the target is the discounted return
    v = vtrace_targets([0.3, -0.1, 0.2], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0], 0.9, 1.0)
    assert v[:3] == pytest.approx([0.81, 0.9, 1.0])


def test_offpac_weights_are_truncated_ratio_times_advantage():
    g = offpac_weights([0.2, 0.4], [0.0, 1.0], [0.5, 2.0], 0.9, 1.0)
    # A_0 = 0 + 0.9 * v_1 - V_0 = 0.9 - 0.2 = 0.7, weight 0.5; A_1 = 1 + 0 - 0.4 = 0.6, weight 1
    assert g == pytest.approx([0.35, 0.6])
    # a baseline: a constant shift of all values by V(x_L) = 0 changes nothing on-policy
    # (lambda = 1: A_l = return - V(x_l)), and a perfect V gives zero advantage
    ret = [0.81, 0.9, 1.0]
    assert offpac_weights(ret, [0.0, 0.0, 1.0], np.ones(3), 0.9, 1.0) == pytest.approx(
        np.zeros(3), abs=1e-12)


def test_imitation_weights_clone_only_where_the_return_beat_the_value():
    r = [0.0, -0.1, 1.0]
    g = discounted_returns(r, 0.5)
    assert g == pytest.approx([-0.05 + 0.25, -0.1 + 0.5, 1.0])      # (0.2, 0.4, 1.0)
    w = imitation_weights([0.5, 0.1, 0.2], r, 0.5, 2.0)
    assert w == pytest.approx([0.0, 2 * 0.3, 2 * 0.8])               # max(0, G - V) x kappa
    assert imitation_weights([0.5, 0.1, 0.2], r, 0.5, 0.0).tolist() == [0.0, 0.0, 0.0]


# ------------------------------------------------------------------------------ mixture


def test_mixture_density_is_the_balance_heuristic():
    pi = np.array([[2.0, 0.5, 1.0], [0.0, 4.0, 1.0]])
    probs = np.array([0.5, 0.25, 0.25])
    mix = mixture_density(pi, probs)
    assert mix == pytest.approx([1.0 + 0.125 + 0.25, 0.0 + 1.0 + 0.25])
    # each module's ratio pi_i / mix is at most 1 / Pr(i)
    assert np.all(pi / mix[:, None] <= 1.0 / probs + 1e-12)
    per_step = mixture_density(pi, np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    assert per_step == pytest.approx([2.0, 1.0])


# ------------------------------------------------------------------------------ selection


def test_normalised_selection_hand_computed():
    v = [0.5, 0.25, 0.0]
    p = selection_probs(v, [0.9, 0.8, 0.5], 2.0, rule='normalized')
    z = np.array([2.0, 1.0, 0.0])                    # beta V / max |V| = 2 V / 0.5
    assert p == pytest.approx(np.exp(z) / np.exp(z).sum())
    # tiny values: the scale is scale_min, so noise around 0 gives a near-uniform draw
    p = selection_probs([1e-4, 0.0, -1e-4], [0.9] * 3, 5.0, rule='normalized', scale_min=0.1)
    assert p.max() - p.min() < 0.02
    # the paper's rule (3) is unchanged
    p3 = selection_probs(v, [0.9, 0.8, 0.5], 2.0)
    z3 = 2.0 * np.array([0.1 * 0.5, 0.2 * 0.25, 0.0])
    assert p3 == pytest.approx(np.exp(z3) / np.exp(z3).sum())
    with pytest.raises(ValueError, match='rule'):
        selection_probs(v, [0.9] * 3, 1.0, rule='greedy')


def test_epsilon_soft_selection_keeps_every_available_module_acting():
    v, g = [1.0, 0.0, -1.0], [0.9, 0.8, 0.5]
    greedy = selection_probs(v, g, 50.0, rule='normalized')
    assert greedy[1] < 1e-20                          # beta = 50: the best module only
    soft = selection_probs(v, g, 50.0, rule='normalized', explore=0.3)
    assert soft == pytest.approx(0.7 * greedy + 0.1)  # (1 - eps) Pr + eps / 3
    # unavailable modules stay at 0; epsilon is spread over the available ones
    soft = selection_probs(v, g, 50.0, [True, True, False], 'normalized', explore=0.3)
    assert soft[2] == 0.0 and soft[1] == pytest.approx(0.15) and soft.sum() == pytest.approx(1)
    # epsilon = 0 is the rule bit for bit (the paper preset)
    assert selection_probs(v, g, 2.0, explore=0.0).tolist() == selection_probs(v, g, 2.0).tolist()
    with pytest.raises(Exception, match='arbiter.explore'):
        load_clis_params(overrides={'arbiter.explore': 1.5})


# ------------------------------------------------------------------------------ steps


def test_feature_normalised_steps_move_the_value_by_alpha_delta():
    B = np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 0.1]])  # noqa: N806
    a = step_sizes(0.2, B, 'features')
    assert a == pytest.approx([0.2 / 0.5, 0.2 / 0.01])
    assert step_sizes(0.2, B, 'none').tolist() == [0.2, 0.2]
    # one step of TD(0): V(x_0) moves by exactly alpha * delta, whatever the feature mass
    for b in (np.array([[1.0, 0.0]]), np.array([[0.1, 0.1]])):
        w, delta, _ = td_lambda_is(np.zeros(2), b, [1.0], [1.0], 0.9, 0.0,
                                   step_sizes(0.2, b, 'features'))
        assert float(w @ b[0]) == pytest.approx(0.2 * delta[0])


def test_bounded_steps_keep_every_value_move_within_alpha_delta():
    # a trace of five "goal not visible" states (one-hot, b.b = 1), then a spread RBF state
    # (b.b = 0.27) that reaches the goal: alpha / (b.b) alone moves V(not visible) by 12x alpha
    # delta (how View alone diverged without it); bounded keeps every move <= alpha
    blind, spread = np.eye(4)[3], np.array([0.3, 0.3, 0.3, 0.0])
    B = np.array([blind] * 5 + [spread])  # noqa: N806
    r, ones = np.r_[np.zeros(5), 1.0], np.ones(6)
    moves = {}
    for td in (td_retrace, td_lambda_is):
        for norm in ('features', 'bounded'):
            cap = 0.1 if norm == 'bounded' else None
            w, delta, _ = td(np.zeros(4), B, r, ones, 0.95, 0.9, step_sizes(0.1, B, norm),
                             cap=cap)
            assert delta.tolist() == [0.0] * 5 + [1.0]        # only the last step updates
            moves[td, norm] = np.abs(B @ w).max()
        assert moves[td, 'features'] > 1.0
        assert moves[td, 'bounded'] == pytest.approx(0.1)
    # without a trace (lambda = 0) on a state of the largest mass, bounded is the NLMS step
    B1 = np.array([spread, spread])  # noqa: N806
    for norm in ('features', 'bounded'):
        w, _, _ = td_retrace(np.zeros(4), B1, [0.0, 1.0], [1.0, 1.0], 0.9, 0.0,
                             step_sizes(0.1, B1, norm), cap=0.1 if norm == 'bounded' else None)
        assert float(w @ spread) == pytest.approx(0.1)
    assert step_sizes(0.1, B1, 'bounded') == pytest.approx(step_sizes(0.1, B1, 'features'))
    with pytest.raises(ValueError, match='step_norm'):
        step_sizes(0.1, B1, 'autostep')
    with pytest.raises(Exception, match='learner.step_norm'):
        load_clis_params(overrides={'learner.step_norm': 'autostep'})


# ------------------------------------------------------------------------------ presets


def test_improved_preset_loads_and_ablation_toggles_each_group():
    over = preset_overrides('improved')
    assert over['learner.value_update'] == 'retrace'
    params = load_clis_params(overrides=over)
    assert params.learner.policy_update == 'offpac' and params.arbiter.rule == 'normalized'
    assert preset_overrides('paper') == {}
    groups = preset_groups('improved')
    conds = ablation_conditions('improved')
    assert len(conds) == len(groups) >= 4
    assert all(c.startswith('async@') for c in conds)
    assert sum(c.count('@') for c in conds) == len(over)    # each change in exactly one row
    with pytest.raises(ValueError, match='unknown preset'):
        preset_overrides('nope')


# ------------------------------------------------------------------------------ evaluation


def _spec(tmp_path, condition, every, overrides=None):
    return JobSpec(index=0, label=condition, condition=condition, overrides=overrides or {},
                   sim_overrides={'episode.time_limit': 8.0}, seed=1, episodes=4,
                   eval_episodes=1, arena=None, run_dir=str(tmp_path), block=2,
                   train_start='starts', eval_every=every)


def test_periodic_evaluation_leaves_learning_unchanged(tmp_path):
    plain = run_job(_spec(tmp_path, 'view', 0))
    evald = run_job(_spec(tmp_path, 'view', 2))
    assert [r['duration'] for r in plain.episodes] == [r['duration'] for r in evald.episodes]
    assert plain.evals == evald.evals
    assert evald.eval_points() == [0, 2, 4] and plain.eval_curve == []
    assert all(p['n'] == 5 for p in evald.eval_curve)


def test_thesis_solo_evaluation_and_improved_episode(tmp_path):
    import dataclasses

    from clis_app.experiments.runner import Agent, evaluate
    import yaml
    # starts 0.3 m from the destination, facing it: the solo episodes reach it (or not)
    # depending on the weights, so the successes and durations tell the weights apart
    near = yaml.safe_load((config_dir() / 'arena.yaml').read_text())
    near['starts'] = {k: {'x': 0.3 * math.cos(a), 'y': 0.3 * math.sin(a),
                          'heading_deg': math.degrees(a) - 180.0}
                      for k, a in zip('ABCDE', (0.5, 1.8, 3.0, 4.2, 5.5))}
    (tmp_path / 'near.yaml').write_text(yaml.safe_dump(near))
    spec = dataclasses.replace(_spec(tmp_path, 'async', 4, preset_overrides('improved')),
                               arena=str(tmp_path / 'near.yaml'))
    res = run_job(spec)
    assert set(res.solo) == {'view', 'place'}
    # each learned module alone, recomputed here from the run's final weights (its checkpoint)
    # with the evaluation draws of the last point: the same successes and mean duration
    params, sim_params, arena = spec.load()
    saved = np.load(spec.result_path().with_suffix('.npz'))
    for name, got in res.solo.items():
        solo = Agent(params, name, arena, np.random.default_rng(0),
                     sim_params.robot.wheel_base)
        m = solo.modules[0]
        m.w, m.W, m.sigma = (saved[f'{name}.{k}'] for k in ('w', 'W', 'sigma'))
        rows = evaluate(solo, arena, sim_params, spec.seed, spec.episodes, spec.eval_episodes)
        assert got['n'] == len(rows) == 5
        assert got['reached'] == sum(r['reached'] for r in rows), name
        assert got['duration'] == pytest.approx(np.mean([r['duration'] for r in rows]),
                                                abs=1e-12), name
    assert any(0 < s['reached'] for s in res.solo.values()), res.solo
    assert any(s['duration'] < 8.0 for s in res.solo.values()), res.solo
    for name in ('innate', 'view', 'place'):
        assert all(math.isfinite(r[f'v_{name}']) for r in res.episodes)
        assert all(r[f'c_median_{name}'] <= 1.0 for r in res.episodes)   # truncated weights
    assert set(res.place_map['modules']) == {'innate', 'view', 'place'}


def test_experiment_preset_and_ablation_flags(tmp_path, capsys):
    code = clis(['experiment', '--out', str(tmp_path / 'x'), '--preset', 'paper', '--ablation',
                 '--episodes', '60'])
    assert code == 2 and 'not with --preset paper' in capsys.readouterr().err
    assert not (tmp_path / 'x').exists()
    code = clis(['experiment', '--out', str(tmp_path / 'x'), '--eval-every', '-1'])
    assert code == 2 and '--eval-every' in capsys.readouterr().err
    out = tmp_path / 'abl'                            # the plan, run on tiny jobs
    assert clis(['experiment', '--preset', 'improved', '--ablation', '--conditions', 'view',
                 '--episodes', '2', '--block', '2', '--seeds', '1', '--eval-every', '0',
                 '--eval-episodes', '0', '--sim-set', 'episode.time_limit=1.0', '--quiet',
                 '--workers', '1', '--out', str(out)]) == 0
    plan = json.loads((out / 'experiment.json').read_text())['overrides']
    labels = list(plan)
    assert labels[0] == 'improved:view' and labels[-1] == 'improved:async'
    assert plan['improved:async'] == preset_overrides('improved')
    singles = labels[1:-1]
    assert len(singles) == len(preset_groups('improved'))
    for lb in singles:                                # one change alone, on the paper preset
        assert plan[lb] and set(plan[lb]) < set(preset_overrides('improved'))
    capsys.readouterr()


# ------------------------------------------------------------------------------ paper preset

#: SHA-256 of the episode rows of tools/rules_digest.py's job, made with the code before the
#: corrections (commit 7597987, ``python tools/rules_digest.py --at 7597987``): the project's
#: rules of before the paper preset was made literal (the step of (9) on the dimensionless W,
#: the behaviour's density at its held state) must still give bit-identical results as the named
#: options ``policy_step = dimensionless`` and ``behaviour_state = held``, with every other
#: option at its paper value. The last bits of a run depend on the CPU (numpy's and numba's
#: vector exp, log and reductions, numba's code for the host), so each digest is 7597987's own
#: run on one kind of CPU.
PAPER_GOLDEN = {
    'sync': {'adf83328dc9de397b9c2e7a23ab5f4df842abf3cdec602b7a3d756adf608d938':
             'Intel Xeon, AVX-512 (2026-12-02)',
             '7dd9f0859e30a8c1bbda886c232ac44c377eb7ea8ca1f5c1a8d73c75818f05ba':
             'AMD EPYC, AVX2 only (2026-12-02)',
             'd7f27fd71b3c3ee34d18603f0a285a7b72815a311bb54005ef0ce34a5679abdd':
             'AMD EPYC znver5, AVX-512 (2026-12-05)'},
    'async': {'c0218b1175ef6e55c004e9ac277d61031ed6cadef24636151bbe967cfa33cfdd':
              'Intel Xeon, AVX-512 (2026-12-02)',
              '26a44dc03f8dd7b2cb719f5db9cc4e76bf340e9ced1fc83b8977087d8922b4ee':
              'AMD EPYC, AVX2 only (2026-12-02)',
              'a75624defd0077abc35811e3489d7bccf6a80b84fb68bf0187d1835e41a1e293':
              'AMD EPYC znver5, AVX-512 (2026-12-05)'}}
BEFORE_COMMIT = '7597987'


@functools.lru_cache(maxsize=1)
def _rules_digest():
    """tools/rules_digest.py as a module (the job and the options live there, once)."""
    import importlib.util
    path = Path(__file__).resolve().parent.parent / 'tools' / 'rules_digest.py'
    spec = importlib.util.spec_from_file_location('rules_digest', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.lru_cache(maxsize=1)
def _before_commit_on_this_cpu() -> dict[str, str]:
    """7597987's own digests on this CPU, for a kind of CPU not in PAPER_GOLDEN (~30 s)."""
    return _rules_digest().digests_at(BEFORE_COMMIT)


@pytest.mark.parametrize('condition', ['async', 'sync'])
def test_rules_before_the_literal_preset_are_bit_identical_as_options(tmp_path, condition):
    tool = _rules_digest()
    digest = tool.digest(condition, tool.BEFORE_LITERAL, str(tmp_path))
    if digest in PAPER_GOLDEN[condition]:
        return                                      # 7597987's run on a CPU of that kind
    try:
        want = _before_commit_on_this_cpu()[condition]
    except RuntimeError as exc:
        pytest.fail(f'{digest} is no recorded digest of {BEFORE_COMMIT} and its code could not '
                    f'be run here: {exc}')
    assert digest == want, (
        f'not the digest of commit {BEFORE_COMMIT} run on this CPU ({want}): the options '
        'no longer give the rules of before')


def test_literal_paper_preset_differs_from_the_rules_before(tmp_path):
    """The paper preset is not the old rules: its step of (9) is v_max^2 smaller and Async's
    behaviour densities are scored at resampled states (both change the episodes)."""
    rows = {}
    for name, over in (('paper', {}), ('before', _rules_digest().BEFORE_LITERAL)):
        (tmp_path / name).mkdir()
        spec = JobSpec(index=0, label='async', condition='async', overrides=over,
                       sim_overrides={'episode.time_limit': 20.0}, seed=3, episodes=10,
                       eval_episodes=0, arena=None, run_dir=str(tmp_path / name), block=5,
                       train_start='starts')
        rows[name] = run_job(spec).episodes
    # the first episode is played with the initial parameters: identical until learning
    assert rows['paper'][0]['duration'] == rows['before'][0]['duration']
    assert rows['paper'] != rows['before']


# ------------------------------------------------------------------------------ trust region


def _stuck_episode(mod, steps: int, u: float):
    """The view module deciding ``steps`` times in the same state, executing ``u`` on both
    wheels, then the goal: a robot pushing against an obstacle, as in the diverged seed."""
    from clis_learner.core.memory import EpisodeMemory
    mem = EpisodeMemory([mod.name])
    b = mod.features(0.0, 0.05, None)
    for k in range(steps):
        mem.record_decision(mod.name, k * mod.period, b)
        mem.record_action(k * mod.period, np.array([u, u]), mod.name)
    mem.record_reward(steps * mod.period, 1.0)
    mem.end(steps * mod.period, reached=True)
    return mem


def test_trust_region_bounds_the_mean_change_of_a_stuck_episode():
    from clis_learner.core.learner import Learner
    from clis_modules.core.modules import make_modules

    lm = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])
    over = {**preset_overrides('improved'), 'learner.policy_update': 'paper'}
    shifts = {}
    for bound in (0.0, 1.0):
        p = load_clis_params(overrides={**over, 'learner.max_mean_step': bound})
        (view,) = make_modules(p, 'view', lm, 1.5)
        b = view.features(0.0, 0.05, None)
        before = view.policy.mean(b)
        Learner([view], p).learn(_stuck_episode(view, 100, 0.3))
        shifts[bound] = float(np.linalg.norm(view.policy.mean(b) - before))
    # 100 steps toward u = 0.3 m/s, each alpha of the error: unbounded, the sum overshoots
    # the executed action many times; bounded, the mean moves by exactly sigma = 0.1 m/s
    assert shifts[0.0] > 0.6 > np.hypot(0.3, 0.3)          # beyond the executed action
    assert shifts[1.0] == pytest.approx(0.1, rel=1e-9)
