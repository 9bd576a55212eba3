"""``ros2 run cr_bridge robot`` on real rclpy: a fake robot in the test process (its /clock,
odom, scan and cmd_vel subscriber) and a fake blob detector (``camera``) drive the node, run in
the namespace /clis with the Husky's profile. Judged on what arrived: the cmd_vel type that
matched the robot's subscriber, the commands' values and stamps (the robot's sim time), the
interface's topics and the episode events; the timeouts are hang guards."""

from __future__ import annotations

import math
import time

from builtin_interfaces.msg import Time
from cr_bridge.conversions import blobs_from_msg, odom_from_msg, scan_from_msg
from cr_sim.core.profile import load_profile
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped, Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from ros_util import start_node, stop
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, LaserScan

from cr_sim import conversions as conv

pytestmark = pytest.mark.ros

PROFILE = load_profile('husky')
STALE = PROFILE.episode.stale_timeout        # 0.5 s
WHEEL_BASE = PROFILE.body.wheel_base         # 0.555 m
PERIOD = 0.05                                # config/bridge.yaml robot: node.period
DT = 0.01                                    # the fake robot's clock step [s]
NS = '/clis'
WHEELS = (0.2, 0.4)                          # the test's wheels_cmd: v 0.3, omega 0.36
V, OMEGA = 0.3, 0.2 / WHEEL_BASE


def node_args(*extra: str, exit_timeout: float = 0.0) -> tuple[str, ...]:
    """The node in /clis on the fake robot's clock with the Husky's profile, its first
    episode at once; not waiting for the exit's acknowledgement unless it is judged."""
    return ('-r', f'__ns:={NS}', '-p', 'use_sim_time:=true', '-p', 'node.profile:=husky',
            '-p', 'node.start:=here', '-p', f'node.exit_timeout:={exit_timeout}', *extra)


def exit_args() -> tuple[str, ...]:
    """The exit as configured (config/bridge.yaml: wait for the acknowledgement)."""
    from clis_base.params import config_dir, ros_parameters
    timeout = ros_parameters(config_dir() / 'bridge.yaml', 'robot')['node']['exit_timeout']
    return node_args(exit_timeout=timeout)


