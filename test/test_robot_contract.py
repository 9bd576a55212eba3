"""The robot interface contract, run against the simulator and against the bridge + emulator.

The modules must not be able to tell the two apart: the same topics, types, QoS, frames and
rates (in the clock's time), the same command handling and safety, and the same reward and
episode semantics (+1 and ``reached`` at the destination, -0.1 once per new contact, ``timeout``
after ``episode.time_limit``, one reward per tick of an episode, the next ``start`` after).
"""

from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped, Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from robot_util import Robot
from ros_util import Probe, assert_grid
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, LaserScan
from visualization_msgs.msg import MarkerArray

from cr_sim import conversions as conv

pytestmark = pytest.mark.ros

SPEED = 5.0          # clock seconds per wall second
TICK = 0.05          # config/sim.yaml episode.dt
TIME_LIMIT = 20.0    # episode.time_limit for these tests [s]
STREAMS = {'/clock': Clock, 'ir': LaserScan, 'ir_ranges': JointState, 'camera': JointState,
           'wheels': JointState, 'reward': Vector3Stamped, 'odom': Odometry,
           'markers': MarkerArray}
RATES = {'/clock': 20.0, 'ir': 20.0, 'ir_ranges': 20.0, 'camera': 20.0, 'wheels': 20.0,
         'reward': 20.0, 'odom': 20.0, 'markers': 10.0}


def stamp(msg) -> float:
    if isinstance(msg, Clock):
        return conv.from_time(msg.clock)
    if isinstance(msg, MarkerArray):
        return conv.from_time(msg.markers[0].header.stamp)
    return conv.from_time(msg.header.stamp)


def events(probe) -> list[tuple[float, str, dict]]:
    return [conv.episode_from_msg(m) for m in probe.msgs['episode']]


@pytest.fixture(scope='module', params=['sim', 'bridge'])
def robot(request):
    p = Probe(f'contract_{request.param}')
    # the bridge's link timeout is wall time: a host loaded for a moment (an emulator not
    # scheduled for 0.5 s) must not end an episode here (link loss: test_bridge_node)
    extra = ('-p', 'node.link_timeout:=30.0') if request.param == 'bridge' else ()
    r = Robot(request.param, SPEED, '-p', f'episode.time_limit:={TIME_LIMIT}', *extra)
    p.listen(MarkerArray, 'arena', latched=True)
    p.listen(DiagnosticArray, 'episode', latched=True, depth=100)
    for topic, msg_type in STREAMS.items():
        p.listen(msg_type, topic, depth=1000)
    p.pub = p.node.create_publisher(TwistStamped, 'cmd_vel', 10)
    ok = p.spin_until(lambda: len(p.msgs['/clock']) > 5 and events(p), 40)
    if not ok:
        out = r.close()
        p.close()
        pytest.fail(f'{request.param}: no clock / episode start:\n{out}')
    yield r, p
    p.close()
    out = r.close()
    assert 'Traceback' not in out, out


def heading_controller(p, reverse_away: bool = False):
    """(v, w) toward the destination by its camera bearing (NaN: turn in place)."""
    cam = p.msgs['camera'][-1]
    b = dict(zip(cam.name, cam.position))['destination']
    if math.isnan(b):
        return 0.0, 1.5
    return (0.4 if abs(b) < 0.6 else 0.0), 3.0 * b


