"""The module node's scheduling core without ROS (clis_modules.core.schedule): decision
instants ``t_0 + l tau_i`` once each, the agent stream's draws at them, readings that come late
or never, the other modules' instants observed, parameter versions, resending and stalls."""

from __future__ import annotations

import math

from clis_base.instants import DecisionClock
from clis_learner.core.config import load_clis_params
from clis_modules.core.draws import AgentStream
from clis_modules.core.modules import arena_map, make_module
from clis_modules.core.schedule import (
    STALL_WARNING,
    Log,
    ModuleSchedule,
    Propose,
    PublishObservation,
    ResetTimer,
    off_grid_rng,
)
from cr_sim.core.arena import load_arena
from cr_sim.core.robot import load_robot_params
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

DT = 0.05
T0 = 12.5                      # the sim clock runs on across episodes: an episode starts late
SEED = 3
ASYNC = [('innate', 0.25), ('view', 0.5), ('place', 1.2)]


@pytest.fixture(scope='module')
def setup():
    """The default CLIS parameters and arena."""
    return load_clis_params(), load_arena(None)


class Graph:
    """What a module node sees of the graph: readings, clock and wall clock, all by hand."""

    def __init__(self, setup, name: str, condition=ASYNC, sim_time: bool = True,
                 **kwargs) -> None:
        params, arena = setup
        self.t, self.wall = 0.0, 100.0
        self.landmarks = [lm.name for lm in arena.landmarks]
        module = make_module(params, name, dict(condition)[name], *arena_map(arena))
        self.s = ModuleSchedule(module, condition, seed=SEED, selection='episode', dt=DT,
                                wheel_base=load_robot_params().wheel_base,
                                landmarks=self.landmarks, sim_time=sim_time,
                                now=lambda: self.t, wall=lambda: self.wall, **kwargs)
        self.out: list = []

    def readings(self, t: float, wheels: bool = True, camera: bool = True) -> None:
        """The simulator's readings of instant ``t`` (before its clock reaches ``t``)."""
        rd = self.s.readings
        if camera:
            rd.add_camera(t, {'destination': 0.3 * math.sin(t), **{
                n: 0.2 * j - 0.4 + 0.1 * math.cos(t) for j, n in enumerate(self.landmarks)}})
        rd.add_ir(t, np.full(7, 0.3 + 0.05 * math.sin(3 * t)))
        if wheels:
            rd.add_wheels(t, np.array([0.1 + 0.01 * math.sin(t), 0.12]))

    def step(self, call, *args) -> list:
        call(*args)
        got = self.s.pop_actions()
        self.out += got
        return got

    def start(self, t0: float = T0, **values) -> list:
        self.t = t0
        return self.step(self.s.start, t0, {'dt': DT, **values})

    def tick(self, k: int, t0: float = T0, timer: bool = True, **readings) -> list:
        """Tick ``k``: its readings, then the clock; the timer too at the module's instants."""
        t = t0 + k * DT
        self.readings(t, **readings)
        if self.s.waiting:                        # the node is woken for the readings
            self.step(self.s.try_decide)
        self.t = t
        got = self.step(self.s.on_clock, t)
        if timer and k % round(self.s.period / DT) == 0:
            got += self.step(self.s.on_timer)
        return got

    def proposals(self) -> list:
        return [a.proposal for a in self.out if isinstance(a, Propose) and not a.again]


def instants(tau: float, ticks: int, t0: float = T0) -> list[float]:
    n = round(tau / DT)
    return [t0 + k * DT for k in range(0, ticks, n)]


# ------------------------------------------------------------------------------ instants

