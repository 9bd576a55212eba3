"""cr_bridge pure cores: the command guard, backoff, device clock, the robot-side episode logic,
and the emulated device; and that device + episode logic give the simulator's rewards."""

from __future__ import annotations

import math

from cr_bridge.core import protocol as proto
from cr_bridge.core.device import Device
from cr_bridge.core.episode import ContactParams, Reading, RobotEpisodes
from cr_bridge.core.safety import Backoff, CommandGuard, DeviceClock
from cr_sim.core.arena import load_arena
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.sim import Simulator, load_sim_params
import numpy as np
import pytest

BUMP = ContactParams(bump=True, accel_threshold=0.0, ir_contact=0.0)


def test_guard_clamps_rejects_non_finite_and_the_watchdog_zeroes():
    g = CommandGuard(v_max=1.3, watchdog=0.2)
    assert g.command((0.5, 3.0), now=10.0)
    assert g.output(10.1).tolist() == [0.5, 1.3] and g.clamped == 1
    for bad in ((math.nan, 0.2), (0.2, math.inf), (-math.inf, 0.0)):
        assert not g.command(bad, now=10.1)
        assert g.output(10.15).tolist() == [0.0, 0.0], 'a NaN never reaches a motor'
    assert g.rejected == 3
    g.command((0.3, 0.3), now=11.0)
    assert g.output(11.2).tolist() == [0.3, 0.3]
    assert g.output(11.2001).tolist() == [0.0, 0.0] and g.expired(11.25)
    assert g.trips == 1
    g.stop()
    assert g.output(11.21).tolist() == [0.0, 0.0]


def test_backoff_doubles_up_to_its_maximum_and_starts_over_on_success():
    b = Backoff(0.1, 1.0)
    assert [b.failure() for _ in range(6)] == pytest.approx([0.1, 0.2, 0.4, 0.8, 1.0, 1.0])
    b.success()
    assert b.failure() == pytest.approx(0.1)


def test_device_clock_starts_at_zero_and_stays_monotonic_over_a_reboot():
    c = DeviceClock(dt=0.05)
    assert [c(t) for t in (100.0, 100.05, 100.1)] == pytest.approx([0.0, 0.05, 0.1])
    assert c(0.0) == pytest.approx(0.15) and c(0.05) == pytest.approx(0.2)


def reading(t, ir=0.5, dest=(0.3, 1.0), bump=0, wheels=(0.0, 0.0), accel=(0.0, 0.0, 9.8)):
    return Reading(t, np.full(7, ir), dest[0], dest[1], np.zeros(4), np.array(wheels), bump,
                   accel)


def episodes(start='here', gate=None, contact=BUMP, time_limit=2.0, wander_time=0.5):
    p = load_sim_params(overrides={'episode.time_limit': time_limit,
                                   'episode.wander_time': wander_time})
    return RobotEpisodes(p.episode, p.wander, contact, 0.15,
                         np.deg2rad(p.sensors.ir_angles_deg), gate or EpisodeGate(),
                         np.random.default_rng(0), start)


def test_episode_rewards_collisions_reached_and_the_wander_to_the_next_start():
    e = episodes()
    s = e.step(reading(0.0), now=0.0)
    assert [ev.name for ev in s.events] == ['start'] and s.reward is None and e.running
    assert e.step(reading(0.05), 0.0).reward == 0.0
    rewards = [e.step(reading(0.05 * k, bump=b), 0.0).reward
               for k, b in zip(range(2, 7), (1, 1, 0, 1, 1))]
    assert rewards == [-0.1, 0.0, 0.0, -0.1, 0.0], 'once per new contact'
    s = e.step(reading(0.35, dest=(0.0, 0.149)), 0.0)
    assert s.reward == pytest.approx(1.0) and [ev.name for ev in s.events] == ['reached']
    end = s.events[0]
    assert end.values['episode_return'] == pytest.approx(0.8)
    assert end.values['duration'] == pytest.approx(0.35)
    # wander: wheel commands of the wander policy, no reward, then the next start
    t, s = 0.35, None
    while True:
        t += 0.05
        s = e.step(reading(t), 0.0)
        if s.events:
            break
        assert s.wander is not None and s.reward is None
    assert s.events[0].name == 'start' and s.events[0].values['episode'] == 2
    assert t - 0.35 == pytest.approx(0.5 + 0.05), 'after wander_time'


def test_episode_timeout_and_no_start_in_the_goal():
    e = episodes(time_limit=1.0, wander_time=0.0)
    e.step(reading(0.0), 0.0)
    names = [ev.name for k in range(1, 21) for ev in e.step(reading(0.05 * k), 0.0).events]
    assert names == ['timeout']
    assert e.step(reading(1.05, dest=(0.0, 0.1)), 0.0).events == [], 'not in the goal'
    assert e.step(reading(1.1), 0.0).events[0].name == 'start'