class FakeRobot:
    """The robot and the blob detector: /clock, odom, scan (a free 360-degree lidar) and
    camera (nothing seen) at every step of DT, cmd_vel subscribed (``cmd_type``, on demand),
    wheels_cmd published like the arbiter; and a probe of the interface's topics."""

    def __init__(self, prefix: str = '') -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('fake_robot', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.prefix = prefix
        n = self.node
        self.pub_clock = n.create_publisher(Clock, '/clock', 10)
        self.pub_odom = n.create_publisher(Odometry, f'{prefix}/odom', qos_profile_sensor_data)
        self.pub_scan = n.create_publisher(LaserScan, f'{prefix}/scan', qos_profile_sensor_data)
        self.pub_camera = n.create_publisher(JointState, f'{NS}/camera', 10)
        self.pub_wheels = n.create_publisher(JointState, f'{NS}/wheels_cmd', 10)
        self.cmds: list = []
        self.msgs: dict[str, list] = {}
        self.t = 0.0
        self.last_scan = -math.inf

    def subscribe_cmd_vel(self, cmd_type) -> None:
        self.node.create_subscription(cmd_type, f'{self.prefix}/cmd_vel', self.cmds.append,
                                      QoSProfile(depth=1000))

    def listen(self, msg_type, topic: str, latched: bool = False) -> None:
        self.msgs[topic] = []
        qos = QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                         else DurabilityPolicy.VOLATILE)
        self.node.create_subscription(msg_type, topic, self.msgs[topic].append, qos)

    def step(self, scan: bool = True, wheels: tuple[float, float] | None = WHEELS) -> None:
        self.t = round(self.t + DT, 9)
        stamp = conv.to_time(self.t)
        self.pub_clock.publish(Clock(clock=stamp))
        odom = Odometry()
        odom.header.stamp = stamp
        odom.pose.pose.orientation.w = 1.0
        self.pub_odom.publish(odom)
        if scan:
            msg = LaserScan(angle_min=-math.pi, angle_max=math.pi,
                            angle_increment=2 * math.pi / 360, range_min=0.1, range_max=12.0,
                            ranges=[5.0] * 360)
            msg.header.stamp = stamp
            self.pub_scan.publish(msg)
            self.last_scan = self.t
        cam = JointState(name=['destination', 'L1', 'L2', 'L3', 'L4'], position=[math.nan] * 5,
                         effort=[math.nan] * 5)
        cam.header.stamp = stamp
        self.pub_camera.publish(cam)
        if wheels is not None:
            self.pub_wheels.publish(conv.wheels_cmd_msg(wheels, self.t, 'base_link'))
        self.executor.spin_once(timeout_sec=DT)

    def run_until(self, done, timeout: float = 30.0, **step) -> bool:
        """Steps (about one DT of sim time per DT of wall time) until ``done()``; False after
        ``timeout`` steps' worth of sim time."""
        for _ in range(int(timeout / DT)):
            self.step(**step)
            if done():
                return True
        return False

    def frame(self, t: float, camera: bool = True) -> None:
        """Clock, odom, scan (and camera) of frame ``t``, no wheels_cmd (a robot in
        lockstep)."""
        self.t = round(t - DT, 9)
        real = self.pub_camera
        if not camera:                                # the camera's message goes nowhere
            self.pub_camera = self.node.create_publisher(JointState, f'{NS}/elsewhere', 1)
        self.step(wheels=None)
        self.pub_camera = real

    def arrived(self, msgs: list, t: float, wait: float) -> list:
        """The messages stamped ``t`` that arrive within ``wait`` wall seconds."""
        end = time.monotonic() + wait
        while True:
            got = [m for m in msgs if abs(conv.from_time(m.header.stamp) - t) < 1e-6]
            if got or time.monotonic() > end:
                return got
            self.executor.spin_once(timeout_sec=0.01)

    def drain(self, seconds: float = 0.5) -> None:
        """Take every message that arrives within ``seconds`` of wall time (a spin takes one
        message: after a wait, hundreds may be queued)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def twist(msg) -> Twist:
    return msg.twist if isinstance(msg, TwistStamped) else msg


def moving(msg) -> bool:
    return twist(msg).linear.x == pytest.approx(V) and twist(msg).angular.z == pytest.approx(OMEGA)


def zero(msg) -> bool:
    return twist(msg).linear.x == 0.0 and twist(msg).angular.z == 0.0


def finite(msg) -> bool:
    t = twist(msg)
    return all(math.isfinite(x) for x in (t.linear.x, t.linear.y, t.linear.z, t.angular.x,
                                          t.angular.y, t.angular.z))


@pytest.fixture
def fake():
    robots: list[FakeRobot] = []

    def make(prefix: str = '') -> FakeRobot:
        robots.append(FakeRobot(prefix))
        return robots[-1]
    yield make
    for r in robots:
        r.close()


@pytest.mark.parametrize('cmd_type', [Twist, TwistStamped])
def test_cmd_vel_takes_the_type_of_the_robots_subscriber(fake, cmd_type):
    """With 'auto' and no subscriber on /cmd_vel the node says it waits; once the robot
    subscribes with either type, the test's wheels_cmd reach it as that type, with the twist
    of those wheels on the profile's wheel base."""
    robot = fake()
    robot.listen(LaserScan, f'{NS}/ir')
    proc = start_node('cr_bridge.robot_node', *node_args('-p', 'node.cmd_vel_type:=auto'))
    try:
        # the node runs (its readings arrive) and has looked at the graph: no subscriber
        assert robot.run_until(lambda: robot.msgs[f'{NS}/ir'])
        robot.subscribe_cmd_vel(cmd_type)
        assert robot.run_until(lambda: any(moving(m) for m in robot.cmds)), \
            [twist(m) for m in robot.cmds[-3:]]
        assert all(isinstance(m, cmd_type) for m in robot.cmds)
    finally:
        out = stop(proc)
    assert 'Traceback' not in out, out
    assert ('waiting for a subscriber on /cmd_vel to learn its type (Twist or TwistStamped); '
            'set cmd_vel_type to skip') in out, out
    assert f'cmd_vel /cmd_vel: {cmd_type.__name__}' in out, out


