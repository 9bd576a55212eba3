"""The simulator node with real rclpy and Fast DDS: topics, rates, /clock, cmd_vel, safety."""

from __future__ import annotations

import math

from cr_sim.core.arena import load_arena
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped, Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from ros_util import Probe, assert_rate, start_node, stop
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, LaserScan
from visualization_msgs.msg import MarkerArray

from cr_sim import conversions as conv

pytestmark = pytest.mark.ros

SPEED = 10.0  # sim seconds per wall second in these tests
TICK = 0.05   # config/sim.yaml episode.dt
TOPICS = {'ir': LaserScan, 'camera': JointState, 'wheels': JointState, 'reward': Vector3Stamped,
          'odom': Odometry, 'markers': MarkerArray}
# declared rates (Hz of sim time), as in the topic table of docs/robot.md
RATES = {'/clock': 1 / TICK, 'ir': 1 / TICK, 'camera': 1 / TICK, 'wheels': 1 / TICK,
         'reward': 1 / TICK, 'odom': 1 / TICK, 'markers': 10.0}


def stamp(msg) -> float:
    return conv.from_time(msg.clock if isinstance(msg, Clock) else msg.header.stamp)


@pytest.fixture
def probe():
    p = Probe()
    yield p
    p.close()


def pose_of(odom: Odometry) -> np.ndarray:
    q = odom.pose.pose.orientation
    return np.array([odom.pose.pose.position.x, odom.pose.pose.position.y,
                     2 * math.atan2(q.z, q.w)])


def test_sim_node_publishes_interface_at_declared_rates_and_obeys_cmd_vel(probe):
    proc = start_node('cr_sim.sim_node', '-p', f'node.speed_factor:={SPEED}',
                      '-p', 'node.start:=A', '-p', 'node.auto_reset:=false',
                      # the sim's clock runs from its start, before the probe has discovered it:
                      # a 60 s episode (6 s wall at x10) could time out during the drives below,
                      # and then the sim (auto_reset off) holds and publishes no odom
                      '-p', 'episode.time_limit:=600.0')
    try:
        probe.listen(Clock, '/clock', depth=1000)
        probe.listen(MarkerArray, 'arena', latched=True)
        probe.listen(DiagnosticArray, 'episode', latched=True)
        for topic, msg_type in TOPICS.items():
            probe.listen(msg_type, topic, depth=1000)
        assert probe.spin_until(lambda: len(probe.msgs['/clock']) > 5, 30), stop(proc)
        for topic in RATES:
            probe.msgs[topic].clear()
        probe.spin_for(2.0)
        clock = [stamp(m) for m in probe.msgs['/clock']]
        assert len(clock) > 50
        assert all(b > a for a, b in zip(clock, clock[1:])), 'clock must increase'
        span = clock[-1] - clock[0]
        assert span > 0.5 * SPEED * 2.0, f'sim ran {span:.1f} s in 2 s wall at x{SPEED}'
        for topic, rate in RATES.items():
            stamps = [stamp(m.markers[0]) if topic == 'markers' else stamp(m)
                      for m in probe.msgs[topic]]
            assert_rate(stamps, rate, topic)
        scan = probe.msgs['ir'][-1]
        assert len(scan.ranges) == 7 and 0 <= min(scan.ranges) <= scan.range_max
        cam = probe.msgs['camera'][-1]
        assert cam.name[0] == 'destination' and len(cam.name) == 5
        assert not math.isnan(cam.position[0]), 'destination is visible from start A'
        assert probe.spin_until(lambda: probe.msgs['arena'], 5), 'arena markers are latched'
        assert probe.msgs['episode'] and probe.msgs['episode'][0].status[0].message == 'start'

        # a forward command moves the robot; a NaN command never does
        pub = probe.node.create_publisher(TwistStamped, 'cmd_vel', 10)
        # a message published before DDS has matched the sim's subscription is lost: wait
        assert probe.spin_until(lambda: pub.get_subscription_count() > 0, 10), stop(proc)

        def drive(v: float, seconds: float) -> np.ndarray:
            msg = TwistStamped()
            msg.twist.linear.x = v
            n0 = len(probe.msgs['odom'])
            for _ in range(int(seconds / 0.05)):
                pub.publish(msg)
                probe.spin_for(0.05)
            fresh = probe.msgs['odom'][n0:]
            assert len(fresh) > 10 * seconds, 'the sim must keep publishing while driven'
            return pose_of(fresh[-1])

        p0 = pose_of(probe.msgs['odom'][-1])
        n = len(probe.msgs['odom'])
        # 5 cm/s toward the goal until 0.3 m (6 s of sim time, 0.6 s of wall at x10; a loaded
        # host runs the sim slower than x10: 10 s of wall is only a bound)
        moved = 0.0
        for _ in range(10):
            moved = np.hypot(*(drive(0.05, 1.0)[:2] - p0[:2]))
            if moved > 0.3:
                break
        assert moved > 0.3, f'moved {moved:.2f} m'
        speeds = [m.twist.twist.linear.x for m in probe.msgs['odom'][n:]]
        assert max(speeds) == pytest.approx(0.05, rel=0.05), 'driven at the commanded speed'
        drive(0.0, 0.5)
        p2 = pose_of(probe.msgs['odom'][-1])
        p3 = drive(float('nan'), 1.0)
        assert np.allclose(p2, p3, atol=1e-9), 'a NaN command must not move the robot'
        n = len(probe.msgs['odom'])
        drive(50.0, 0.3)  # far over the 1.3 m/s wheel limit
        speeds = [abs(m.twist.twist.linear.x) for m in probe.msgs['odom'][n:]]
        assert speeds and max(speeds) <= 1.3 + 1e-9, f'body speed {max(speeds)} over the limit'
        # watchdog: commands stop -> the robot stops
        probe.spin_for(1.0)
        p5 = pose_of(probe.msgs['odom'][-1])
        probe.spin_for(0.5)
        assert np.allclose(p5[:2], pose_of(probe.msgs['odom'][-1])[:2], atol=1e-9)
    finally:
        out = stop(proc)
    assert 'Traceback' not in out, out


