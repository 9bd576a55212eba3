"""The simulator's speed cap holds in lockstep (`clis run --speed X`)."""

from __future__ import annotations

from geometry_msgs.msg import TwistStamped
import numpy as np
import pytest
from ros_util import Probe, start_node, stop
from rosgraph_msgs.msg import Clock

from cr_sim import conversions as conv

pytestmark = pytest.mark.ros


def test_lockstep_clock_is_capped_at_the_speed_factor():
    """A controller that answers every instant at once: the clock still runs at most x2.

    Judged by the simulator's own publication stamps of /clock (DDS source timestamps), not
    by when they reach this probe: a stall of the test process changes nothing, and a loaded
    host can only slow the simulator down. Its pacer may catch up a lag of up to 1 s in a
    burst (sim_node.run), so over any stretch of the run sim time may lead speed x wall time
    by at most speed x (1 s + one tick's period) (20 ms more for the wall clock of the stamps,
    not the pacer's monotonic one)."""
    speed, catch_up = 2.0, 1.0
    p = Probe('pacing')
    pub = p.node.create_publisher(TwistStamped, 'cmd_vel', 10)
    clock: list[tuple[float, float]] = []          # (publication stamp [s], sim time [s])

    def on_clock(msg: Clock, info) -> None:
        t = conv.from_time(msg.clock)
        clock.append((info['source_timestamp'] * 1e-9, t))
        pub.publish(conv.cmd_from_wheels((0.0, 0.0), 0.16, t, 'base_link'))

    p.node.create_subscription(Clock, '/clock', on_clock, 1000)
    proc = start_node('cr_sim.sim_node', '-p', f'node.speed_factor:={speed}', '-p',
                      'node.lockstep:=true', '-p', 'node.command_timeout:=5.0')
    try:
        assert p.spin_until(lambda: len(clock) >= 200, 120), stop(proc)   # a hang guard
    finally:
        out = stop(proc)
        p.close()
    assert 'Traceback' not in out, out
    wall, sim = np.array(clock[:200]).T
    dt = float(np.min(np.diff(sim)[np.diff(sim) > 0]))
    assert sim[-1] - sim[0] >= 150 * dt, 'the clock did not advance'
    # the largest lead of sim time over speed x wall time over any stretch [i, j]
    d = sim - speed * wall
    lead = float(np.max(d - np.minimum.accumulate(d)))
    assert lead <= speed * catch_up + dt + 0.02, (
        f'sim time ran {lead:.2f} s ahead of x{speed} wall time over a stretch of the run')