def test_a_namespaced_node_with_remapped_robot_topics(fake):
    """The node in /clis, the robot under /husky (-r /odom:=/husky/odom, ...): the interface's
    topics are under /clis (not /clock, not camera: the robot's and the detector's), the
    commands reach /husky/cmd_vel, and at SIGTERM its zero command."""
    robot = fake('/husky')
    robot.subscribe_cmd_vel(TwistStamped)                 # the profile's type
    for topic, msg_type in (('ir', LaserScan), ('ir_ranges', JointState), ('wheels', JointState),
                            ('odom', Odometry), ('reward', Vector3Stamped)):
        robot.listen(msg_type, f'{NS}/{topic}')
    robot.listen(DiagnosticArray, f'{NS}/episode', latched=True)
    proc = start_node('cr_bridge.robot_node', *exit_args(),
                      '-r', '/odom:=/husky/odom', '-r', '/scan:=/husky/scan',
                      '-r', '/cmd_vel:=/husky/cmd_vel')
    try:
        assert robot.run_until(lambda: any(moving(m) for m in robot.cmds)), robot.cmds[-3:]
        assert robot.run_until(lambda: all(len(v) > 3 for k, v in robot.msgs.items()
                                           if not k.endswith('episode'))
                               and robot.msgs[f'{NS}/episode'], timeout=15.0), \
            {k: len(v) for k, v in robot.msgs.items()}
        n = robot.node
        graph: dict = {}

        def publishers() -> bool:
            # an endpoint can be discovered before its node's name (_NODE_NAME_UNKNOWN_)
            graph.update({name: [i.node_name for i in n.get_publishers_info_by_topic(name)]
                          for name in ('/clock', f'{NS}/camera', '/cmd_vel', f'{NS}/ir')})
            return not any(u.startswith('_NODE_NAME_UNKNOWN') for v in graph.values() for u in v)
        robot.run_until(publishers, timeout=10.0)
        robot.run_until(lambda: False, timeout=0.2)
        assert moving(robot.cmds[-1])
        proc.send_signal(15)
        proc.wait(10)
    finally:
        out = stop(proc)
    assert 'Traceback' not in out and proc.returncode == 0, out
    robot.drain(0.3)
    assert zero(robot.cmds[-1]), 'SIGTERM: the last command is zero'
    assert graph == {'/clock': ['fake_robot'], f'{NS}/camera': ['fake_robot'], '/cmd_vel': [],
                     f'{NS}/ir': ['robot']}, graph
    ir = robot.msgs[f'{NS}/ir'][-1]
    assert list(ir.ranges) == pytest.approx([PROFILE.scan.range_max] * 7), \
        'the free lidar read as the 7 sectors'
    wheels = robot.msgs[f'{NS}/wheels'][-1]
    assert list(wheels.velocity) == [0.0, 0.0], "odom's twist"
    start = conv.episode_from_msg(robot.msgs[f'{NS}/episode'][0])
    assert start[1] == 'start' and start[2]['start'] == 'here'
    assert all(conv.reward_from_msg(m)[1] == 0.0 for m in robot.msgs[f'{NS}/reward'])