def test_reaching_the_destination_gives_plus_one_and_ends_the_episode(robot):
    """Episode 1 starts at A (the simulator's start; the emulator's robot stands there).

    The controller steers by each new camera reading; an episode lasts ``TIME_LIMIT`` of
    clock (4 s wall here) and on a loaded machine the Python controller may not get there
    in one: then it tries the next episode (a hang guard of 8, not a window)."""
    _, p = robot
    _, event, values = events(p)[0]
    assert (event, values['episode']) == ('start', '1'), events(p)

    def reached() -> bool:
        return any(e == 'reached' for _, e, _ in events(p))

    def running() -> bool:
        return events(p)[-1][1] == 'start'

    for _ in range(8):
        assert p.spin_until(running, TIME_LIMIT / SPEED * 4 + 30), events(p)[-3:]
        seen = len(p.msgs['camera'])
        while running() and not reached():
            if len(p.msgs['camera']) > seen:             # a new reading: a new decision
                seen = len(p.msgs['camera'])
                v, w = heading_controller(p)
                msg = TwistStamped()
                msg.twist.linear.x, msg.twist.angular.z = v, w
                p.pub.publish(msg)
            p.spin_once()
        if reached():
            break
    assert reached(), 'the destination was not reached in 8 episodes'
    t_end, _, values = next(e for e in events(p) if e[1] == 'reached')
    ep = int(values['episode'])
    # the end event and the rewards travel on two topics: wait for the episode's last reward
    assert p.spin_until(lambda: any(t >= t_end - 1e-6 for t, _, _ in _episode_rewards(p, ep)),
                        60)
    rewards = _episode_rewards(p, ep)
    goal = [(t, r) for t, r, _ in rewards if r >= 1.0 - 0.11]
    assert len(goal) == 1 and goal[0][0] == pytest.approx(t_end, abs=1e-6)
    assert goal[0][1] in (pytest.approx(1.0), pytest.approx(0.9)), 'reward_goal (+ a contact)'
    assert float(values['episode_return']) == pytest.approx(sum(r for _, r, _ in rewards))
    assert rewards[-1][2] == pytest.approx(float(values['episode_return']))
    assert max(t for t, _, _ in rewards) == pytest.approx(t_end, abs=1e-6), 'no reward after'
    # the next episode starts after the end (the sim at its start, the bridge after a wander)
    def next_start():
        return next((e for e in events(p) if e[1] == 'start' and e[0] > t_end), None)
    assert p.spin_until(lambda: next_start() is not None, 60), events(p)[-3:]
    t_next, _, v2 = next_start()
    assert int(v2['episode']) == ep + 1 and t_next > t_end


def test_topics_types_frames_and_rates(robot):
    _, p = robot
    for topic in STREAMS:
        p.msgs[topic].clear()
        p.seqs[topic].clear()
    # a bounded stream judged on what arrived (the publisher's grid between consecutive
    # sequence numbers), not how much of it reached the probe per wall second
    want = {t: 20 if t in ('markers', 'reward') else 40 for t in RATES}
    assert p.spin_until(lambda: all(len(p.msgs[t]) >= n for t, n in want.items()), 120), \
        {t: len(p.msgs[t]) for t in RATES}
    for topic, rate in RATES.items():
        stamps = [stamp(m) for m in p.msgs[topic]]
        assert all(b > a for a, b in zip(stamps, stamps[1:])), f'{topic}: stamps increase'
        seqs = p.seqs[topic]
        if topic == 'reward':       # within an episode only (the bridge wanders between them)
            last = int(p.msgs[topic][-1].vector.z)
            keep = [k for k, m in enumerate(p.msgs[topic]) if int(m.vector.z) == last]
            stamps, seqs = [stamps[k] for k in keep], [seqs[k] for k in keep]
            if len(stamps) < 12:
                continue            # the last episode just started: judged in the idle test
        assert_grid(stamps, seqs, 1.0 / rate, topic)
    scan = p.msgs['ir'][-1]
    assert scan.header.frame_id == 'base_link' and len(scan.ranges) == 7
    assert scan.angle_min == pytest.approx(-math.pi / 2) and scan.range_max == pytest.approx(0.5)
    assert all(0.0 <= r <= scan.range_max for r in scan.ranges)
    # the same beams at full precision (what the modules read): the scan is their float32
    full = {round(stamp(m), 6): m for m in p.msgs['ir_ranges']}
    pairs = [(s, full[round(stamp(s), 6)]) for s in p.msgs['ir'] if round(stamp(s), 6) in full]
    assert len(pairs) > 10, (len(pairs), len(p.msgs['ir']), len(p.msgs['ir_ranges']))
    for s, f in pairs:
        assert list(f.name) == [f'ir_{k}' for k in range(7)] and f.header.frame_id == 'base_link'
        assert np.array_equal(np.asarray(f.position, np.float32), np.asarray(s.ranges)), (s, f)
    cam = p.msgs['camera'][-1]
    assert cam.header.frame_id == 'base_link'
    assert list(cam.name) == ['destination', 'L1', 'L2', 'L3', 'L4']
    assert all(math.isnan(b) or -math.pi <= b <= math.pi for b in cam.position)
    wheels = p.msgs['wheels'][-1]
    assert list(wheels.name) == ['left_wheel', 'right_wheel'] and len(wheels.velocity) == 2
    odom = p.msgs['odom'][-1]
    assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_link')
    assert abs(odom.pose.pose.position.x) < 1.5 and abs(odom.pose.pose.position.y) < 1.5
    starts = [int(v['episode']) for _, e, v in events(p) if e == 'start']
    assert starts == list(range(1, len(starts) + 1)), 'episodes are numbered 1, 2, ...'
    last = [m for m in p.msgs['reward'] if stamp(m) >= events(p)[-1][0]]
    assert all(m.vector.z == starts[-1] for m in last), 'reward.z is the episode index'
    assert p.spin_until(lambda: p.msgs['arena'], 5), 'arena markers are latched'