@pytest.mark.parametrize('name', ['innate', 'view', 'place'])
def test_one_decision_at_each_instant_with_the_agent_streams_draws(setup, name):
    """Timer and clock both see every instant (and the wall timer runs between): module i
    decides exactly once at each ``t_0 + l tau_i``, on that instant's readings, with the
    normals the headless runner's agent stream gives it there, episode after episode."""
    g = Graph(setup, name)
    tau = dict(ASYNC)[name]
    i = [n for n, _ in ASYNC].index(name)
    replay = AgentStream(np.random.default_rng([SEED, 2]), 3, 'episode',
                         DecisionClock([p for _, p in ASYNC], DT))
    t0 = T0
    for ticks in (73, 50):                       # two episodes, ended off an instant of i
        g.out.clear()
        g.start(t0)
        for k in range(ticks):
            g.tick(k, t0)
            g.step(g.s.on_wall)
        g.step(g.s.end, t0 + ticks * DT)
        got = g.proposals()
        assert [p.t for p in got] == pytest.approx(instants(tau, ticks, t0), abs=1e-9)
        assert len(got) == len(instants(tau, ticks, t0))
        replay.begin_episode()
        for p in got:
            replay.instant(round((p.t - t0) / DT))
            # (10) u = mean + sigma * z with the runner's z, to the bit
            assert np.array_equal(p.u, p.mean + p.sigma * replay.normals[i])
        replay.end_episode(ticks)
        t0 += ticks * DT + 0.4


def test_a_decision_waits_for_the_readings_of_its_instant(setup):
    """The clock reaches an instant before its readings: the decision waits (the node is
    woken for the readings) and is made on them, once, when they come."""
    g = Graph(setup, 'view')
    g.t = T0 - DT
    g.step(g.s.start, T0, {'dt': DT})
    assert not g.proposals() and g.s.waiting       # due at T0, no reading yet
    g.t = T0
    g.step(g.s.on_clock, T0)
    assert not g.proposals() and g.s.waiting
    g.readings(T0)
    g.step(g.s.try_decide)
    assert [p.t for p in g.proposals()] == [T0] and not g.s.waiting
    g.step(g.s.try_decide)
    g.step(g.s.on_timer)
    assert len(g.proposals()) == 1


def test_a_missed_instant_is_decided_on_the_first_readings_after_it(setup):
    """The camera reading of an instant never comes: the decision is made on the next
    instant's readings, and the following instant is the grid's again."""
    g = Graph(setup, 'innate')                      # 5 ticks
    g.start()
    for k in range(12):
        g.tick(k, camera=k != 5)
    assert [round(p.t - T0, 6) for p in g.proposals()] == [0.0, 0.3, 0.5]


def test_a_module_started_between_its_instants_decides_at_the_next(setup):
    """Restarted mid-episode (the clock past the start, between two instants): no decision
    until the next instant ``t_0 + l tau_i``, where the timer is realigned."""
    g = Graph(setup, 'view')
    g.t = T0 + 0.3
    g.readings(T0 + 0.3)
    g.step(g.s.start, T0, {'dt': DT})
    assert not g.proposals() and ResetTimer() in g.out
    g.out.clear()
    for k in range(7, 11):
        assert (ResetTimer() in g.tick(k, timer=False)) == (k == 10)
    assert [p.t for p in g.proposals()] == pytest.approx([T0 + 0.5])


def test_no_decision_after_the_end_and_none_before_the_start(setup):
    g = Graph(setup, 'innate')
    g.tick(0)
    assert not g.out
    g.start()
    g.tick(0)
    g.step(g.s.end, T0 + 0.1)
    for k in range(1, 12):
        g.tick(k)
    assert [p.t for p in g.proposals()] == [T0]


def test_the_place_module_waits_for_the_wheel_reading_of_its_instant(setup):
    """Odometry up to the instant needs its wheel reading, which travels on its own topic."""
    g = Graph(setup, 'place')
    g.start()
    g.tick(0)
    for k in range(1, 24):
        g.tick(k)
    g.tick(24, wheels=False)
    assert [p.t for p in g.proposals()] == [T0] and g.s.waiting
    g.s.readings.add_wheels(T0 + 24 * DT, np.array([0.1, 0.12]))
    g.step(g.s.try_decide)
    assert [p.t for p in g.proposals()] == pytest.approx([T0, T0 + 1.2])
    assert g.s.readings.integrated == pytest.approx(T0 + 1.2)