def test_a_stale_scan_stops_the_robot_within_the_profiles_timeout_in_sim_time(fake):
    """The scan stops while /clock goes on: a zero command stamped within stale_timeout (and
    a period) of the last scan, nothing but zero after it, the episode ended as on a link
    loss; fresh scans again: the node drives again (the wander to the next start)."""
    robot = fake()
    robot.subscribe_cmd_vel(TwistStamped)
    robot.listen(DiagnosticArray, f'{NS}/episode', latched=True)
    proc = start_node('cr_bridge.robot_node', *node_args())
    try:
        assert robot.run_until(lambda: any(moving(m) for m in robot.cmds)), robot.cmds[-3:]
        robot.run_until(lambda: False, timeout=0.2)
        last_scan, n = robot.last_scan, len(robot.cmds)
        assert robot.run_until(lambda: any(zero(m) for m in robot.cmds[n:]), timeout=5.0,
                               scan=False), [twist(m) for m in robot.cmds[-3:]]
        robot.run_until(lambda: False, timeout=0.5, scan=False)
        after = robot.cmds[n:]
        k = next(i for i, m in enumerate(after) if zero(m))
        t_zero = conv.from_time(after[k].header.stamp)
        assert t_zero - last_scan >= STALE - 2 * DT, (t_zero, last_scan)
        # judged by the stamps (a loaded host runs the node's period late, not its clock):
        # no command moves the robot at or past the timeout and its period
        late = [conv.from_time(m.header.stamp) for m in after if not zero(m)
                and conv.from_time(m.header.stamp) - last_scan > STALE + PERIOD + DT]
        assert late == [], (late, last_scan)
        assert all(zero(m) for m in after[k:]), 'nothing but zero while the scan is stale'
        ends = [conv.episode_from_msg(m) for m in robot.msgs[f'{NS}/episode']]
        assert ends[-1][1] == 'reset' and ends[-1][2]['reason'] == 'link_lost' \
            and ends[-1][2]['stale'] == 'scan', ends
        m = len(robot.cmds)
        assert robot.run_until(lambda: any(not zero(c) for c in robot.cmds[m:]), timeout=5.0)
    finally:
        out = stop(proc)
    assert 'Traceback' not in out, out
    assert 'scan older than 0.5 s' in out, out


def test_a_nan_wheels_cmd_never_reaches_cmd_vel(fake):
    robot = fake()
    robot.subscribe_cmd_vel(TwistStamped)
    proc = start_node('cr_bridge.robot_node', *node_args())
    try:
        assert robot.run_until(lambda: any(moving(m) for m in robot.cmds)), robot.cmds[-3:]
        for bad in ((math.nan, 0.3), (0.1, math.inf)):
            n = len(robot.cmds)
            assert robot.run_until(lambda n=n: any(zero(m) for m in robot.cmds[n:]),
                                   timeout=5.0, wheels=bad)
            robot.run_until(lambda: False, timeout=0.3, wheels=bad)
            assert all(zero(m) for m in robot.cmds[-5:])
            assert robot.run_until(lambda: moving(robot.cmds[-1]), timeout=5.0)
    finally:
        out = stop(proc)
    assert 'Traceback' not in out, out
    assert all(finite(m) for m in robot.cmds), 'a NaN reached cmd_vel'
    assert 'rejected a non-finite wheels_cmd' in out, out


def test_ctrl_c_leaves_the_robot_commanded_to_zero(fake):
    """The robot moving on the last command when SIGINT comes: the last cmd_vel it receives
    is zero, acknowledged before the node exits (SIGTERM: the remapped run above)."""
    robot = fake()
    robot.subscribe_cmd_vel(TwistStamped)
    proc = start_node('cr_bridge.robot_node', *exit_args())
    try:
        assert robot.run_until(lambda: any(moving(m) for m in robot.cmds)), robot.cmds[-3:]
        robot.run_until(lambda: False, timeout=0.2)
        assert moving(robot.cmds[-1])
        proc.send_signal(2)
        proc.wait(10)
    finally:
        out = stop(proc)
    assert proc.returncode == 0 and 'Traceback' not in out, out
    assert 'not acknowledged' not in out, out
    robot.drain(0.3)
    assert zero(robot.cmds[-1]) and moving(robot.cmds[-2]), [twist(m) for m in robot.cmds[-3:]]


