"""Message layouts of the bridge's own topic (``diagnostics``) and of the robot node's robot
side (``odom``, ``scan``, the detector's ``camera``, ``cmd_vel``'s two types); the robot
interface itself is :mod:`cr_sim.conversions`, shared with the simulator."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math

from cr_sim.conversions import from_time, status_msg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import JointState, LaserScan

from cr_bridge.core.ros_robot import Scan

__all__ = ['LEVELS', 'CMD_VEL_CLASSES', 'diagnostics_msg', 'diagnostics_from_msg',
           'scan_from_msg', 'odom_from_msg', 'blobs_from_msg']

LEVELS = {'ok': DiagnosticStatus.OK, 'warn': DiagnosticStatus.WARN,
          'error': DiagnosticStatus.ERROR, 'stale': DiagnosticStatus.STALE}

#: cmd_vel's message class by its name in a profile (``topics.cmd_vel_type``).
CMD_VEL_CLASSES = {'Twist': Twist, 'TwistStamped': TwistStamped}


def diagnostics_msg(level: str, message: str, values: Mapping[str, object], t: float,
                    hardware_id: str) -> DiagnosticArray:
    """One status ``cr_bridge: link``: ``level`` (ok / warn / error), a message, counters."""
    return status_msg('cr_bridge: link', LEVELS[level], message, values, t, hardware_id)


def diagnostics_from_msg(msg: DiagnosticArray) -> tuple[int, str, dict[str, str]]:
    """``(level, message, values)`` of :func:`diagnostics_msg`."""
    s = msg.status[0]
    return int.from_bytes(s.level, 'little') if isinstance(s.level, bytes) else int(s.level), \
        s.message, {kv.key: kv.value for kv in s.values}


def scan_from_msg(msg: LaserScan) -> Scan:
    """A sensor_msgs/LaserScan as :class:`~cr_bridge.core.ros_robot.Scan` (its stamp, ray
    geometry, valid range and ranges)."""
    return Scan(from_time(msg.header.stamp), float(msg.angle_min), float(msg.angle_increment),
                float(msg.range_min), float(msg.range_max),
                np.asarray(msg.ranges, dtype=np.float64))


def odom_from_msg(msg: Odometry) -> tuple[float, np.ndarray, float, float]:
    """``(t, pose, v, omega)`` of a nav_msgs/Odometry: its stamp [s], the pose ``(x, y,
    yaw)`` (shape (3,); the yaw of the orientation quaternion [rad]), the body's forward speed
    [m/s] and yaw rate [rad/s]."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    twist = msg.twist.twist
    return (from_time(msg.header.stamp), np.array((p.x, p.y, yaw), dtype=np.float64),
            float(twist.linear.x), float(twist.angular.z))


def blobs_from_msg(msg: JointState, names: Sequence[str]) -> tuple[float, np.ndarray,
                                                                   np.ndarray]:
    """``(t, bearings, widths)`` of the detector's ``camera`` (sensor_msgs/JointState: ``name``
    = the blobs, ``position`` = bearing [rad], ``effort`` = apparent angular width [rad], NaN
    = not seen), in the order of ``names`` (shape (len(names),) each): NaN for a name the
    message does not carry or a value it leaves out."""
    bearings = np.full(len(names), np.nan)
    widths = np.full(len(names), np.nan)
    index = {name: k for k, name in enumerate(msg.name)}
    for i, name in enumerate(names):
        k = index.get(name)
        if k is None:
            continue
        if k < len(msg.position):
            bearings[i] = msg.position[k]
        if k < len(msg.effort):
            widths[i] = msg.effort[k]
    return from_time(msg.header.stamp), bearings, widths