def test_commands_drive_nan_never_moves_and_wheels_are_clamped(robot):
    _, p = robot

    # NaN commands until 60 readings arrived and the last 30 of them at rest: none moves it.
    # Judged on every reading from the first still one (the probe may lag the robot: the
    # latest reading at a wall instant can be an old one). An episode that ends meanwhile
    # puts the robot back at its start (the sim) or wanders (the bridge): that try does not
    # count, and it is found by the rewards (one per tick within an episode, stamped in sim
    # time with the episode's index), not by the episode events, which may reach this probe
    # after the readings.
    def at(m) -> np.ndarray:
        return np.array([m.pose.pose.position.x, m.pose.pose.position.y])

    def turning(m) -> bool:
        return abs(m.twist.twist.linear.x) > 1e-6 or abs(m.twist.twist.angular.z) > 1e-6

    def still() -> bool:
        # the wheels of three readings in a row at rest, and their poses equal: one pair of
        # equal poses is not enough (the bridge's pose is the device's TRUE_POSE frame of the
        # tick before, and a lost one repeats the pose before it while the robot still moves)
        last = p.msgs['odom'][-3:]
        return len(last) == 3 and not any(turning(m) for m in last) \
            and all(np.allclose(at(last[0]), at(m), atol=1e-4) for m in last)

    def pose():
        return at(p.msgs['odom'][-1])

    def publish_until(v: float, done, steps: int = 2000, w: float = 0.0) -> bool:
        msg = TwistStamped()
        msg.twist.linear.x, msg.twist.angular.z = v, w
        for _ in range(steps):                  # a hang guard, not a window
            p.pub.publish(msg)
            p.spin_for(0.02)
            if done():
                return True
        return False

    def moving(drive: list) -> list[int]:
        return [k for k, m in enumerate(drive) if turning(m)]

    def settled(n: int) -> bool:
        drive = p.msgs['odom'][n:]
        k = moving(drive)
        return len(drive) >= 60 and len(drive) - (k[-1] + 1 if k else 0) >= 30

    def one_episode(drive: list) -> bool:
        t0, t1 = stamp(drive[0]), stamp(drive[-1])
        assert p.spin_until(lambda: p.msgs['reward'] and stamp(p.msgs['reward'][-1]) > t1,
                            120), 'no reward after the NaN drive'      # a hang guard
        inside = [m for m in p.msgs['reward'] if t0 <= stamp(m) <= t1]
        # no change of episode, and no gap at its end (the bridge's wander gives no reward)
        return (len({int(m.vector.z) for m in inside}) == 1
                and stamp(inside[-1]) >= t1 - 2 * TICK)

    for _ in range(5):
        # each try from where a command moves the robot: a little back (commanded until it has
        # moved 5 cm; A faces the goal, the bridge's next episodes start where its wander left
        # the robot, maybe with its back to a wall: then the try does not count), so that there
        # is room in front of it
        p0 = pose()
        if not publish_until(-0.1, lambda p0=p0: np.hypot(*(pose() - p0)) > 0.05, 400):
            continue
        assert publish_until(0.0, still), 'the robot did not stop'
        n = len(p.msgs['odom'])
        assert publish_until(float('nan'), lambda n=n: settled(n), 4000), \
            'the robot did not stand in a NaN drive'
        drive_nan = list(p.msgs['odom'][n:])
        if one_episode(drive_nan):
            break
    else:
        raise AssertionError('no NaN drive within one episode in five tries')
    # 'still' may also be a watchdog's stop while this probe was not scheduled, and -0.1 m/s
    # commands still in flight then move the robot at the start of the NaN drive (commands
    # arrive in the order published: none after the first 0 or NaN one; on a loaded host
    # late enough that no share of the readings bounds them): the robot may move only
    # backwards at up to that earlier command's speed, without turning, and it stands for the
    # last 30 readings at least
    moved_at = moving(drive_nan)
    rest = moved_at[-1] + 1 if moved_at else 0
    assert all(-0.1 - 1e-3 <= drive_nan[k].twist.twist.linear.x <= 0.0
               and abs(drive_nan[k].twist.twist.angular.z) <= 1e-3 for k in moved_at), \
        'moved by a NaN command, not by an earlier one'
    p1 = at(drive_nan[rest])
    assert all(np.allclose(p1, at(m), atol=2e-3) for m in drive_nan[rest:]), \
        'a NaN command must not move the robot'
    n = len(p.msgs['wheels'])

    def spun() -> bool:
        return any(max(abs(v) for v in m.velocity) > 1.0 for m in p.msgs['wheels'][n:])

    assert publish_until(0.0, spun, w=40.0)  # spin far over the wheel limit
    publish_until(0.0, still)
    speeds = [max(abs(v) for v in m.velocity) for m in p.msgs['wheels'][n:]]
    assert max(speeds) <= 1.3 + 1e-3, f'wheel speed {max(speeds)} over the limit'
    assert max(speeds) > 1.0, 'the spin command was executed (clamped)'