def test_real_time_decides_on_the_newest_readings_with_its_own_draws(setup):
    g = Graph(setup, 'view', sim_time=False)
    g.step(g.s.start, 3.0, {'episode': 4})
    assert not g.proposals()
    for t in (3.01, 3.07, 3.13):
        g.readings(t)
    g.step(g.s.try_decide)
    (p,) = g.proposals()
    assert p.t == 3.13
    z = off_grid_rng(SEED, 'view', 4).standard_normal(2)
    assert np.array_equal(p.u, p.mean + p.sigma * z)
    g.step(g.s.on_timer)                       # no newer reading: waits for one
    g.step(g.s.on_wall)
    assert len(g.proposals()) == 1 and g.s.waiting
    g.readings(3.2)
    g.step(g.s.try_decide)
    assert [p.t for p in g.proposals()] == [3.13, 3.2]


def test_off_grid_draws_index_the_paper_modules_by_their_order_others_by_name():
    for index, name in enumerate(['innate', 'view', 'place']):
        expected = np.random.default_rng([1, 2, index, 2]).random()
        assert off_grid_rng(1, name, 2).random() == expected
    expected = np.random.default_rng([1, 2, 334884854, 0]).random()  # zlib.crc32(b'wall')
    assert off_grid_rng(1, 'wall', 0).random() == expected


# ------------------------------------------------------------------------------ observations

def test_the_other_modules_instants_are_observed_in_order_once(setup):
    """With innate (0.25 s) and view (0.5 s), view observes at ``t_0 + 0.25 + 0.5 l``, each
    once and in order, its own decisions in between."""
    g = Graph(setup, 'view', condition=[('innate', 0.25), ('view', 0.5)])
    g.start()
    for k in range(31):
        g.tick(k)
    g.step(g.s.end, T0 + 31 * DT)
    seq = [('observe', round(a.t - T0, 6)) if isinstance(a, PublishObservation)
           else ('propose', round(a.proposal.t - T0, 6))
           for a in g.out if isinstance(a, PublishObservation | Propose)]
    assert seq == [('propose', 0.0), ('observe', 0.25), ('propose', 0.5), ('observe', 0.75),
                   ('propose', 1.0), ('observe', 1.25), ('propose', 1.5)]
    alone = Graph(setup, 'view', condition=[('view', 0.5)])
    alone.start()
    for k in range(11):
        alone.tick(k)
    assert not [a for a in alone.out if isinstance(a, PublishObservation)]


def test_an_observation_does_not_overtake_the_modules_own_decision(setup):
    """View's readings of 0.5 to 0.75 come only after the episode's end: its decision of 0.5
    was never made, and innate's instant 0.75 after it is not observed either."""
    g = Graph(setup, 'view', condition=[('innate', 0.25), ('view', 0.5)])
    g.start()
    for k in range(16):
        g.tick(k, camera=k < 10)
    for k in range(10, 16):
        g.readings(T0 + k * DT, wheels=False)
    g.step(g.s.end, T0 + 16 * DT)
    assert [round(a.t - T0, 6) for a in g.out if isinstance(a, PublishObservation)] == [0.25]


def test_the_place_module_observes_once_the_wheel_reading_is_in(setup):
    g = Graph(setup, 'place')
    g.start()
    for k in range(5):
        g.tick(k)
    g.tick(5, wheels=False)
    assert not [a for a in g.out if isinstance(a, PublishObservation)]
    g.s.readings.add_wheels(T0 + 5 * DT, np.array([0.1, 0.12]))
    g.tick(6)
    assert [round(a.t - T0, 6) for a in g.out if isinstance(a, PublishObservation)] == [0.25]


class Wheels:
    """What :meth:`Readings.integrate` tells a decider."""

    def __init__(self) -> None:
        self.held: list[float] = []

    def on_wheels(self, v_left: float, v_right: float, dt: float) -> None:
        self.held.append(dt)


@pytest.mark.parametrize('on_ticks', [True, False])
def test_wheel_readings_are_held_whole_ticks_under_sim_time(setup, on_ticks):
    """Stamps ``t_0 + k dt`` differ by ``dt`` only to rounding: under sim time each reading
    is held exactly ``dt``, as the headless runner integrates; in real time the difference."""
    g = Graph(setup, 'place')
    rd = g.s.readings
    rd.integrated = T0
    stamps = [T0 + k * DT for k in range(1, 25)]
    for t in stamps:
        rd.add_wheels(t, np.array([0.1, 0.12]))
    w = Wheels()
    rd.integrate(stamps[-1], w, DT, on_ticks)
    diffs = np.diff([T0, *stamps])
    assert not np.all(diffs == DT)                  # the rounding is there to be removed
    assert w.held == ([DT] * 24 if on_ticks else diffs.tolist())
    assert rd.integrated == stamps[-1] and not rd.wheels


