"""The runner's random streams, replayed elsewhere: the agent stream as each module
node and the arbiter node replay it, the simulator's streams carried to another process, the
decision instants in integer ticks."""

from __future__ import annotations

from clis_base.instants import DecisionClock
from clis_modules.core.draws import AgentStream, module_draws, selection_draws
from cr_sim.core.arena import load_arena
from cr_sim.core.sim import Simulator, load_sim_params
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

PERIODS = (0.25, 0.5, 1.2)
DT = 0.05


def test_decision_clock_ticks():
    clock = DecisionClock(PERIODS, DT)
    assert clock.every == [5, 10, 24] and clock.cycle == 120
    t0 = 1234.55                                     # a sim clock far into a run
    assert clock.due(t0 + 0.5, t0) == [True, True, False]
    assert clock.due(t0 + 1.2, t0) == [False, False, True]
    assert not clock.is_instant(t0 + 0.05, t0) and clock.is_instant(t0 + 6.0, t0)
    assert clock.tick(t0 + 0.0501, t0) is None and clock.tick(t0 - 0.05, t0) is None
    assert clock.last_instant(2, t0 + 2.39, t0) == pytest.approx(t0 + 1.2)
    assert clock.last_before(0, t0 + 0.5, t0) == pytest.approx(t0 + 0.25)
    assert clock.last_before(0, t0 + 0.55, t0) == pytest.approx(t0 + 0.5)


@pytest.mark.parametrize('selection', ['episode', 'decision'])
def test_each_consumer_replays_the_runners_draws(selection):
    """Episodes of random lengths: the runner's consumers drawing from one stream in call
    order get what each replaying consumer (a node: its own draws only, and the end events)
    gets, bit for bit, also when a node drew at the tick the episode ended on."""
    clock = DecisionClock(PERIODS, DT)
    lengths = np.random.default_rng(7).integers(1, 300, 6)
    runner = AgentStream(np.random.default_rng([3, 2]), 3, selection, clock)
    draws = [module_draws(runner, i) for i in range(3)]
    sel = selection_draws(runner)
    want: dict = {i: [] for i in range(4)}
    for k_end in lengths:
        runner.begin_episode()
        for k in range(k_end):
            due = clock.due_at(k)
            if not due:
                continue
            runner.instant(k)
            for i in due:
                want[i].append(draws[i].standard_normal(2).copy())
            if k == 0 or selection == 'decision':
                want[3].append(sel.random())
        runner.end_episode(int(k_end))
    for me in range(4):                              # a module node, or the arbiter (3)
        node = AgentStream(np.random.default_rng([3, 2]), 3, selection, clock)
        got = []
        for k_end in lengths:
            node.begin_episode()
            for k in range(k_end + 1):               # (also at the end tick: rewound)
                if me < 3 and clock.is_due(me, k):
                    node.instant(k)
                    if k < k_end:
                        got.append(module_draws(node, me).standard_normal(2).copy())
                elif me == 3 and clock.due_at(k) and (k == 0 or selection == 'decision'):
                    node.instant(k)
                    if k < k_end:
                        got.append(selection_draws(node).random())
            node.end_episode(int(k_end))
        assert len(got) == len(want[me])
        assert all(np.array_equal(a, b) for a, b in zip(got, want[me]))
        assert node.state() == runner.state()


def test_simulator_streams_carried_to_another_simulator():
    """random_state and carried: a simulator built anew goes on exactly as the first."""
    params, arena = load_sim_params(), load_arena()

    def episode(sim, steps):
        sim.reset('wander')
        out = []
        for k in range(steps):
            if sim.hold(np.array([0.2, 0.25]), 1)[0].done:
                break
            if k % 5 == 0:
                out.append(sim.sense_all()[2].copy())
        return out

    a = Simulator(arena, params, np.random.default_rng([5, 0]))
    for steps in (40, 90, 30):
        episode(a, steps)
    b = Simulator(arena, params, np.random.default_rng([5, 0]))
    b.carry(a.carried())
    b.set_random_state(a.random_state())
    for steps in (50, 70):
        ours, theirs = episode(a, steps), episode(b, steps)
        assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(ours, theirs))
        assert a.pose.tolist() == b.pose.tolist()
