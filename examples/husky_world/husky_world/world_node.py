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
``cmd_vel`` (in)   geometry_msgs/TwistStamped  reliable 10  any
=================  ==========================  ===========  ================================

"sensor data" is rclpy's ``qos_profile_sensor_data`` (best effort, depth 5), as Gazebo's
bridges publish sensors: a subscriber must ask for best effort. No reset service: where the
next episode starts is the driver's business (it drives the robot there).

Time: the physics steps at 240 Hz from sim time 0; a message is published at the first step
at or after each multiple of its period and stamped with that step's time (the state it
describes); ``/clock`` comes first. ``real_time_factor`` paces the physics against the wall
clock (1 = real time, 0 = as fast as the CPU goes); commands are taken every
:data:`SPIN_EVERY` steps. The node's own ROS clock is the wall's.

Safety: a command is clipped to ``v_max``, ``omega_max``; one with NaN or inf drives at zero;
``cmd_timeout`` s of sim time without a command set the wheels to zero. Ctrl-C or SIGTERM
stops the loop between two steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
import sys
import time

from clis_base.params import as_dict, build
from clis_base.ros.process import SHUTDOWN_RACES, reraise_unless_shut_down, start_node
from clis_base.ros.ros_params import declare_from_config
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
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
    opt,
    param_fields,
)

__all__ = ['SPIN_EVERY', 'WorldNodeParams', 'WorldNode', 'run', 'main']

#: Physics steps between two takes of the commands (3: 80 Hz of sim time, a command acts
#: within 12.5 ms of sim time); an executor's turn costs about 0.6 ms of CPU, a step 0.1 ms.
SPIN_EVERY = 3


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
        w = self.world
        x, y, yaw = w.start_pose
        self.get_logger().info(
            f'Husky at ({x:.2f}, {y:.2f}, {yaw:.2f} rad) in {w.arena.source} scaled to '
            f'{w.params.size} m; real time x{self.cfg.real_time_factor or "max"}')

    def _on_cmd(self, msg: TwistStamped) -> None:
        if not self.world.set_command(*conv.command_from_msg(msg)):
            self.get_logger().warning('a cmd_vel with NaN or inf: wheels set to zero',
                                      throttle_duration_sec=1.0)

    def tick(self) -> None:
        """Publish what is due for the current state, then step the physics once."""
        w, n, t = self.world, self.world.steps, self.world.t
        if self.every['clock'].due(n):
            self.pub_clock.publish(conv.clock_msg(t))
        if self.every['odom'].due(n):
            self.pub_odom.publish(conv.odom_msg(w.odom(), t))
        if self.every['scan'].due(n):
            self.pub_scan.publish(conv.scan_msg(w.scan(), w.scan_angles, RANGE_MIN,
                                                w.params.range_max, 1.0 / self.cfg.scan_rate,
                                                t))
        if self.every['image'].due(n):
            self.pub_image.publish(conv.image_msg(w.image(), t))
            self.pub_info.publish(conv.camera_info_msg(w.intrinsics, t))
        w.step(1)

    def destroy_node(self) -> None:
        self.world.close()
        super().destroy_node()


def run(node: WorldNode, executor: SingleThreadedExecutor,
        stop: Callable[[], bool] = lambda: False) -> None:
    """Step the world at ``real_time_factor`` x the wall clock until rclpy shuts down or
    ``stop()``, taking the commands every :data:`SPIN_EVERY` steps (and while waiting for the
    wall clock)."""
    rtf = node.cfg.real_time_factor
    wall0, t0 = time.monotonic(), node.world.t
    since = 0
    while rclpy.ok() and not stop():
        node.tick()
        since += 1
        if since < SPIN_EVERY:
            continue
        since = 0
        if rtf <= 0.0:
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