# ------------------------------------------------------------------------------ parameters

def _params(g: Graph, version: int) -> tuple:
    m = g.s.decider.module
    return (g.s.name, np.full(m.n, 0.5), np.zeros((2, m.n)), 0.2, version)


def test_a_start_waits_for_the_parameters_it_announces(setup):
    g = Graph(setup, 'view', params_timeout=5.0)
    g.readings(T0)
    g.start(params_version=2)
    assert not g.proposals()
    g.step(g.s.set_parameters, *_params(g, 2))
    (p,) = g.proposals()
    assert p.version == 2 and p.value == pytest.approx(0.5 * p.b.sum())


def test_announced_parameters_that_do_not_come_time_out(setup):
    g = Graph(setup, 'view', params_timeout=5.0)
    g.readings(T0)
    g.start(params_version=2)
    g.wall += 4.9
    g.step(g.s.on_wall)
    assert not g.proposals()
    g.wall += 0.2
    g.step(g.s.on_wall)
    (p,) = g.proposals()
    assert p.version == 0
    assert [a.level for a in g.out if isinstance(a, Log)] == ['warning']


def test_parameters_received_during_an_episode_wait_for_the_next(setup):
    g = Graph(setup, 'view')
    g.start()
    g.tick(0)
    g.step(g.s.set_parameters, *_params(g, 1))
    assert g.s.decider.version == 0
    g.step(g.s.end, T0 + DT)
    assert g.s.decider.version == 0
    g.start(T0 + 1.0)
    assert g.s.decider.version == 1
    g.step(g.s.set_parameters, 'innate', *_params(g, 3)[1:])
    assert g.s.decider.version == 1 and isinstance(g.out[-1], Log)


# ------------------------------------------------------------------------------ resending, stalls

def test_the_last_proposal_is_sent_again_while_the_clock_stands_at_it(setup):
    g = Graph(setup, 'view', resend_period=0.5)
    g.start()
    g.tick(0)
    (p,) = g.proposals()
    sent = next(a for a in g.out if isinstance(a, Propose))
    g.wall += 0.4
    assert not g.step(g.s.on_wall)
    g.wall += 0.1
    (again,) = g.step(g.s.on_wall)
    assert again == Propose(p, sent.stamp, again=True)
    g.wall += 0.4
    assert not g.step(g.s.on_wall)
    g.tick(1)
    g.wall += 1.0
    assert not g.step(g.s.on_wall)                 # the clock went on: the arbiter had it


def test_readings_between_episodes_are_a_wander_and_a_stand_still_a_stall(setup):
    """After an episode's end, readings that go on coming are the robot wandering to its next
    start: no warning however long that takes; readings that stop coming with no start event
    say why, once."""
    g = Graph(setup, 'view')
    g.start()
    g.tick(0)
    g.step(g.s.end, T0 + DT)
    t = T0 + DT
    for _ in range(int(4 * STALL_WARNING / 0.5)):      # a long wander, readings coming
        t += DT
        g.readings(t)
        g.t = t
        g.wall += 0.5
        g.step(g.s.on_wall)
    assert not [a for a in g.out if isinstance(a, Log)]
    for _ in range(int(STALL_WARNING / 0.5) + 4):      # then they stop: the clock stands
        g.wall += 0.5
        g.step(g.s.on_wall)
    (log,) = [a for a in g.out if isinstance(a, Log)]
    assert log.level == 'warning' and log.text.startswith('no start event seen')


def test_a_decision_due_for_long_says_why_once(setup):
    g = Graph(setup, 'view')
    g.start()
    for _ in range(int(STALL_WARNING / 0.5) + 4):
        g.wall += 0.5
        g.step(g.s.on_wall)
    (log,) = [a for a in g.out if isinstance(a, Log)]
    assert log.level == 'warning' and log.text.startswith('due: waiting for 2.0 s')
    g.readings(T0)
    g.step(g.s.on_wall)
    assert [p.t for p in g.proposals()] == [T0]