def test_lockstep_answers_each_frame_once_and_a_decision_frame_with_its_decision(fake):
    """node.lockstep with decision periods of 0.25 s: the fake robot publishes one frame of
    its sensors at a time (every PERIOD) and steps on only once a cmd_vel stamped with it
    arrives, as our simulator's and the Husky world's lockstep do. A frame is read (its ``ir``
    published) only once its camera is in too; the frames between the decision instants are
    answered at once (the command in force), those at t0 + l 0.25 s of the running episode
    only by the arbiter's decision on them; every answer is stamped with its frame."""
    robot = fake()
    robot.subscribe_cmd_vel(TwistStamped)
    robot.listen(LaserScan, f'{NS}/ir')
    proc = start_node('cr_bridge.robot_node', *node_args(
        '-p', 'node.lockstep:=true', '-p', 'node.decision_periods:=[0.25]'))

    frame, arrived = robot.frame, robot.arrived
    try:
        # the first frame, sent again until the node has read it; the episode starts there
        # ('here'): a decision instant, answered by the decision alone
        t0, ir = PERIOD, robot.msgs[f'{NS}/ir']
        for _ in range(300):
            frame(t0)
            if arrived(ir, t0, 0.1):
                break
        assert arrived(ir, t0, 0.0), 'the first frame was never read'
        assert arrived(robot.cmds, t0, 0.5) == [], 'a decision frame waits for its decision'
        robot.pub_wheels.publish(conv.wheels_cmd_msg(WHEELS, t0, 'base_link'))
        got = arrived(robot.cmds, t0, 10.0)
        assert len(got) == 1 and moving(got[0]), got
        for k in range(1, 11):
            t = round(t0 + k * PERIOD, 9)
            if k == 3:                                # no camera yet: not read, not answered
                frame(t, camera=False)
                assert arrived(ir, t, 0.5) == [] and arrived(robot.cmds, t, 0.0) == []
            frame(t)
            if k % 5:                                 # between the instants: at once
                got = arrived(robot.cmds, t, 10.0)
                assert len(got) == 1 and moving(got[0]), (k, got)
            else:                                     # t0 + 0.25 s, t0 + 0.5 s: the decision
                assert arrived(robot.cmds, t, 0.5) == [], k
                robot.pub_wheels.publish(conv.wheels_cmd_msg(WHEELS, t, 'base_link'))
                assert len(arrived(robot.cmds, t, 10.0)) == 1, k
    finally:
        out = stop(proc)
    assert 'Traceback' not in out and 'lockstep' in out, out
    stamps = [conv.from_time(m.header.stamp) for m in robot.cmds]
    assert stamps == sorted(stamps) and len(stamps) == len(set(stamps)), stamps


