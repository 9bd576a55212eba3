"""The cores shared by the headless runner and the node graph: Decider, Selector, StreamBuffer,
episode rows. No ROS: each is driven the way a node drives it (records in any order, stale
streams) and checked against hand-computed results."""

from __future__ import annotations

import math

from clis_learner.core.config import load_clis_params
from clis_learner.core.episodes import acting_shares, episode_row
from clis_learner.core.memory import EpisodeMemory, StreamBuffer
from clis_modules.core.arbiter import ArbiterParams, Selector, selection_probs
from clis_modules.core.decider import Decider, Percept
from clis_modules.core.modules import make_modules
from clis_modules.core.proposal import Proposal
from cr_sim.core.robot import integrate_arc, wheels_to_twist
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])
WHEEL_BASE = 0.16


@pytest.fixture(scope='module')
def params():
    return load_clis_params()


# ------------------------------------------------------------------------------ Decider

def test_decider_proposes_from_the_policy_and_the_value(params):
    view = make_modules(params, 'view', LANDMARKS, 1.5)[0]
    view.W = np.random.default_rng(0).normal(size=view.W.shape)
    view.w = np.linspace(-1, 1, view.n)
    d = Decider(view, np.random.default_rng(7), WHEEL_BASE)
    p = d.decide(Percept(2.5, 0.3, 0.2, np.full(4, np.nan)))
    b = view.features(0.3, 0.2)
    expected_u = view.sample(b, np.random.default_rng(7))     # same two normals
    assert p.module == 'view' and p.t == 2.5 and p.version == 0
    assert np.array_equal(p.b, b) and np.array_equal(p.u, expected_u)
    # the policy's and the value's own methods, bit for bit (decide inlines them)
    assert np.array_equal(p.mean, view.policy_mean(b)) and p.sigma == view.sigma
    assert p.value == view.value(b)


def test_decider_place_odometry_reaches_the_motion_update(params):
    """Odometry of the wheels since the last decision is the motion update of the next one;
    none before the first decision of an episode (a reset forgets it)."""
    place = make_modules(params, 'place', LANDMARKS, 1.5)[0]
    twin = make_modules(params, 'place', LANDMARKS, 1.5)[0]
    d = Decider(place, np.random.default_rng(0), WHEEL_BASE)
    bearings = np.array([0.3, 1.9, -2.8, -1.2])
    d.on_wheels(0.2, 0.2, 0.05)                 # before the episode's first decision: dropped
    d.reset()
    d.decide(Percept(0.0, math.nan, 0.5, bearings))
    twin.localizer.update(bearings)
    odo = (0.0, 0.0, 0.0)
    for vl, vr in [(0.1, 0.12)] * 10 + [(0.05, -0.05)] * 4:
        d.on_wheels(vl, vr, 0.05)
        odo = integrate_arc(*odo, *wheels_to_twist(vl, vr, WHEEL_BASE), 0.05)
    p = d.decide(Percept(0.7, math.nan, 0.5, bearings))
    twin.localizer.predict(*odo)
    twin.localizer.update(bearings)
    assert np.array_equal(p.b, twin.localizer.belief)
    d.reset()
    assert np.array_equal(place.localizer.belief, place.localizer._uniform.reshape(-1))


def test_decider_set_parameters_validates_before_changing(params):
    view = make_modules(params, 'view', LANDMARKS, 1.5)[0]
    d = Decider(view, np.random.default_rng(0), WHEEL_BASE)
    w0 = view.w.copy()
    with pytest.raises(ValueError, match='do not fit'):
        d.set_parameters(np.zeros(3), np.zeros((2, 3)), 0.1, 5)
    with pytest.raises(ValueError, match='non-finite'):
        d.set_parameters(np.full(view.n, np.nan), np.zeros((2, view.n)), 0.1, 5)
    assert np.array_equal(view.w, w0) and d.version == 0
    d.set_parameters(np.ones(view.n), np.full((2, view.n), 0.5), 0.2, 5)
    assert d.version == 5 and view.sigma == 0.2 and np.all(view.W == 0.5)


# ------------------------------------------------------------------------------ Selector

def proposal(module: str, t: float, value: float, u=(0.5, -0.5)) -> Proposal:
    return Proposal(module, t, np.zeros(1), np.array(u, float), np.zeros(2), 0.1, value)


