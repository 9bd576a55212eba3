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
