"""``ros2 run husky_world world``: Clearpath's Husky in a PyBullet world, as a Gazebo bridge is.

The world of :mod:`husky_world.world` (the CLIS arena scaled to ``size``, the Husky's URDF,
PyBullet's physics and TinyRenderer), behind the standard topics of a differential-drive
ROS 2 robot and nothing else:

=================  ==========================  ===========  ================================
topic              type                        QoS          rate [Hz of sim time]
=================  ==========================  ===========  ================================
``/clock``         rosgraph_msgs/Clock         reliable 10  ``clock_rate`` (100)
``odom``           nav_msgs/Odometry           reliable 10  ``odom_rate`` (50)
``scan``           sensor_msgs/LaserScan       sensor data  ``scan_rate`` (10)
``image_raw``      sensor_msgs/Image (rgb8)    sensor data  ``image_rate`` (10)
``camera_info``    sensor_msgs/CameraInfo      sensor data  with each image, the same stamp
``cmd_vel`` (in)   geometry_msgs/TwistStamped  reliable 10  any (lockstep: one per image)
``ground_truth``   nav_msgs/Odometry           reliable 10  with odom, if ``ground_truth``
=================  ==========================  ===========  ================================

``ground_truth`` (off by default, as Gazebo's pose plugin is): the body's true pose in the
arena (frame ``map``), for a benchmark that judges a localization; no robot has it, and the
CLIS graph never reads it.

"sensor data" is rclpy's ``qos_profile_sensor_data`` (best effort, depth 5), as Gazebo's
bridges publish sensors: a subscriber must ask for best effort. No reset service: where the
next episode starts is the driver's business (it drives the robot there).

Time: the physics steps at 240 Hz from sim time 0; a message is published at the first step
at or after each multiple of its period and stamped with that step's time (the state it
describes); ``/clock`` comes first. ``real_time_factor`` paces the physics against the wall
clock (1 = real time, 0 = as fast as the CPU goes); commands are taken every
:data:`SPIN_EVERY` steps (in lockstep at 0, unpaced: at the held frames, where its commands
come, and every :data:`SPIN_EVERY` steps only while it runs free after a timeout). The node's
own ROS clock is the wall's.

Lockstep (``lockstep``, off by default; like Gazebo's or PX4 SITL's lockstep, for benchmarks
and tests that must not depend on the host's speed): the world waits for its controller. After
publishing an image (the camera frame at sim time t) the physics does not step on until a
``cmd_vel`` whose ``header.stamp`` is at or after t (within :data:`STAMP_TOLERANCE` s) arrives,
or ``command_timeout`` s of wall time passed: then it runs free, as without lockstep, until the
next ``cmd_vel`` arrives (one warning per such timeout), and is held again at the next image.
Before the first command it is held at t = 0 until one comes (a graph that starts slowly on
a loaded host is waited for). While it waits it
serves its callbacks and re-publishes the held instant's ``/clock``, odom, scan, image and
camera_info (all five, stamped t) every :data:`RESEND_EVERY` s of wall time, so that a message
lost while the graph connects does not stall the run. Whether odom and scan are published at
the image instants in the first place is the rates' business (``odom_rate``, ``scan_rate``).
``real_time_factor`` still paces the physics: a held world falls behind the wall clock and
makes up for it as it would for a slow step; more than 1 s behind, it starts afresh from there
instead of bursting to catch up.

Safety: a command is clipped to ``v_max``, ``omega_max``; one with NaN or inf drives at zero;
``cmd_timeout`` s of sim time without a command set the wheels to zero. Ctrl-C or SIGTERM
stops the loop between two steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
import math
import sys
import time
from typing import Any

from clis_base.params import as_dict, build
from clis_base.ros.process import SHUTDOWN_RACES, reraise_unless_shut_down, start_node
from clis_base.ros.ros_params import declare_from_config
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, LaserScan

from husky_world import conversions as conv
from husky_world.world import (
    PHYSICS_HZ,
    RANGE_MIN,
    Every,
    HuskyWorld,
    HuskyWorldParams,
    Odom,
    opt,
    param_fields,
)

__all__ = ['SPIN_EVERY', 'RESEND_EVERY', 'STAMP_TOLERANCE', 'HOLD_SPIN', 'WorldNodeParams',
           'FrameHold', 'WorldNode', 'run', 'main']

#: Physics steps between two takes of the commands (3: 80 Hz of sim time, a command acts
#: within 12.5 ms of sim time); an executor's turn costs about 0.6 ms of CPU, a step 0.1 ms.
SPIN_EVERY = 3
#: [s of wall time] lockstep: a held frame's messages are re-published this often.
RESEND_EVERY = 0.2
#: [s] lockstep: a command stamped this much before the held instant still releases it (the
#: stamps are whole nanoseconds).
STAMP_TOLERANCE = 1e-6
#: [s of wall time] lockstep: the longest executor turn while a frame is held (a command is
#: served as soon as it arrives; this bounds the reaction to a timeout, a resend or Ctrl-C).
HOLD_SPIN = 0.01


@dataclass(frozen=True)
class WorldNodeParams:
    """The node's own parameters (the world's are :class:`HuskyWorldParams`)."""

    real_time_factor: float = opt(1.0, 0.0, 100.0, doc='sim time / wall time; 0 = as fast as '
                                  'the CPU goes')
    clock_rate: float = opt(100.0, 1.0, float(PHYSICS_HZ), doc='[Hz of sim time] /clock')
    odom_rate: float = opt(50.0, 1.0, float(PHYSICS_HZ), doc='[Hz of sim time] odom')
    scan_rate: float = opt(10.0, 0.1, float(PHYSICS_HZ), doc='[Hz of sim time] scan')
    image_rate: float = opt(10.0, 0.1, float(PHYSICS_HZ), doc='[Hz of sim time] image_raw '
                            'and camera_info')
    ground_truth: bool = opt(False, doc="true: also publish the body's true pose on "
                             "'ground_truth' with each odom (for benchmarks only)")
    lockstep: bool = opt(False, doc='true: after each image (sim time t) the physics waits for '
                         'a cmd_vel stamped at or after t (module docstring)')
    command_timeout: float = opt(30.0, 0.01, 3600.0, doc='[s wall] lockstep: no such cmd_vel '
                                 'for this long: run free until the next cmd_vel (the graph '
                                 "holds a frame while its learner learns: the learner's "
                                 'timeout)')


class FrameHold:
    """The lockstep's rule, without ROS: when the world may step on past a held frame.

    Parameters
    ----------
    timeout : float
        [s of wall time] a frame held this long without its command is let go, and the world
        runs free (nothing is held) until the next command re-arms the hold; before the first
        command the world waits for its controller however long it takes to come up.
    resend : float
        [s of wall time] :meth:`poll` says ``'resend'`` this long after the frame was
        published or last re-published.
    tolerance : float
        [s] a command stamped this much before the held instant still releases it.

    The wall times ``now`` are the caller's (``time.monotonic()``), so the rule is a pure
    function of its calls.
    """

    def __init__(self, timeout: float, resend: float = RESEND_EVERY,
                 tolerance: float = STAMP_TOLERANCE) -> None:
        self.timeout, self.resend, self.tolerance = float(timeout), float(resend), tolerance
        self.t: float | None = None        # the held instant [s of sim time]; None: not held
        self.free = False                  # timed out: nothing held until the next command
        self.latest = -math.inf            # the latest command stamp [s of sim time]
        self.timeouts = 0                  # frames let go by the timeout
        self._since = self._sent = 0.0     # [s of wall time] held since, last (re)published

    def held_at(self, t: float, now: float) -> bool:
        """The frame at sim time ``t`` was published at wall time ``now``: hold the world there
        (unless it runs free after a timeout). Returns whether it is held."""
        if self.free:
            return False
        self.t, self._since, self._sent = float(t), now, now
        return True

    def on_command(self, stamp: float) -> None:
        """A command stamped ``stamp`` [s of sim time] arrived; it re-arms a free world."""
        self.latest = max(self.latest, float(stamp))
        self.free = False

    def poll(self, now: float) -> str:
        """``'go'``: step on (nothing held, the command came, or the timeout let the frame go:
        then :attr:`timeouts` counts it); ``'resend'``: still held, re-publish the frame now;
        ``'wait'``: still held."""
        if self.t is None:
            return 'go'
        if self.latest >= self.t - self.tolerance:
            self.t = None
            return 'go'
        if now - self._since >= self.timeout and self.latest > -math.inf:
            self.t, self.free = None, True
            self.timeouts += 1
            return 'go'
        if now - self._sent >= self.resend:
            self._sent = now
            return 'resend'
        return 'wait'


def _split(values: dict) -> tuple[dict, dict]:
    """The declared values as the world's and the node's parameters."""
    node_keys = {f.name for f in fields(WorldNodeParams)}
    return ({k: v for k, v in values.items() if k not in node_keys},
            {k: v for k, v in values.items() if k in node_keys})


class WorldNode(Node):
    """Thin glue: cmd_vel -> world; world -> /clock, odom, scan, image_raw, camera_info."""

    def __init__(self) -> None:
        super().__init__('husky_world')
        defaults = {**as_dict(HuskyWorldParams()), **as_dict(WorldNodeParams())}
        world_values, node_values = _split(declare_from_config(self, defaults))
        self.cfg = build(WorldNodeParams, node_values)
        self.world = HuskyWorld(build(HuskyWorldParams, world_values))
        self.every = {name: Every(getattr(self.cfg, f'{name}_rate'))
                      for name in ('clock', 'odom', 'scan', 'image')}
        self.pub_clock = self.create_publisher(Clock, '/clock', 10)
        self.pub_odom = self.create_publisher(Odometry, 'odom', QoSProfile(depth=10))
        self.pub_scan = self.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
        self.pub_image = self.create_publisher(Image, 'image_raw', qos_profile_sensor_data)
        self.pub_info = self.create_publisher(CameraInfo, 'camera_info',
                                              qos_profile_sensor_data)
        self.sub_cmd = self.create_subscription(TwistStamped, 'cmd_vel', self._on_cmd, 10)
        self.pub_truth = (self.create_publisher(Odometry, 'ground_truth', 10)
                          if self.cfg.ground_truth else None)
        #: lockstep's rule (None: no lockstep) and the held frame's messages
        self.hold = FrameHold(self.cfg.command_timeout) if self.cfg.lockstep else None
        self._held: list[tuple[Publisher, Any]] = []
        w = self.world
        x, y, yaw = w.start_pose
        self.get_logger().info(
            f'Husky at ({x:.2f}, {y:.2f}, {yaw:.2f} rad) in {w.arena.source} scaled to '
            f'{w.params.size} m; real time x{self.cfg.real_time_factor or "max"}'
            + (f'; lockstep (command_timeout {self.cfg.command_timeout:g} s)'
               if self.hold is not None else ''))

    def _on_cmd(self, msg: TwistStamped) -> None:
        if not self.world.set_command(*conv.command_from_msg(msg)):
            self.get_logger().warning('a cmd_vel with NaN or inf: wheels set to zero',
                                      throttle_duration_sec=1.0)
        if self.hold is not None:
            self.hold.on_command(conv.from_time(msg.header.stamp))

    def _messages(self, name: str, t: float) -> list[tuple[Publisher, Any]]:
        """The messages of schedule ``name`` for the current state, stamped ``t``."""
        w = self.world
        if name == 'clock':
            return [(self.pub_clock, conv.clock_msg(t))]
        if name == 'odom':
            out = [(self.pub_odom, conv.odom_msg(w.odom(), t))]
            if self.pub_truth is not None:
                x, y, yaw = w.pose()
                out.append((self.pub_truth, conv.odom_msg(Odom(x, y, yaw, 0.0, 0.0), t, 'map')))
            return out
        if name == 'scan':
            return [(self.pub_scan, conv.scan_msg(w.scan(), w.scan_angles, RANGE_MIN,
                                                  w.params.range_max,
                                                  1.0 / self.cfg.scan_rate, t))]
        return [(self.pub_image, conv.image_msg(w.image(), t)),
                (self.pub_info, conv.camera_info_msg(w.intrinsics, t))]

    def publish(self) -> None:
        """Publish what is due for the current state (``/clock`` first); after an image, under
        lockstep, hold the world at this instant with all five of its messages to re-send."""
        n, t = self.world.steps, self.world.t
        sent: dict[str, list[tuple[Publisher, Any]]] = {}
        for name, every in self.every.items():
            if every.due(n):
                sent[name] = self._messages(name, t)
                for pub, msg in sent[name]:
                    pub.publish(msg)
        if ('image' in sent and self.hold is not None
                and self.hold.held_at(t, time.monotonic())):
            self._held = [m for name in self.every
                          for m in (sent[name] if name in sent else self._messages(name, t))]

    def wait_for_command(self, executor: SingleThreadedExecutor,
                         stop: Callable[[], bool] = lambda: False) -> None:
        """Lockstep: while the frame just published is held (:class:`FrameHold`), serve the
        callbacks and re-publish it every :data:`RESEND_EVERY` s; return when the world may
        step on (at once without lockstep or a held frame), rclpy shuts down or ``stop()``."""
        hold = self.hold
        if hold is None:
            return
        t, timeouts = hold.t, hold.timeouts
        while rclpy.ok() and not stop():
            state = hold.poll(time.monotonic())
            if state == 'go':
                break
            if state == 'resend':
                for pub, msg in self._held:
                    pub.publish(msg)
            executor.spin_once(timeout_sec=HOLD_SPIN)
        self._held = []
        if hold.timeouts > timeouts:
            self.get_logger().warning(
                f'lockstep: no cmd_vel stamped at or after {t:.4f} s within '
                f'{hold.timeout:g} s of wall time: running free until the next cmd_vel')

    def tick(self, executor: SingleThreadedExecutor | None = None,
             stop: Callable[[], bool] = lambda: False) -> None:
        """Publish what is due for the current state; under lockstep, given the ``executor``
        that serves the commands, wait while it is held; then step the physics once."""
        self.publish()
        if executor is not None:
            self.wait_for_command(executor, stop)
        self.world.step(1)

    def destroy_node(self) -> None:
        self.world.close()
        super().destroy_node()


def run(node: WorldNode, executor: SingleThreadedExecutor,
        stop: Callable[[], bool] = lambda: False) -> None:
    """Step the world at ``real_time_factor`` x the wall clock until rclpy shuts down or
    ``stop()``, taking the commands every :data:`SPIN_EVERY` steps (in lockstep unpaced, only
    while it runs free) and while waiting for the wall clock, or for a command under lockstep."""
    rtf = node.cfg.real_time_factor
    wall0, t0 = time.monotonic(), node.world.t
    since = 0
    while rclpy.ok() and not stop():
        node.tick(executor, stop)
        since += 1
        if since < SPIN_EVERY:
            continue
        since = 0
        if rtf <= 0.0:
            # in lockstep the commands come while a frame is held (wait_for_command serves
            # them); an executor's turn between frames would cost as much CPU as the physics
            if node.hold is None or node.hold.free:
                executor.spin_once(timeout_sec=0.0)
            continue
        target = wall0 + (node.world.t - t0) / rtf
        now = time.monotonic()
        if now - target > 1.0:                   # fell far behind: no burst to catch up
            wall0, t0 = now, node.world.t
        executor.spin_once(timeout_sec=max(0.0, target - now))
        while (now := time.monotonic()) < target and not stop():
            executor.spin_once(timeout_sec=target - now)


def _print_help() -> None:
    print(f'usage: {sys.argv[0]} [--ros-args -p KEY:=VALUE ...]\n')
    print((__doc__ or '').strip())
    print('\nParameters (-p KEY:=VALUE):')
    for cls in (HuskyWorldParams, WorldNodeParams):
        for name, default, what in param_fields(cls):
            print(f'  {name} = {default!r}: {what}')


def main(args: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if args is None else args)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        _print_help()
        raise SystemExit(0)
    # Ctrl-C and SIGTERM only raise a flag: the loop ends between two steps, never inside
    # rclpy or a PyBullet call
    node, stopping = start_node('husky_world', WorldNode, args)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        run(node, executor, stop=lambda: bool(stopping))
    except ExternalShutdownException:
        pass
    except SHUTDOWN_RACES:
        reraise_unless_shut_down()
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
