"""The simulator as a plain robot world (``node.episodes: false``), for the standard path.

Pure: :class:`cr_sim.core.sim_episodes.SimEpisodes` in world mode drives a robot from start A
straight through the goal and on into short obstacle S4, past the time limit: no step ends
anything, nothing is summed, no event is made, the learner gate never holds and lockstep holds
at every tick until a command stamped at or after it (never one stamped before), the robot
moves at most one wheel-limited step per tick (never teleported, also not by ``reset`` or
``start``) and the obstacle blocks it. The same drive with episodes ends at the goal (the
drive does pass through it). An endless :class:`~cr_sim.core.sim.Simulator` never gives the
goal's reward and never ends. ROS: the node with ``node.episodes:=false`` runs its clock past
the time limit of config/sim.yaml, publishes ``image_raw``, ``scan`` and ``odom``, no
``episode`` and no ``reward`` message, drives under TwistStamped ``cmd_vel`` after the time
limit, and its ``reset`` moves nothing.
"""

from __future__ import annotations

import math

from cr_sim.core.arena import load_arena
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.robot import load_robot_params
from cr_sim.core.sim import Simulator, load_sim_params
from cr_sim.core.sim_episodes import SimEpisodes
import numpy as np
import pytest

DT = 0.05
TIME_LIMIT = 4.0                    # [s] of the pure tests: the drive lasts three times longer
FORWARD = np.array((0.4, 0.4))      # [m/s] from A toward the goal, then on into S4
V_MAX = load_robot_params().v_wheel_max


def world(episodes: bool = False) -> SimEpisodes:
    p = load_sim_params(overrides={'episode.time_limit': TIME_LIMIT})
    # gates that would hold at once if they were on
    gate = EpisodeGate(wait_for_learner=True, lockstep=True, command_timeout=1.0, dt=DT)
    return SimEpisodes(load_arena(), p, gate, seed=1, start='A', episodes=episodes,
                       clock=lambda: 0.0)


def test_world_mode_drives_past_the_goal_and_the_time_limit_without_an_end():
    core = world()
    arena = core.arena
    dest = np.array((arena.destination.x, arena.destination.y))
    assert not core.gate.wait_for_learner and core.gate.lockstep
    assert core.first(), 'world mode: no learner to wait for'
    assert core.start() is None, 'no start event'
    a = arena.start('A')
    assert np.allclose(core.sim.pose, [a.x, a.y, a.heading])
    poses, stamps, contacts, gaps = [core.sim.pose], [core.sim_time], [], []
    n = round(3 * TIME_LIMIT / DT)
    for k in range(n):
        if k:                                     # held at the last tick: an older command
            assert core.holding                   # does not release it, its own does
            core.command(FORWARD, core.sim_time - DT)
            assert core.holding and not core.stale(core.sim_time - DT)
        core.command(FORWARD, core.sim_time)
        assert not core.holding
        res = core.step()
        assert res is not None and not (res.done or res.reached or res.timeout), (k, res)
        assert core.finish(res) == (None, False)
        obs, _ = core.readings_now()
        assert obs is not None
        core.published(core.sim_time)
        assert core.holding and core.gate.t == core.sim_time, 'lockstep holds at every tick'
        poses.append(core.sim.pose)
        stamps.append(core.sim_time)
        contacts.append(res.collision)
        gaps.append(core.sim.gap)
        if k == n // 2:                           # neither a reset nor a start teleports it
            pose = core.sim.pose
            assert core.reset() is None and core.start() is None
            assert np.array_equal(core.sim.pose, pose)
    poses = np.array(poses)
    assert stamps[-1] == pytest.approx(n * DT) and stamps[-1] > 2 * TIME_LIMIT
    assert np.allclose(np.diff(stamps), DT), 'one tick of sim time per step'
    # continuous: at most one wheel-limited step of dt per tick
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    assert steps.max() <= V_MAX * DT + 1e-12, steps.max()
    # through the goal and on
    dist = np.hypot(*(poses[:, :2] - dest).T)
    inside = np.flatnonzero(dist <= arena.destination.goal_radius)
    assert inside.size and dist[inside[-1] + 1:].max() > 3 * arena.destination.goal_radius
    # into S4: blocked there without overlap, standing still past the time limit
    assert any(contacts) and min(gaps) >= 0.0
    assert np.ptp(poses[-20:, :2], axis=0).max() < 1e-9, 'pressed against S4, not moving'
    assert core.book.ret == 0.0 and core.episode == 0 and not core.book.running


def test_the_graph_gate_still_holds_the_world_until_its_subscribers_are_matched():
    core = world()
    assert not core.first(ready=False) and core.holding
    assert core.check_hold(lambda: ['image_raw: 0 of 1'])[0] is None and core.holding
    core.graph_check_at = 0.0                     # the next poll is due
    action, said = core.check_hold(lambda: [])
    assert action == 'start' and not core.holding, said
    assert core.start() is None
    a = core.arena.start('A')
    assert np.allclose(core.sim.pose, [a.x, a.y, a.heading])


def test_the_same_drive_with_episodes_ends_at_the_goal():
    core = world(episodes=True)
    core.gate.wait_for_learner = core.gate.lockstep = False
    assert core.first()
    assert core.start().name == 'start'
    for _ in range(round(TIME_LIMIT / DT)):
        core.command(FORWARD, core.sim_time)
        res = core.step()
        ev, _ = core.finish(res)
        if ev is not None:
            break
    assert ev is not None and ev.name == 'reached' and core.book.ret == 1.0