def selector(mode: str = 'episode', beta: float = 1.0, seed: int = 0) -> Selector:
    return Selector(['innate', 'view', 'place'], [0.9, 0.8, 0.7], [0.6, 0.3, 0.125],
                    [0.25, 0.5, 1.2],
                    ArbiterParams(selection=mode, stale_periods=1.5, start_timeout=0.5,
                                  rule='paper', scale_min=0.1, explore=0.0, bonus=0.0),
                    beta,
                    np.random.default_rng(seed))


WARM_UP_CHECK = """
import dataclasses, json, sys
import numba, numpy as np
from clis_learner.core.config import load_clis_params
from clis_app.experiments.runner import Agent, run_episode
from clis_modules.core.decider import Decider
from clis_modules.core.modules import arena_map, condition_periods, make_module
from cr_sim.core.arena import load_arena
from cr_sim.core.sim import Simulator, load_sim_params

def signatures():
    return {f'{name}.{k}': len(v.signatures) for name, mod in list(sys.modules.items())
            if name.startswith('clis_modules.') for k, v in vars(mod).items()
            if isinstance(v, numba.core.registry.CPUDispatcher)}

params, sim_params, arena = load_clis_params(), load_sim_params(), load_arena(None)
# the simulator's kernels first, driven alone as a run drives them: compiling one (a cold
# cache: a fresh clone, another NUMBA_CPU_NAME) compiles the shared kernels it calls too
# (pairwise_sum), which would count as compiled during the run without being the modules'
sim = Simulator(arena, sim_params, np.random.default_rng(2))
for start in ('wander', 'A'):
    sim.reset(start=start)
    for _ in range(40):
        sim.sense_all()
        sim.hold(np.array((0.1, 0.12)), 5)
twin = None
for name, tau in condition_periods(params, 'async'):
    d = Decider(make_module(params, name, tau, *arena_map(arena)), np.random.default_rng(0),
                sim_params.robot.wheel_base)
    if name == 'place':
        twin = (d.module.localizer.belief.copy(), d.rng.bit_generator.state)
    d.warm_up(len(arena.landmarks))
    if name == 'place':
        assert np.array_equal(twin[0], d.module.localizer.belief), 'warm_up changed the belief'
        assert twin[1] == d.rng.bit_generator.state, 'warm_up drew from the generator'
warm = signatures()
sim_params = dataclasses.replace(sim_params, episode=dataclasses.replace(
    sim_params.episode, time_limit=20.0))
agent = Agent(params, 'async', arena, np.random.default_rng(1), sim_params.robot.wheel_base)
sim = Simulator(arena, sim_params, np.random.default_rng(1))
for _ in range(3):
    run_episode(sim, agent, 'wander', None)
print(json.dumps([sum(warm.values()), {k: v for k, v in signatures().items()
                                        if v != warm.get(k, 0)}]))
"""