def test_the_learner_gate_keeps_the_robot_wandering_until_it_reports():
    gate = EpisodeGate(wait_for_learner=True, learner_timeout=10.0)
    e = episodes(start='wander', gate=gate, wander_time=0.1)
    assert e.step(reading(0.0), now=0.0).events == [], 'the learner is not up yet'
    gate.on_progress(0, 0)
    assert e.step(reading(0.05), 0.0).events == []     # wander_time not over
    assert e.step(reading(0.2), 0.0).events[0].values == {'episode': 1, 'start': 'wander',
                                                          'params_version': 0}
    ends = [ev for k in range(5, 60) for ev in e.step(reading(0.05 * k), 1.0).events]
    assert [ev.name for ev in ends] == ['timeout']
    for k in range(60, 90):
        s = e.step(reading(0.05 * k), now=2.0)
        assert not s.events and s.wander is not None, 'waiting for the learner'
    gate.on_progress(1, 7)
    s = e.step(reading(4.5), now=3.0)
    assert s.events[0].name == 'start' and s.events[0].values['params_version'] == 7
    # and without a report, the timeout opens the gate
    ends = [ev for k in range(91, 140) for ev in e.step(reading(0.05 * k), 4.0).events]
    assert ends[0].name == 'timeout'
    assert not e.step(reading(7.05), 5.0).events
    assert e.step(reading(7.1), 14.5).events[0].name == 'start'


def test_accelerometer_and_ir_contacts_when_enabled():
    e = episodes(contact=ContactParams(bump=False, accel_threshold=20.0, ir_contact=0.01))
    e.step(reading(0.0), 0.0)
    assert e.step(reading(0.05, bump=1), 0.0).reward == 0.0, 'bump switch not used'
    assert e.step(reading(0.1, accel=(-25.0, 0.0, 9.8)), 0.0).reward == pytest.approx(-0.1)
    assert e.step(reading(0.15), 0.0).reward == 0.0
    assert e.step(reading(0.2, ir=0.005), 0.0).reward == pytest.approx(-0.1)


def make_sim(seed=0, time_limit=60.0):
    params = load_sim_params(overrides={'episode.time_limit': time_limit})
    return Simulator(load_arena(), params, np.random.default_rng(seed))


def test_device_executes_commands_stops_on_its_own_and_outlives_episodes():
    sim = make_sim(time_limit=0.5)
    sim.reset(start='A')
    dev = Device(sim, np.random.default_rng(1), true_pose=True, heartbeat_every=5)
    host = proto.FrameParser()
    dev.receive(proto.encode(proto.WheelCommand(0.3, 0.3, timeout=0.2), 0))
    frames = [f for _ in range(12) for raw in dev.tick() for f in host.feed(raw)]
    sensors = [f.payload for f in frames if f.type is proto.MsgType.SENSORS]
    assert len(sensors) == 12 and len(sensors[0].ir) == 7 and len(sensors[0].bearings) == 5
    assert sensors[0].wheels == pytest.approx((0.3, 0.3))
    assert sensors[5].wheels == (0.0, 0.0), 'its own watchdog stopped it after 0.2 s'
    types = [f.type for f in frames]
    assert proto.MsgType.TRUE_POSE in types and proto.MsgType.HEARTBEAT in types
    errors = [f.payload.code for f in frames if f.type is proto.MsgType.ERROR]
    assert errors == [proto.ErrorCode.WATCHDOG_STOP]
    assert dev.t == pytest.approx(0.6), 'the time limit of the sim episode does not stop it'
    d = sensors[0].distances[0]
    a = load_arena().start('A')
    assert d == pytest.approx(math.hypot(a.x, a.y), abs=0.05), 'range of the destination'
    dev.receive(b'\x00garbage' + proto.encode(proto.WheelCommand(5.0, 0.0), 1))
    assert dev.pending and dev.u.tolist() == [1.3, 0.0], 'clamped, and reported'


def test_device_and_robot_episodes_give_the_simulators_rewards_tick_for_tick():
    """The same commands: the simulator's own reward/episode logic and the bridge's (from the
    device's frames) agree on every tick: collisions, reached, the return."""
    ref = make_sim(seed=3)
    ref.reset(start='A')
    dest = np.array([0.0, 0.0])
    commands, rewards = [], []
    for k in range(2000):
        x, y, th = ref.pose
        if k < 30:
            u = (-0.6, -0.6)                             # back into the corner: a collision
        elif k < 45:
            u = (0.4, 0.4)                               # off the wall
        else:
            b = math.remainder(math.atan2(dest[1] - y, dest[0] - x) - th, 2 * math.pi)
            w = float(np.clip(3.0 * b, -3.0, 3.0))
            u = (0.4 - 0.08 * w, 0.4 + 0.08 * w)
        u = tuple(round(v, 3) for v in u)                # the wire carries mm/s
        commands.append(u)
        res = ref.step(u)
        rewards.append(res.reward)
        if res.done:
            assert res.reached
            break
    assert rewards.count(-0.1) >= 1 and rewards[-1] == pytest.approx(1.0)

    sim = make_sim(seed=3, time_limit=3600.0)
    sim.reset(start='A')
    dev = Device(sim, np.random.default_rng(0))
    host = proto.FrameParser()
    e = episodes(time_limit=60.0)
    first = reading(0.0, dest=(0.0, 2.0))
    assert e.step(first, 0.0).events[0].name == 'start'
    got = []
    for u in commands:
        dev.receive(proto.encode(proto.WheelCommand(*u, timeout=1.0), len(got)))
        for f in (f for raw in dev.tick() for f in host.feed(raw)):
            if f.type is proto.MsgType.SENSORS:
                s = f.payload
                r = Reading(s.t, np.array(s.ir), s.bearings[0], s.distances[0],
                            np.array(s.bearings[1:]), np.array(s.wheels), s.bump, s.accel)
                got.append(e.step(r, 0.0).reward)
    assert got == pytest.approx(rewards)
    assert not e.running, 'the bridge saw the destination reached at the same tick'