def test_an_endless_simulator_never_ends_nor_gives_the_goal_reward():
    p = load_sim_params(overrides={'episode.time_limit': 1.0})
    arena = load_arena()
    sims = {e: Simulator(arena, p, np.random.default_rng(0), endless=e) for e in (False, True)}
    for sim in sims.values():
        sim.reset(start=(0.3, 0.0, math.pi))     # the goal 0.3 m ahead
    rewards = {e: [] for e in sims}
    for _ in range(round(3.0 / DT)):
        for e, sim in sims.items():
            if not sim.done:
                res = sim.step((0.2, 0.2))
                rewards[e].append(res.reward)
                assert not (e and res.done)
    assert sims[False].done and rewards[False][-1] == 1.0
    assert not sims[True].done and sims[True].t == pytest.approx(3.0)
    assert all(r == 0.0 for r in rewards[True])
    # hold() in an endless simulator runs its n steps through the goal
    res, wheels = sims[True].hold(np.array((-0.2, -0.2)), 40)
    assert res.steps == 40 and not res.done and res.reward == 0.0


# ---------------------------------------------------------------------------- ROS

@pytest.mark.ros
def test_the_node_as_a_world_publishes_no_episode_and_drives_past_the_time_limit():
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TwistStamped, Vector3Stamped
    from nav_msgs.msg import Odometry
    from ros_util import Probe, assert_grid, start_node, stop
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Image, LaserScan
    from std_srvs.srv import Trigger

    from cr_sim import conversions as conv

    limit = load_sim_params().episode.time_limit     # config/sim.yaml: 60 s
    a = load_arena().start('A')

    def pose_of(m: Odometry) -> np.ndarray:
        q = m.pose.pose.orientation
        return np.array([m.pose.pose.position.x, m.pose.pose.position.y,
                         2 * math.atan2(q.z, q.w)])

    def stamp(m) -> float:
        return conv.from_time(m.clock if isinstance(m, Clock) else m.header.stamp)

    probe = Probe()
    proc = start_node('cr_sim.sim_node', '-p', 'node.episodes:=false',
                      '-p', 'node.standard_topics:=true', '-p', 'node.speed_factor:=0.0',
                      '-p', 'node.start:=A')
    try:
        probe.listen(Clock, '/clock', depth=1000)
        probe.listen(DiagnosticArray, 'episode', latched=True)
        probe.listen(Vector3Stamped, 'reward', depth=1000)
        probe.listen(Image, 'image_raw', depth=10)
        probe.listen(LaserScan, 'scan', depth=1000)
        probe.listen(Odometry, 'odom', depth=1000)
        msgs = probe.msgs

        def past_limit() -> bool:
            return bool(msgs['/clock'] and stamp(msgs['/clock'][-1]) > limit + 1.0
                        and msgs['image_raw'] and msgs['scan'] and msgs['odom'])
        assert probe.spin_until(past_limit, 90), (
            {t: len(v) for t, v in msgs.items()}, stop(proc))
        img, scan = msgs['image_raw'][-1], msgs['scan'][-1]
        assert (img.width, img.height, img.encoding) == (360, 40, 'rgb8')
        assert len(scan.ranges) == 7 and stamp(scan) > 0.0
        # never commanded yet: standing at A, past the time limit
        assert np.allclose(pose_of(msgs['odom'][-1]), [a.x, a.y, a.heading], atol=1e-9)

        pub = probe.node.create_publisher(TwistStamped, 'cmd_vel', 10)
        assert probe.spin_until(lambda: pub.get_subscription_count() > 0, 10), stop(proc)
        n = len(msgs['odom'])
        cmd = TwistStamped()
        cmd.twist.linear.x = 0.2

        def moved() -> float:
            return float(np.hypot(*(pose_of(msgs['odom'][-1])[:2] - (a.x, a.y))))

        def drive_until(done) -> None:
            for _ in range(1000):                         # a hang guard, not a window
                pub.publish(cmd)
                probe.spin_for(0.02)
                if done():
                    return
            pytest.fail(f'cmd_vel: not done; moved {moved():.3f} m')
        drive_until(lambda: moved() > 0.3)
        driven = msgs['odom'][n:]
        assert min(stamp(m) for m in driven) > limit
        assert max(m.twist.twist.linear.x for m in driven) == pytest.approx(0.2, rel=1e-6)
        # a world has no episode to reset: refused, and the robot is not teleported
        client = probe.node.create_client(Trigger, 'reset')
        assert client.wait_for_service(timeout_sec=10)
        future = client.call_async(Trigger.Request())
        assert probe.spin_until(future.done, 10) and not future.result().success
        n = len(msgs['odom'])
        drive_until(lambda: len(msgs['odom']) > n + 20 and moved() > 0.5)
        # continuous over all the odometry that arrived: one tick apart, at most one
        # wheel-limited step (consecutive publications only: the probe may lose some)
        odom, seqs = msgs['odom'], probe.seqs['odom']
        assert_grid([stamp(m) for m in odom], seqs, 0.05, 'odom')
        jumps = [float(np.hypot(*(pose_of(b)[:2] - pose_of(a_)[:2])))
                 for a_, b, qa, qb in zip(odom, odom[1:], seqs, seqs[1:]) if qb == qa + 1]
        assert max(jumps) <= V_MAX * 0.05 + 1e-9, max(jumps)
        probe.spin_for(0.5)
        assert not msgs['episode'], [m.status[0].message for m in msgs['episode']]
        assert not msgs['reward']
    finally:
        out = stop(proc)
        probe.close()
    assert 'Traceback' not in out, out