def test_decider_warm_up_compiles_every_kernel_a_run_calls(tmp_path):
    """A module node warms its decider up before joining the graph: in a fresh interpreter,
    after :meth:`Decider.warm_up` of each module, three Async episodes compile no kernel of
    the modules' cores (a kernel compiled at a decision of a lockstep run takes seconds: the
    arbiter would answer without the module), and the decider itself is left untouched.
    Whatever numba's cache holds: the simulator (a node of its own in the graph) is warmed
    before, so that its kernels compiling the shared ones they call is not counted."""
    import json
    import subprocess
    import sys
    out = subprocess.run([sys.executable, '-c', WARM_UP_CHECK], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    warmed, compiled_later = json.loads(out.stdout.strip().splitlines()[-1])
    assert warmed > 0
    assert compiled_later == {}, 'compiled during the run, not by warm_up'


def test_selector_waits_for_every_module_then_draws_and_clips():
    sel = selector(beta=1e4)     # place has by far the best (1 - gamma) V: always chosen
    sel.begin_episode(10.0)
    assert sel.on_proposals([proposal('innate', 10.0, 0.0)], 10.0) is None
    assert sel.on_proposals([proposal('view', 10.0, 0.0)], 10.05) is None
    cmd = sel.on_proposals([proposal('place', 10.05, 1.0)], 10.1)
    assert cmd is not None and cmd.module == 2 and cmd.drawn and cmd.t == 10.05
    assert np.array_equal(cmd.u, [0.5, -0.5]) and np.array_equal(cmd.u_exec, [0.125, -0.125])
    assert sel.start_probs[2] == pytest.approx(1.0)
    # proposals of a module that does not act change nothing; the acting one's do
    assert sel.on_proposals([proposal('innate', 10.25, 0.0)], 10.25) is None
    cmd = sel.on_proposals([proposal('place', 11.25, 1.0, u=(0.1, 0.0))], 11.25)
    assert cmd.module == 2 and not cmd.drawn and np.array_equal(cmd.u_exec, [0.1, 0.0])


def test_selector_start_timeout_draws_among_those_that_proposed():
    sel = selector()
    sel.begin_episode(0.0)
    assert sel.on_proposals([proposal('innate', 0.0, 0.0)], 0.0) is None
    assert sel.on_proposals([proposal('innate', 0.25, 0.0)], 0.25) is None
    assert sel.check(0.3) is None                           # still waiting
    cmd = sel.check(0.5)
    assert cmd.module == 0 and cmd.drawn and sel.start_probs.tolist() == [1.0, 0.0, 0.0]


def test_selector_drops_a_stale_module_and_stops_when_none_is_fresh():
    sel = selector(beta=1e4)
    sel.begin_episode(0.0)
    sel.on_proposals([proposal('innate', 0.0, 0.0), proposal('view', 0.0, 0.0),
                      proposal('place', 0.0, 1.0)], 0.0)
    assert sel.acting == 2
    sel.on_proposals([proposal('innate', 1.7, 0.0), proposal('view', 1.7, 0.0)], 1.7)
    assert sel.check(1.79) is None                          # place fresh for 1.5 x 1.2 s
    cmd = sel.check(1.81)
    assert cmd is not None and cmd.module in (0, 1) and cmd.drawn
    assert sel.check(1.9) is None
    stop = sel.check(3.0)                                  # innate and view stale too
    assert stop.module == -1 and np.array_equal(stop.u_exec, [0.0, 0.0])
    assert sel.check(3.1) is None                           # stopped once
    cmd = sel.on_proposals([proposal('view', 3.2, 0.0)], 3.2)
    assert cmd.module == 1                                  # a fresh module drives again


def test_selector_decision_mode_frequencies_follow_eq_3():
    sel = selector(mode='decision', beta=50.0, seed=3)
    values = {'innate': 0.0, 'view': 0.1, 'place': 0.2}
    gammas = np.array([0.9, 0.8, 0.7])
    sel.begin_episode(0.0)
    sel.on_proposals([proposal(m, 0.0, v) for m, v in values.items()], 0.0)
    counts = np.zeros(3)
    for k in range(1, 4001):
        cmd = sel.on_proposals([proposal('innate', k * 0.01, values['innate'])], k * 0.01)
        counts[cmd.module] += 1
        sel.latest[1] = proposal('view', k * 0.01, values['view'])     # keep all fresh
        sel.latest[2] = proposal('place', k * 0.01, values['place'])
    p = selection_probs(list(values.values()), gammas, 50.0)
    assert counts / counts.sum() == pytest.approx(p, abs=0.025)


def test_selector_episode_mode_keeps_the_commands_of_the_full_freshness_check():
    """on_proposals' shortcut (episode mode, the acting module still fresh: only its
    freshness is checked) gives the commands of the full check of every module."""

    class FullCheck(Selector):
        def _fresh_one(self, i, now):                     # the shortcut never taken
            return False if self._full else super()._fresh_one(i, now)

        def fresh(self, now):
            self._full = False
            ok = super().fresh(now)
            self._full = True
            return ok

    rng = np.random.default_rng(5)
    a, b = selector(beta=2.0, seed=1), FullCheck(
        ['innate', 'view', 'place'], [0.9, 0.8, 0.7], [0.6, 0.3, 0.125], [0.25, 0.5, 1.2],
        ArbiterParams(selection='episode', stale_periods=1.5, start_timeout=0.5, rule='paper',
                      scale_min=0.1, explore=0.0, bonus=0.0), 2.0, np.random.default_rng(1))
    b._full = True
    n_commands = 0
    for episode in range(30):
        t0 = 10.0 * episode
        a.begin_episode(t0)
        b.begin_episode(t0)
        for k in range(120):
            now = t0 + 0.05 * k
            due = [m for m, n in (('innate', 5), ('view', 10), ('place', 24))
                   if k % n == 0 and rng.random() > 0.1]     # some proposals go missing
            props = [proposal(m, now, float(rng.normal()), tuple(rng.normal(size=2)))
                     for m in due]
            ca, cb = a.on_proposals(props, now), b.on_proposals(props, now)
            if ca is None or cb is None:
                assert ca is cb
                continue
            n_commands += 1
            assert (ca.t, ca.module, ca.drawn) == (cb.t, cb.module, cb.drawn)
            assert np.array_equal(ca.u_exec, cb.u_exec)
    assert n_commands > 300


# ------------------------------------------------------------------------------ StreamBuffer

def test_stream_buffer_cuts_episodes_from_records_in_any_order():
    buf = StreamBuffer(['innate', 'view'])
    # the end of a previous episode the learner never closed, then episode [100, 101.5]
    buf.add_decision('innate', 99.0, [9.0])
    buf.add_reward(99.5, -0.1)
    buf.add_decision('view', 100.5, [2.0])                 # arrives before older records
    buf.add_decision('view', 100.0, [1.0])
    buf.add_reward(100.05, -0.1)
    buf.add_action(100.25, [0.2, 0.2], 'innate')
    buf.add_action(100.0, [0.1, 0.1], 'innate')
    buf.add_decision('innate', 100.0, [3.0])
    buf.add_reward(101.5, 1.0)                             # the last tick's reward
    buf.add_decision('innate', 101.55, [4.0])              # next episode (starts 101.55)
    buf.add_reward(101.6, -0.1)
    buf.add_reward(100.5, 0.0)                              # zeros are not kept
    mem = buf.cut(100.0, 101.5, reached=True)
    t, B = mem.decisions('view')  # noqa: N806
    assert t.tolist() == [100.0, 100.5] and B[:, 0].tolist() == [1.0, 2.0]
    assert mem.decisions('innate')[0].tolist() == [100.0]
    assert mem.actions()[0].tolist() == [100.0, 100.25]
    assert mem.rewards()[0].tolist() == [100.05, 101.5] and mem.reached
    assert mem.duration == pytest.approx(1.5)
    nxt = buf.cut(101.55, 102.0, reached=False)
    assert nxt.decisions('innate')[0].tolist() == [101.55]
    assert nxt.rewards()[1].tolist() == [-0.1] and nxt.actions()[0].size == 0


def test_episode_row_from_memory():
    mem = EpisodeMemory(['innate', 'view'])
    mem.t_start = 10.0
    mem.record_action(10.0, [0.1, 0.1], 'view')
    mem.record_action(12.0, [0.1, 0.1], 'innate')
    mem.record_reward(11.0, -0.1)
    mem.record_reward(13.0, 1.0)
    mem.end(13.0, reached=True)
    assert acting_shares(mem).tolist() == pytest.approx([1 / 3, 2 / 3])
    diag = {'view': {'c_final': 1e-5, 'c_median': 1.0, 'ess': 1.0, 'rho_mean': 1.0,
                     'delta_abs_mean': 0.0, 'grad_norm': 0.0, 'n_steps': 6.0,
                     'on_policy': 0.0, 'c_max': 0.5, 'grow_share': 0.25}}
    row = episode_row(mem, ['innate', 'view'], np.array([0.4, 0.6]), np.array([1.0, 0.0]),
                      diag, 'A')
    assert row['reached'] == 1 and row['duration'] == 3.0 and row['collisions'] == 1
    assert row['ret'] == pytest.approx(0.9) and row['behaviour'] == 'view'
    assert row['p_view'] == 0.6 and row['v_innate'] == 1.0
    assert row['log10c_view'] == pytest.approx(-5.0) and 'c_final_innate' not in row
    assert row['c_max_view'] == 0.5 and row['grow_share_view'] == 0.25


# ---------------------------------------------------------------------------- lockstep cores

def test_episode_gate_learner_wait_and_lockstep():
    from cr_sim.core.gate import EpisodeGate
    gate = EpisodeGate(wait_for_learner=True, learner_timeout=5.0, lockstep=True,
                       command_timeout=1.0, resend_period=0.2)
    assert not gate.first(now=0.0) and gate.holding           # waits for the learner to be up
    assert gate.poll(1.0) == (None, None)
    gate.on_progress(0, 0)
    assert gate.poll(1.1) == ('start', None) and not gate.holding
    gate.started(1)
    gate.published(t=0.0, now=1.2)
    assert gate.holding
    assert gate.on_command(stamp=-0.05, now=1.3) is None     # an old command does not count
    assert gate.holding
    assert gate.poll(1.45) == ('resend', None)                # the readings again
    # the round trip from the instant's first publication, resends included
    assert gate.on_command(stamp=0.0, now=1.5) == pytest.approx(0.3)
    assert not gate.holding
    assert gate.on_command(stamp=0.0, now=1.6) is None        # a copy: nothing held any more
    gate.published(t=0.05, now=2.0)
    action, warning = gate.poll(3.1)                          # no controller: run free
    assert action == 'go' and 't = 0.050' in warning and not gate.holding
    gate.published(t=0.1, now=3.2)
    assert not gate.holding                                   # free until a command arrives
    gate.on_command(stamp=0.1)
    gate.published(t=0.15, now=3.3)
    assert gate.holding
    gate.on_command(stamp=0.15)
    assert not gate.ended(1, now=4.0) and gate.state == 'learner'
    gate.on_progress(1, 1)
    assert gate.poll(4.1) == ('start', None) and gate.version == 1
    assert not gate.ended(2, now=5.0)
    action, warning = gate.poll(10.5)                         # the learner is gone
    assert action == 'start' and 'episode 2' in warning


def test_episode_gate_waits_for_the_graph_then_the_learner():
    """Graph gate: the first episode waits for the subscribers (the caller says when they are
    matched), at most graph_timeout, then for the learner as before."""
    from cr_sim.core.gate import EpisodeGate
    gate = EpisodeGate(wait_for_learner=True, learner_timeout=5.0, graph_timeout=2.0)
    assert not gate.first(now=0.0, ready=False) and gate.state == 'graph'
    gate.on_progress(0, 0)                                    # the learner is up already
    assert gate.poll(1.0, ready=False) == (None, None) and gate.holding
    assert gate.poll(1.5, ready=True) == ('start', None) and not gate.holding
    # not matched in time: start anyway, saying so; the learner gate still applies
    gate = EpisodeGate(wait_for_learner=True, learner_timeout=5.0, graph_timeout=2.0)
    assert not gate.first(now=0.0, ready=False)
    action, warning = gate.poll(2.5, ready=False)
    assert action is None and 'not connected within 2.0 s' in warning
    assert gate.state == 'learner'
    gate.on_progress(0, 0)
    assert gate.poll(2.6) == ('start', None)
    # nothing to wait for: as before
    assert EpisodeGate().first(now=0.0, ready=True)


def test_start_subscribers_are_parsed_with_errors_naming_the_key():
    from clis_base.params import ConfigError
    from cr_sim.interface import parse_counts
    assert parse_counts(('episode:5', '/clock:4', ''), 'k') == {'episode': 5, '/clock': 4}
    assert parse_counts(('',), 'k') == {}
    for bad in ('episode', 'episode:x', ':3', 'episode:-1'):
        with pytest.raises(ConfigError, match=r'sim.node.start_subscribers\[0\].*TOPIC:COUNT'):
            parse_counts((bad,), 'sim.node.start_subscribers')


def test_tick_barrier_waits_for_the_decisions_due_then():
    from clis_modules.core.lockstep import TickBarrier
    barrier = TickBarrier(['innate', 'view'], [0.25, 0.5], timeout=0.5)

    def p(module, t):
        return Proposal(module, t, np.zeros(1), np.zeros(2), np.zeros(2), 0.1, 0.0, 0)
    barrier.on_tick(10.0, now=0.0)
    assert barrier.ready(0.0) == []                           # no episode yet: no answer
    barrier.begin_episode(10.0)
    assert barrier.waiting_for == ['innate', 'view']          # both decide at t_0
    barrier.on_proposal(p('view', 10.0))
    assert barrier.ready(0.01) == []
    barrier.on_proposal(p('innate', 10.0))
    [(t, ps)] = barrier.ready(0.02)
    assert t == 10.0 and {q.module for q in ps} == {'innate', 'view'}
    barrier.on_tick(10.05, now=0.03)
    assert [t for t, _ in barrier.ready(0.03)] == [10.05]     # nobody due
    for k in range(2, 5):
        barrier.on_tick(10.0 + 0.05 * k, now=0.04)
    assert [t for t, _ in barrier.ready(0.04)] == [10.1, 10.15, 10.2]
    barrier.on_tick(10.25, now=0.05)
    assert barrier.waiting_for == ['innate']                  # innate is due at 10.25
    assert barrier.ready(0.3) == []
    # it does not deliver: after the timeout the instant is answered and innate is missing
    assert barrier.ready(0.56) == [(10.25, [])] and barrier.missing == {0}
    barrier.on_tick(10.5, now=0.6)
    assert barrier.waiting_for == ['view']                    # a missing module is not awaited
    barrier.on_proposal(p('innate', 10.5))                    # back: no longer missing
    barrier.on_proposal(p('view', 10.5))
    [(t, ps)] = barrier.ready(0.61)
    assert t == 10.5 and len(ps) == 2 and barrier.missing == set()


def test_copies_of_a_proposal_count_once():
    """A module sends its last proposal again while the clock stands at its instant (it may
    have been lost while the graph connected): the barrier and the learner take it once."""
    from clis_modules.core.lockstep import TickBarrier
    barrier = TickBarrier(['innate'], [0.25], timeout=0.5)

    def p(t):
        return Proposal('innate', t, np.zeros(1), np.zeros(2), np.zeros(2), 0.1, 0.0, 0)
    barrier.begin_episode(0.0)
    barrier.on_tick(0.0, now=0.0)
    assert barrier.on_proposal(p(0.0)) and not barrier.on_proposal(p(0.0))
    [(t, ps)] = barrier.ready(0.01)
    assert t == 0.0 and len(ps) == 1
    assert not barrier.on_proposal(p(0.0))                    # a late copy after the answer
    barrier.on_tick(0.25, now=0.02)
    assert barrier.waiting_for == ['innate']                  # the copy is not the 0.25 one
    buf = StreamBuffer(['innate'])
    assert buf.add_decision('innate', 0.0, [1.0]) and buf.add_decision('innate', 0.25, [2.0])
    assert not buf.add_decision('innate', 0.0, [1.0])
    assert buf.cut(0.0, 1.0, reached=False).decisions('innate')[0].tolist() == [0.0, 0.25]


def test_tick_barrier_does_not_wait_for_a_decision_made_past_its_instant():
    """If the clock ran past a due instant (after a timeout), the module decides on a later
    instant's readings: the due instant is answered at once instead of timing out."""
    from clis_modules.core.lockstep import TickBarrier
    barrier = TickBarrier(['view'], [0.5], timeout=2.0)

    def p(t):
        return Proposal('view', t, np.zeros(1), np.zeros(2), np.zeros(2), 0.1, 0.0, 0)
    barrier.begin_episode(0.0)
    barrier.on_tick(0.5, now=0.0)
    barrier.on_tick(0.55, now=0.0)
    assert barrier.ready(0.1) == [] and barrier.waiting_for == ['view']
    barrier.on_proposal(p(0.55))                              # decided one tick late
    assert barrier.waiting_for == []
    ready = barrier.ready(0.2)
    assert [t for t, _ in ready] == [0.5, 0.55] and ready[0][1] == []
    assert [q.t for q in ready[1][1]] == [0.55] and barrier.missing == set()


def test_tick_barrier_does_not_wait_for_a_module_known_dead():
    """The arbiter learns from DDS liveliness that a module's process died: the instant due
    for it is answered at once, long before the timeout, and the module rejoins by proposing."""
    from clis_modules.core.lockstep import TickBarrier
    barrier = TickBarrier(['innate', 'view'], [0.25, 0.5], timeout=5.0)

    def p(module, t):
        return Proposal(module, t, np.zeros(1), np.zeros(2), np.zeros(2), 0.1, 0.0, 0)
    barrier.begin_episode(0.0)
    barrier.on_tick(0.0, now=0.0)
    barrier.on_proposal(p('innate', 0.0))
    assert barrier.ready(0.1) == [] and barrier.waiting_for == ['view']
    barrier.lost('view')
    [(t, ps)] = barrier.ready(0.2)                            # 0.2 s, not the 5 s timeout
    assert t == 0.0 and [q.module for q in ps] == ['innate'] and barrier.missing == {1}
    barrier.on_proposal(p('view', 0.5))
    assert barrier.missing == set()


def test_tick_barrier_waits_again_for_a_module_alive_again():
    """A liveliness lease that lapsed while the machine was busy (seen at start-up, before
    the first episode) is not a death: once the module is alive again, its decisions are
    waited for, so the run stays the headless runner's."""
    from clis_modules.core.lockstep import TickBarrier
    barrier = TickBarrier(['innate', 'view'], [0.25, 0.5], timeout=5.0)

    def p(module, t):
        return Proposal(module, t, np.zeros(1), np.zeros(2), np.zeros(2), 0.1, 0.0, 0)
    barrier.lost('view')                                      # before the first episode
    barrier.alive('view')
    barrier.begin_episode(0.0)
    barrier.on_tick(0.0, now=0.0)
    barrier.on_proposal(p('innate', 0.0))
    assert barrier.ready(0.1) == [] and barrier.waiting_for == ['view']
    barrier.on_proposal(p('view', 0.0))
    [(t, ps)] = barrier.ready(0.2)
    assert t == 0.0 and sorted(q.module for q in ps) == ['innate', 'view']


def test_lockstep_holds_only_at_decision_instants_when_given_the_periods():
    """With the modules' periods the clock stands only at t0 + l tau_i (the command cannot
    change between two decisions); without them, at every instant."""
    from cr_sim.core.gate import EpisodeGate
    gate = EpisodeGate(lockstep=True, command_timeout=5.0, hold_periods=(0.25, 1.2))
    gate.started(1, t0=100.0)
    held = []
    for k in range(30):                                       # 100.00 ... 101.45
        t = 100.0 + 0.05 * k
        gate.published(t, now=0.0)
        if gate.holding:
            held.append(round(t - 100.0, 2))
            gate.on_command(stamp=t)
    assert held == [0.0, 0.25, 0.5, 0.75, 1.0, 1.2, 1.25]
    every = EpisodeGate(lockstep=True, command_timeout=5.0)
    every.started(1, t0=100.0)
    every.published(100.05, now=0.0)
    assert every.holding
    every.on_command(stamp=100.0)                             # an older answer: still held
    assert every.holding


def test_stream_buffer_cut_is_the_memory_recorded_one_by_one():
    """cut() hands the held decisions to the memory (no copy, no per-record check but the
    time order): the same memory as recording each; an ended memory stacks each module's
    decisions and the actions once."""
    rng = np.random.default_rng(2)
    buf = StreamBuffer(['innate', 'view'])
    ref = EpisodeMemory(['innate', 'view'])
    for k in range(40):
        for name, n in (('innate', 1), ('view', 2)):
            if k % n == 0:
                b = rng.normal(size=3)
                assert buf.add_decision(name, 0.25 * k, b)
                assert not buf.add_decision(name, 0.25 * k, b)     # a copy counts once
                if k < 36:
                    ref.record_decision(name, 0.25 * k, b)
        buf.add_action(0.25 * k, rng.normal(size=2), 'view')
        if k < 36:
            ref.record_action(0.25 * k, buf._act[-1][1], 'view')
    ref.end(9.0, False)
    mem = buf.cut(0.0, 9.0, reached=False)
    for name in ('innate', 'view'):
        t, B = mem.decisions(name)  # noqa: N806
        t_ref, B_ref = ref.decisions(name)  # noqa: N806
        assert np.array_equal(t, t_ref) and np.array_equal(B, B_ref)
        assert mem.decisions(name)[1] is B                    # stacked once
    assert all(np.array_equal(x, y) for x, y in zip(mem.actions(), ref.actions()))
    assert mem.actions()[1] is mem.actions()[1]
    assert buf.last_decision('innate') == 9.75 and buf.last_decision('view') == 9.5  # kept