def _episode_rewards(p, episode: int) -> list[tuple[float, float, float]]:
    return [(stamp(m), m.vector.x, m.vector.y) for m in p.msgs['reward']
            if int(m.vector.z) == episode]


def test_an_idle_episode_times_out_with_one_reward_per_tick(robot):
    """No command: ``timeout`` after ``TIME_LIMIT``, one reward per tick, and no collision once
    the robot is at rest (the simulator starts each episode at rest; the bridge where the wander
    left it, moving until its zero command reaches the device)."""
    _, p = robot
    n = len(events(p))
    assert p.spin_until(lambda: len(events(p)) > n and events(p)[-1][1] == 'start',
                        TIME_LIMIT / SPEED * 4 + 10), 'a fresh episode'
    t0, event, values = events(p)[-1]
    ep = int(values['episode'])
    assert p.spin_until(lambda: events(p)[-1][1] == 'timeout', TIME_LIMIT / SPEED * 4 + 60)
    t_end, _, v = events(p)[-1]
    assert int(v['episode']) == ep
    assert t_end - t0 == pytest.approx(TIME_LIMIT, abs=1e-3)
    assert float(v['duration']) == pytest.approx(TIME_LIMIT, abs=1e-3)
    # the rewards travel on their own topic, in the order published: once one of a later
    # episode has arrived, every one of this episode that the probe will get is in (and the
    # wheels, their own topic, once one stamped after the end is in). The probe (a reader
    # that lags can lose some) is judged on what it got: the publishers' sequence numbers
    # count what was published
    def later(topic: str, done) -> bool:
        return bool(p.msgs[topic]) and done(p.msgs[topic][-1])
    assert p.spin_until(lambda: later('reward', lambda m: int(m.vector.z) > ep)
                        and later('wheels', lambda m: stamp(m) > t_end + 1e-6),
                        TIME_LIMIT / SPEED * 4 + 60), events(p)[-3:]
    got = [(stamp(m), m.vector.x, q) for m, q in zip(p.msgs['reward'], p.seqs['reward'])
           if int(m.vector.z) == ep]
    assert len(got) > 10, got
    rewards = [(t, r, 0.0) for t, r, _ in got]
    stamps = [t for t, _, _ in got]
    n = round(TIME_LIMIT / TICK)
    ks = [round((t - t0) / TICK) for t in stamps]
    # on the tick grid of the episode (t0 + k TICK, k = 1..n), in order, none twice
    assert all(abs(t - t0 - k * TICK) < 1e-6 for t, k in zip(stamps, ks)), stamps[:5]
    assert ks == sorted(set(ks)) and 1 <= ks[0] and ks[-1] <= n, ks
    published = [(k, q) for k, (_, _, q) in zip(ks, got)]
    # one reward per reading: between two rewards received, as many rewards were published
    # as readings (wheels, published with each) were, judged where the probe has the
    # readings of both instants
    wheels = {round(stamp(m), 6): q for m, q in zip(p.msgs['wheels'], p.seqs['wheels'])}
    paired = 0
    for (ta, _, qa), (tb, _, qb) in zip(got, got[1:]):
        wa, wb = wheels.get(round(ta, 6)), wheels.get(round(tb, 6))
        if wa is not None and wb is not None:
            assert qb - qa == wb - wa, (ta, tb, qb - qa, wb - wa)
            paired += 1
    assert paired >= 10, (paired, len(got))
    for (ka, qa), (kb, qb) in zip(published, published[1:]):
        if robot[0].kind == 'sim':      # one reward per tick, nothing else
            assert qb - qa == kb - ka, ((ka, qa), (kb, qb))
        else:   # one per frame received: a frame lost on the line (counted) has none
            assert 0 < qb - qa <= kb - ka, ((ka, qa), (kb, qb))
    if ks[0] == 1 and ks[-1] == n:      # the probe got the first and the last one
        count = published[-1][1] - published[0][1] + 1
        assert count == n if robot[0].kind == 'sim' else 0 < count <= n, count
    hits = [(k, r) for k, (_, r, _) in zip(ks, rewards) if r != 0.0]
    if robot[0].kind == 'sim':      # every episode starts at rest
        assert not hits, ('standing still collides with nothing', hits)
        return
    # the bridge's episode starts where the wander left the robot, still moving: the zero
    # command sent at the start frame reaches the device (another process) some frames later
    # on a loaded host. Judged by the wheel readings that arrived (k = 0 is the start frame):
    # the robot comes to rest and stays there, and a contact is new only while it still moves
    moving = {round((stamp(m) - t0) / TICK): bool(np.any(np.asarray(m.velocity) != 0.0))
              for m in p.msgs['wheels'] if t0 - 1e-6 <= stamp(m) <= t_end + 1e-6}
    assert moving and not moving[max(moving)], ('the robot comes to rest', sorted(moving.items()))
    k_rest = min(k for k in moving if not any(moving[j] for j in moving if j >= k))
    assert all(r == pytest.approx(-0.1) and k <= k_rest
               and (moving.get(k - 1, True) or moving.get(k, True)) for k, r in hits), \
        ('standing still collides with nothing', hits, k_rest, sorted(moving.items())[:k_rest + 2])