def test_sim_node_takes_plain_twist_by_parameter_and_resets_on_request(probe):
    from std_srvs.srv import Trigger

    proc = start_node('cr_sim.sim_node', '-p', f'node.speed_factor:={SPEED}',
                      '-p', 'node.cmd_vel_stamped:=false', '-p', 'node.start:=A',
                      # as above: no episode end (and auto reset to A) in the middle of the turn
                      '-p', 'episode.time_limit:=600.0')
    try:
        probe.listen(Odometry, 'odom')
        probe.listen(DiagnosticArray, 'episode', latched=True)
        assert probe.spin_until(lambda: probe.msgs['odom'], 30), stop(proc)
        pub = probe.node.create_publisher(Twist, 'cmd_vel', 10)
        # a message published before DDS has matched the sim's subscription is lost: wait
        assert probe.spin_until(lambda: pub.get_subscription_count() > 0, 10), stop(proc)
        p0 = pose_of(probe.msgs['odom'][-1])
        msg = Twist()
        msg.angular.z = 2.0

        def turned() -> float:
            pub.publish(msg)
            p1 = pose_of(probe.msgs['odom'][-1])
            return abs(math.remainder(p1[2] - p0[2], 2 * math.pi))
        # at x10 the turn takes a fraction of a second; 10 s of wall time is only a bound
        assert probe.spin_until(lambda: turned() > 0.3, 10), f'Twist turned {turned():.3f} rad'
        # stop turning (the command in force would turn the robot right after the reset)
        msg.angular.z = 0.0
        for _ in range(5):
            pub.publish(msg)
            probe.spin_for(0.05)
        # the reset service ends the episode and starts the next one at start A again
        client = probe.node.create_client(Trigger, 'reset')
        assert client.wait_for_service(timeout_sec=10)
        future = client.call_async(Trigger.Request())
        assert probe.spin_until(future.done, 10) and future.result().success
        # the events arrive on their own topic: wait for them (no order across topics)
        def events() -> list[str]:
            return [m.status[0].message for m in probe.msgs['episode']]
        assert probe.spin_until(lambda: events()[-2:] == ['reset', 'start'], 10), events()
        n = len(probe.msgs['odom'])
        assert probe.spin_until(lambda: len(probe.msgs['odom']) > n + 2, 10)
        a = load_arena().start('A')
        assert np.allclose(pose_of(probe.msgs['odom'][-1]), [a.x, a.y, a.heading], atol=1e-6)
    finally:
        stop(proc)


def test_sim_node_rejects_bad_parameter_naming_the_key():
    proc = start_node('cr_sim.sim_node', '-p', 'node.speed_factor:=-3.0')
    proc.wait(60)
    out = stop(proc)
    assert proc.returncode == 2, out
    assert 'node.speed_factor' in out and '[0.0, 1000.0]' in out
