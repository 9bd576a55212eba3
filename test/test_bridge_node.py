"""The bridge's safety on real rclpy with the device emulator: the watchdog, link loss (stop,
report, reconnect with backoff) and a line full of faults. Judged on what arrived (stamps,
counters); the timeouts are hang guards, never a window (the watchdog's timing:
test_bridge_safety.py)."""

from __future__ import annotations

from cr_bridge.conversions import diagnostics_from_msg
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
import pytest
from robot_util import Robot
from ros_util import Probe
from sensor_msgs.msg import JointState

pytestmark = pytest.mark.ros
ERROR = 2       # diagnostic_msgs/DiagnosticStatus.ERROR


@pytest.fixture
def probe():
    p = Probe('bridge_probe')
    p.listen(JointState, 'wheels', depth=1000)
    p.listen(DiagnosticArray, 'diagnostics', depth=1000)
    p.listen(DiagnosticArray, 'episode', latched=True, depth=100)
    p.pub = p.node.create_publisher(TwistStamped, 'cmd_vel', 10)
    yield p
    p.close()


def diag(p) -> list[tuple[int, str, dict]]:
    return [diagnostics_from_msg(m) for m in p.msgs['diagnostics']]


def forward(v: float) -> TwistStamped:
    msg = TwistStamped()
    msg.twist.angular.z = v     # turn in place: no contact, the wheels run at +-v*b/2
    return msg


def stamps(msgs) -> list[float]:
    return [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in msgs]


def test_watchdog_stops_the_wheels_after_the_last_command(probe):
    """End to end: the wheels the emulator executes stop once cmd_vel stops, and it was the
    bridge's watchdog (its trip counter), not only the device's own timeout. The watchdog's
    timing is judged against the bridge's own clock, driven by the test, in
    test_bridge_safety.py."""
    p = probe
    robot = Robot('bridge', 1.0, '-p', 'node.diagnostics_period:=0.2')
    try:
        assert p.spin_until(lambda: len(p.msgs['wheels']) > 5, 60), robot.close()
        for k in range(3):
            n = len(p.msgs['wheels'])
            for _ in range(200):                    # commands until they are executed
                p.pub.publish(forward(4.0))
                p.spin_for(0.05)
                if any(abs(m.velocity[0]) > 0.2 for m in p.msgs['wheels'][n:]):
                    break
            assert any(abs(m.velocity[0]) > 0.2 for m in p.msgs['wheels'][n:]), \
                'the command was executed'
            n = len(p.msgs['wheels'])
            assert p.spin_until(lambda n=n: any(max(map(abs, m.velocity)) == 0.0
                                                for m in p.msgs['wheels'][n:]), 60)
            assert p.spin_until(lambda k=k: int(diag(p)[-1][2]['watchdog_trips']) > k, 60), \
                diag(p)[-1]
    finally:
        out = robot.close()
    assert 'Traceback' not in out, out


def test_link_loss_stops_reports_and_reconnects_losing_only_frames_in_flight(probe):
    """Judged on what arrived, never on wall time (the waits are hang guards): the link-lost
    report and the episode's end, no reading published again while the link is down (each
    reading's stamp is new: the bridge's clock only moves with the device's frames), and after
    the reconnect every frame (stamps one dt apart, no loss counted)."""
    p = probe
    robot = Robot('bridge', 1.0, '-p', 'node.link_timeout:=0.3', '-p',
                  'node.diagnostics_period:=0.2', '-p', 'node.backoff_max:=0.4')
    try:
        assert p.spin_until(lambda: any(m == 'connected' for _, m, _ in diag(p)), 60), \
            robot.close()
        for _ in range(10):
            p.pub.publish(forward(4.0))
            p.spin_for(0.05)
        robot.stop_emulator()                       # the cable is pulled
        assert p.spin_until(lambda: any(lvl == ERROR and m.startswith('link lost')
                                        for lvl, m, _ in diag(p)), 60), diag(p)[-3:]
        # the episode event and the diagnostics travel on two topics: either may arrive first
        assert p.spin_until(lambda: p.msgs['episode'][-1].status[0].message == 'reset', 60), \
            [m.status[0].message for m in p.msgs['episode']][-3:]
        end = p.msgs['episode'][-1].status[0]
        assert {kv.key: kv.value for kv in end.values}['reason'] == 'link_lost'
        # down: the bridge retries with backoff (the diagnostics go on: >= 3 reports)
        n_diag = len(diag(p))
        assert p.spin_until(lambda: len(diag(p)) >= n_diag + 3, 60)
        assert all(m.startswith('link lost') for _, m, _ in diag(p)[n_diag:])
        robot.start_emulator()                      # plugged in again
        assert p.spin_until(lambda: diag(p)[-1][1] == 'connected', 60), diag(p)[-3:]
        # after the reconnect every frame arrives: no gap, nothing counted out of sequence
        n0 = len(p.msgs['wheels'])
        assert p.spin_until(lambda: len(p.msgs['wheels']) > n0 + 20, 60)
        values = diag(p)[-1][2]
        after = stamps(p.msgs['wheels'][n0:])
        steps = [b - a for a, b in zip(after, after[1:])]
        assert max(steps) < 0.075, 'a frame after the reconnect was lost'
        assert int(values['out_of_sequence']) == 0 and int(values['lost']) == 0, values
        assert int(values['reconnects']) == 1, values
        # nothing was published again while the link was down: every stamp is a new one
        every = stamps(p.msgs['wheels'])
        assert all(b > a for a, b in zip(every, every[1:])), 'a reading published twice'
        # the episode goes on: a new one starts after the wander
        assert p.spin_until(lambda: p.msgs['episode'][-1].status[0].message == 'start', 60)
    finally:
        out = robot.close()
    assert 'Traceback' not in out, out


def test_a_faulty_line_is_counted_and_never_crashes_the_bridge(probe):
    p = probe
    robot = Robot('bridge', 2.0, '-p', 'node.diagnostics_period:=0.2',
                  emulator_args=('--drop', '0.05', '--corrupt', '0.1', '--garbage', '0.1'))
    try:
        assert p.spin_until(lambda: len(p.msgs['wheels']) > 40, 60), robot.close()

        def counted() -> bool:
            v = diag(p)[-1][2]
            return int(v['malformed']) > 0 and int(v['skipped_bytes']) > 0 and int(v['lost']) > 0
        assert p.spin_until(counted, 60), diag(p)[-1]
        values = diag(p)[-1][2]
        assert diag(p)[-1][1] == 'connected'
        assert int(values['malformed']) > 0 and int(values['skipped_bytes']) > 0, values
        assert int(values['lost']) > 0, values
        # a corrupted frame is never published: every wheel reading is a plausible one
        assert all(max(map(abs, m.velocity)) <= 1.3 for m in p.msgs['wheels'])
    finally:
        out = robot.close()
    assert 'Traceback' not in out, out