def test_a_collision_costs_once_while_pressed(robot):
    """Backing away from the destination runs into a wall: -0.1 once, however long it presses.

    An episode lasts ``TIME_LIMIT`` of clock (4 s wall here); on a loaded machine turning to
    face the destination can take most of that, and the episode may end before the robot
    reaches a wall. Then the next episode is tried, three at most.
    """
    _, p = robot
    def hit(ep: int) -> bool:
        return any(r < 0 for _, r, _ in _episode_rewards(p, ep))

    def over(ep: int) -> bool:
        return events(p)[-1][1] != 'start' or int(events(p)[-1][2]['episode']) != ep

    def command(v: float, w: float) -> None:
        msg = TwistStamped()
        msg.twist.linear.x, msg.twist.angular.z = v, w
        p.pub.publish(msg)

    for _ in range(6):                              # a hang guard, not a window
        n = len(events(p))
        assert p.spin_until(lambda n=n: len(events(p)) > n and events(p)[-1][1] == 'start',
                            TIME_LIMIT / SPEED * 4 + 60), 'a fresh episode'
        ep = int(events(p)[-1][2]['episode'])
        # face the destination (a decision per new camera reading), then back away from it
        # into whatever is behind (a wall), until the contact or the episode's end
        seen = len(p.msgs['camera'])
        while not over(ep):
            if len(p.msgs['camera']) > seen:
                seen = len(p.msgs['camera'])
                v, w = heading_controller(p)
                if abs(w) < 0.1 and v > 0:
                    break
                command(0.0, w)
            p.spin_once()
        while not (hit(ep) or over(ep)):
            command(-0.8, 0.0)
            p.spin_for(0.02)
        if hit(ep):
            break
    assert hit(ep), 'no collision backing away, in six episodes'
    # keep pressing for 40 more wheel readings of this episode (2 s of clock), or to its end
    n = len(p.msgs['wheels'])
    while len(p.msgs['wheels']) < n + 40 and not over(ep):
        command(-0.8, 0.0)
        p.spin_for(0.02)
    assert p.spin_until(lambda: over(ep), TIME_LIMIT / SPEED * 4 + 60)
    assert p.spin_until(lambda: any(e[1] != 'start' and int(e[2]['episode']) == ep
                                    for e in events(p)), 60)
    t_end = next(e[0] for e in events(p) if e[1] != 'start' and int(e[2]['episode']) == ep)
    assert p.spin_until(lambda: any(t >= t_end - 1e-6 for t, _, _ in _episode_rewards(p, ep)),
                        60)
    hits = [(t, r) for t, r, _ in _episode_rewards(p, ep) if r < 0]
    assert [r for _, r in hits] == [pytest.approx(-0.1)], hits
    # pressed against it from two ticks after the contact to the episode's end: it does not
    # move (the executed wheels, by their stamps)
    pressed = [m for m in p.msgs['wheels'] if hits[0][0] + 2 * TICK <= stamp(m) <= t_end]
    assert all(abs(sum(m.velocity)) < 0.8 for m in pressed), 'pressed: it does not move'


def test_qos_and_the_reset_service(robot):
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
    _, p = robot
    latched = {'/episode', '/arena'}
    for topic in ['/clock', '/ir', '/camera', '/wheels', '/reward', '/odom', '/markers',
                  *latched]:
        infos = p.node.get_publishers_info_by_topic(topic)
        assert len(infos) == 1, topic
        qos = infos[0].qos_profile
        assert qos.reliability == ReliabilityPolicy.RELIABLE, topic
        assert qos.durability == (DurabilityPolicy.TRANSIENT_LOCAL if topic in latched
                                  else DurabilityPolicy.VOLATILE), topic
    types = dict(p.node.get_topic_names_and_types())
    assert types['/cmd_vel'] == ['geometry_msgs/msg/TwistStamped']
    assert ('/reset', ['std_srvs/srv/Trigger']) in p.node.get_service_names_and_types()