@pytest.mark.parametrize('gate', ['learner', 'graph'])
def test_lockstep_holds_a_starting_frame_until_its_gate_opens(fake, gate):
    """In lockstep the frame at which an episode is due is neither read nor answered before
    its gate opens: with node.wait_for_learner, the learner's report of the last episode (the
    robot waits there, as on any host, instead of wandering on while the learner learns);
    with node.start_subscribers (clis run sets them), for the first episode, the interface's
    subscribers (a reading sent before is lost to a node that matches later). Then that frame
    starts the episode, is read once, and its decision answers it."""
    robot = fake()
    robot.subscribe_cmd_vel(TwistStamped)
    robot.listen(LaserScan, f'{NS}/ir')
    progress = robot.node.create_publisher(
        DiagnosticArray, f'{NS}/learner/progress',
        QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    proc = start_node('cr_bridge.robot_node', *node_args(
        '-p', 'node.lockstep:=true', '-p', 'node.decision_periods:=[0.25]', '-p',
        'node.wait_for_learner:=true' if gate == 'learner'
        else "node.start_subscribers:=['reward:1']"))
    t0, ir = PERIOD, robot.msgs[f'{NS}/ir']
    try:
        # the frame, sent again and again as a held robot does, for long after the node is up
        for _ in range(40):
            robot.frame(t0)
            robot.drain(0.1)
        assert ir == [], f'read before the {gate} gate opened'
        assert robot.cmds == [], f'answered before the {gate} gate opened'
        if gate == 'learner':
            progress.publish(conv.episode_msg('progress', 0.0, episode=0, version=0))
        else:
            robot.listen(Vector3Stamped, f'{NS}/reward')   # the learner's subscription
        assert robot.arrived(ir, t0, 10.0), 'the held frame was not read once the gate opened'
        assert robot.arrived(robot.cmds, t0, 0.5) == [], 'the start waits for its decision'
        robot.pub_wheels.publish(conv.wheels_cmd_msg(WHEELS, t0, 'base_link'))
        got = robot.arrived(robot.cmds, t0, 10.0)
        assert len(got) == 1 and moving(got[0]), got
        assert len(robot.arrived(ir, t0, 0.0)) == 1, 'the frame read once'
        # the robot still held there resends the frame (its answer was lost): answered again
        robot.cmds.clear()
        robot.frame(t0)
        again = robot.arrived(robot.cmds, t0, 10.0)
        assert again and moving(again[0]), again
        assert len(robot.arrived(ir, t0, 0.0)) == 1, 'and not read again'
    finally:
        out = stop(proc)
    assert 'Traceback' not in out, out


def test_a_bad_profile_or_topics_that_clash_stop_the_node_in_one_line():
    """Exit code 2 and one line naming the key (a node at the root: its odom and cmd_vel
    would be the robot's)."""
    cases = {"unknown robot profile 'nosuch'": ('-p', 'node.profile:=nosuch'),
             'node.period = 5.0 is out of range: must be in [0.005, 1.0]':
                 ('-p', 'node.period:=5.0'),
             'robot topics odom: /odom, cmd_vel: /cmd_vel are topics of the interface: run the '
             'node in a namespace of its own': ('-p', 'node.profile:=husky')}
    procs = {text: start_node('cr_bridge.robot_node', *args) for text, args in cases.items()}
    for text, proc in procs.items():
        out, _ = proc.communicate(timeout=60)
        lines = [s for s in out.splitlines() if s.strip()]
        assert proc.returncode == 2 and len(lines) == 1 and text in lines[0], out


def test_the_robot_side_messages_as_arrays():
    scan = scan_from_msg(LaserScan(angle_min=-1.0, angle_increment=0.5, range_min=0.1,
                                   range_max=4.0, ranges=[1.0, math.inf, 2.0]))
    assert (scan.angle_min, scan.angle_increment, scan.range_min, scan.range_max) == \
        (-1.0, 0.5, pytest.approx(0.1), 4.0)
    assert scan.ranges.tolist() == [1.0, math.inf, 2.0]
    odom = Odometry()
    odom.header.stamp = Time(sec=3, nanosec=500_000_000)
    odom.pose.pose.position.x, odom.pose.pose.position.y = 1.0, -2.0
    odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = math.sin(0.4), math.cos(0.4)
    odom.twist.twist.linear.x, odom.twist.twist.angular.z = 0.25, -0.5
    t, pose, v, w = odom_from_msg(odom)
    assert t == 3.5 and pose.tolist() == pytest.approx([1.0, -2.0, 0.8]) and (v, w) == \
        (0.25, -0.5)
    cam = JointState(name=['L2', 'destination', 'L1'], position=[0.2, -0.1, math.nan],
                     effort=[0.05, 0.3])
    t, bearings, widths = blobs_from_msg(cam, ['destination', 'L1', 'L2', 'L3'])
    assert np.array_equal(bearings, [-0.1, math.nan, 0.2, math.nan], equal_nan=True)
    assert np.array_equal(widths, [0.3, math.nan, 0.05, math.nan], equal_nan=True)
