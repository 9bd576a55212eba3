"""The robot interface's message conversions round-trip (both directions are used by nodes)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cr_sim import conversions as conv

pytestmark = pytest.mark.ros  # needs the ROS message types (no node, no DDS)


def test_time_round_trip():
    for t in (0.0, 0.05, 12.345678901, 3600.999999999):
        assert conv.from_time(conv.to_time(t)) == pytest.approx(t, abs=1e-9)


def test_cmd_wheels_round_trip_stamped_and_plain():
    for stamped in (True, False):
        msg = conv.cmd_from_wheels([0.2, 0.5], 0.16, 1.5, 'base_link', stamped=stamped)
        assert np.allclose(conv.wheels_from_cmd(msg, 0.16), [0.2, 0.5])


def test_sensor_messages_round_trip():
    t = 7.25
    angles = np.deg2rad([-90, -60, -30, 0, 30, 60, 90])
    ir = np.linspace(0.05, 0.5, 7)
    t_ir, ir_back = conv.ir_from_msg(conv.ir_msg(ir, angles, 0.5, t, 'base_link'))
    assert t_ir == pytest.approx(t) and np.allclose(ir_back, ir)
    names = ['destination', 'L1', 'L2', 'L3', 'L4']
    t_b, blobs = conv.bearings_from_msg(
        conv.bearings_msg(names, [0.1, math.nan, -3.0, 2.0, 0.0], t, 'base_link'))
    assert t_b == pytest.approx(t) and math.isnan(blobs['L1']) and blobs['L2'] == -3.0
    t_w, wheels = conv.wheels_from_msg(conv.wheels_msg([0.3, -0.1], t, 'base_link'))
    assert t_w == pytest.approx(t) and np.allclose(wheels, [0.3, -0.1])
    assert conv.reward_from_msg(conv.reward_msg(-0.1, 0.9, 4, t)) == (
        pytest.approx(t), pytest.approx(-0.1), 4)
    t_e, event, values = conv.episode_from_msg(conv.episode_msg('reached', t, episode=3))
    assert (t_e, event, values) == (pytest.approx(t), 'reached', {'episode': '3'})


def test_to_time_rounds_to_the_nearest_nanosecond():
    # a stamp a hair below a whole second must not wrap back to the start of that second
    from cr_sim.conversions import from_time, to_time
    for t in (180.99999999997, 181.0, 0.05 * 3620, 59.9999999999, 1e-10, 12.3456789):
        stamp = to_time(t)
        assert 0 <= stamp.nanosec < 1_000_000_000
        assert abs(from_time(stamp) - t) < 1e-9
    assert (to_time(180.99999999997).sec, to_time(180.99999999997).nanosec) == (181, 0)


# ---------------------------------------------------------------- against hand-computed messages
# A round trip passes a mirrored bug (left/right swapped on both sides); these fix each side.

def test_cmd_from_wheels_is_the_hand_computed_twist():
    # wheels (0.2, 0.5) m/s, wheel base 0.16 m: v = (0.2 + 0.5) / 2, omega = (0.5 - 0.2) / 0.16
    msg = conv.cmd_from_wheels([0.2, 0.5], 0.16, 1.5, 'base_link')
    assert msg.twist.linear.x == pytest.approx(0.35)
    assert msg.twist.angular.z == pytest.approx(1.875)          # counter-clockwise: left turn
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    assert msg.header.frame_id == 'base_link'
    plain = conv.cmd_from_wheels([0.2, 0.5], 0.16, 1.5, 'base_link', stamped=False)
    assert (plain.linear.x, plain.angular.z) == (pytest.approx(0.35), pytest.approx(1.875))


def test_wheels_from_cmd_is_the_hand_computed_pair():
    from geometry_msgs.msg import Twist, TwistStamped
    twist = Twist()
    twist.linear.x, twist.angular.z = 0.35, 1.875     # a left turn: the right wheel is faster
    assert np.allclose(conv.wheels_from_cmd(twist, 0.16), [0.2, 0.5])
    assert np.allclose(conv.wheels_from_cmd(TwistStamped(twist=twist), 0.16), [0.2, 0.5])


def test_wheels_and_odom_messages_are_the_hand_computed_ones():
    msg = conv.wheels_msg([0.3, -0.1], 2.25, 'base_link')
    assert list(msg.name) == ['left_wheel', 'right_wheel']
    assert list(msg.velocity) == [0.3, -0.1]
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (2, 250_000_000)
    # pose (1, 2, pi/2), wheels (0.3, -0.1), base 0.16: v = 0.1, omega = -0.4 / 0.16 = -2.5
    odom = conv.odom_msg(np.array([1.0, 2.0, math.pi / 2]), np.array([0.3, -0.1]), 0.16, 2.25,
                         'odom', 'base_link')
    assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_link')
    assert (odom.pose.pose.position.x, odom.pose.pose.position.y) == (1.0, 2.0)
    assert odom.pose.pose.orientation.z == pytest.approx(math.sqrt(0.5))
    assert odom.pose.pose.orientation.w == pytest.approx(math.sqrt(0.5))
    assert odom.twist.twist.linear.x == pytest.approx(0.1)
    assert odom.twist.twist.angular.z == pytest.approx(-2.5)


def test_sensor_and_reward_messages_are_the_hand_computed_ones():
    angles = np.deg2rad([-90, -60, -30, 0, 30, 60, 90])
    scan = conv.ir_msg(np.linspace(0.05, 0.5, 7), angles, 0.5, 7.25, 'base_link')
    assert scan.angle_min == pytest.approx(-math.pi / 2)
    assert scan.angle_max == pytest.approx(math.pi / 2)
    assert scan.angle_increment == pytest.approx(math.pi / 6)
    assert (scan.range_min, scan.range_max) == (0.0, 0.5)
    assert list(scan.ranges) == pytest.approx([0.05, 0.125, 0.2, 0.275, 0.35, 0.425, 0.5])
    cam = conv.bearings_msg(['destination', 'L1'], [0.1, math.nan], 7.25, 'base_link')
    assert list(cam.name) == ['destination', 'L1'] and cam.position[0] == 0.1
    assert math.isnan(cam.position[1]) and cam.header.frame_id == 'base_link'
    r = conv.reward_msg(-0.1, 0.9, 4, 7.25)
    assert (r.vector.x, r.vector.y, r.vector.z) == (-0.1, 0.9, 4.0)
    ev = conv.episode_msg('reached', 7.25, episode=3)
    assert ev.status[0].message == 'reached'
    assert [(kv.key, kv.value) for kv in ev.status[0].values] == [('episode', '3')]
    assert (ev.header.stamp.sec, ev.header.stamp.nanosec) == (7, 250_000_000)


def test_wheels_cmd_carries_the_wheels_exactly_and_a_bad_one_is_refused():
    """``wheels_cmd`` gives back the decided wheels to the bit; ``cmd_vel``'s (v, w) only to
    rounding (the pair below is one an arbiter sent under ``clis run``)."""
    u = [-0.008943322709441679, 0.041668905125463056]
    msg = conv.wheels_cmd_msg(u, 1.5, 'base_link')
    assert list(msg.name) == ['left_wheel', 'right_wheel'] and msg.header.frame_id == 'base_link'
    assert conv.cmd_stamp(msg) == 1.5
    assert conv.wheels_from_cmd(msg, 0.16).tolist() == u
    twist = conv.cmd_from_wheels(u, 0.16, 1.5, 'base_link')
    assert conv.wheels_from_cmd(twist, 0.16).tolist() != u       # why wheels_cmd exists
    msg.velocity = [0.1]
    with pytest.raises(ValueError, match='2 velocities'):
        conv.wheels_from_cmd(msg, 0.16)


def test_ir_ranges_carry_the_float64_beams_that_the_scan_rounds():
    ir = np.array([0.1 + 1e-12, 0.5, 0.3333333333333333, 0.2, 0.25, 0.45, 0.05])
    msg = conv.ir_ranges_msg(ir, 2.0, 'base_link')
    assert list(msg.name) == [f'ir_{k}' for k in range(7)]
    t, ranges = conv.ir_ranges_from_msg(msg)
    assert t == 2.0 and ranges.tolist() == ir.tolist()
    _, scan = conv.ir_from_msg(conv.ir_msg(ir, np.linspace(-1.5, 1.5, 7), 0.5, 2.0, 'base_link'))
    assert scan.tolist() != ir.tolist()                          # float32 on the wire
    assert np.array_equal(scan, ir.astype(np.float32))


def test_status_messages_are_the_hand_computed_ones():
    from cr_bridge.conversions import diagnostics_from_msg, diagnostics_msg
    from diagnostic_msgs.msg import DiagnosticStatus
    m = diagnostics_msg('warn', 'link lost', {'reconnects': 2}, 1.5, 'udp://127.0.0.1:1')
    s = m.status[0]
    assert (s.level, s.name, s.message, s.hardware_id) == (
        DiagnosticStatus.WARN, 'cr_bridge: link', 'link lost', 'udp://127.0.0.1:1')
    assert [(kv.key, kv.value) for kv in s.values] == [('reconnects', '2')]
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1, 500_000_000)
    assert diagnostics_from_msg(m) == (1, 'link lost', {'reconnects': '2'})
    e = conv.event_msg('episode', 'start', 2.25, episode=3).status[0]
    assert (e.level, e.name, e.message, e.hardware_id) == (
        DiagnosticStatus.OK, 'episode', 'start', 'cr')
    assert [(kv.key, kv.value) for kv in e.values] == [('episode', '3')]
