"""Message conversions of the Husky world: the one place where its values meet ROS types.

==============  ==========================  =============================================
topic           type                        content
==============  ==========================  =============================================
``/clock``      rosgraph_msgs/Clock         sim time
``odom``        nav_msgs/Odometry           wheel odometry, ``odom`` -> ``base_link``
``scan``        sensor_msgs/LaserScan       the lidar, frame ``lidar``
``image_raw``   sensor_msgs/Image           the camera, ``rgb8``, frame ``camera``
``camera_info`` sensor_msgs/CameraInfo      its pinhole intrinsics, same stamp and frame
``cmd_vel``     geometry_msgs/TwistStamped  in: ``twist.linear.x``, ``twist.angular.z``
==============  ==========================  =============================================
"""

from __future__ import annotations

import array
import math

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
import numpy as np
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, LaserScan

from husky_world.world import Intrinsics, Odom

__all__ = ['ODOM_COVARIANCE', 'to_time', 'from_time', 'clock_msg', 'odom_msg', 'scan_msg',
           'image_msg', 'camera_info_msg', 'command_from_msg']

#: Diagonal of the pose and twist covariances of ``odom`` (x, y, z, roll, pitch, yaw), as
#: Clearpath's diff_drive_controller configuration of the Husky sets them.
ODOM_COVARIANCE = (0.001, 0.001, 0.001, 0.001, 0.001, 0.01)


def to_time(t: float) -> Time:
    """Seconds to builtin_interfaces/Time, rounded to the nearest nanosecond."""
    sec, nanosec = divmod(int(round(t * 1e9)), 1_000_000_000)
    return Time(sec=int(sec), nanosec=int(nanosec))


def from_time(stamp: Time) -> float:
    """builtin_interfaces/Time to seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def clock_msg(t: float) -> Clock:
    """``/clock`` at sim time ``t`` [s]."""
    return Clock(clock=to_time(t))


def odom_msg(odom: Odom, t: float, frame: str = 'odom', child_frame: str = 'base_link'
             ) -> Odometry:
    """Wheel odometry: pose in ``frame``, twist in ``child_frame``."""
    msg = Odometry()
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.child_frame_id = child_frame
    msg.pose.pose.position.x, msg.pose.pose.position.y = odom.x, odom.y
    msg.pose.pose.orientation.z = math.sin(odom.yaw / 2.0)
    msg.pose.pose.orientation.w = math.cos(odom.yaw / 2.0)
    msg.twist.twist.linear.x, msg.twist.twist.angular.z = odom.v, odom.omega
    cov = [0.0] * 36
    for i, c in enumerate(ODOM_COVARIANCE):
        cov[7 * i] = c
    msg.pose.covariance = msg.twist.covariance = cov
    return msg


def scan_msg(ranges: np.ndarray, angles: np.ndarray, range_min: float, range_max: float,
             scan_time: float, t: float, frame: str = 'lidar') -> LaserScan:
    """A LaserScan of ``ranges`` (N,) [m] at ``angles`` (N,) [rad], evenly spaced."""
    msg = LaserScan()
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.angle_min, msg.angle_max = float(angles[0]), float(angles[-1])
    msg.angle_increment = float(angles[1] - angles[0]) if len(angles) > 1 else 0.0
    msg.time_increment = 0.0
    msg.scan_time = float(scan_time)
    msg.range_min, msg.range_max = float(range_min), float(range_max)
    msg.ranges = array.array('f', np.asarray(ranges, dtype=np.float32).tobytes())
    return msg


def image_msg(rgb: np.ndarray, t: float, frame: str = 'camera') -> Image:
    """An ``rgb8`` Image of ``rgb`` (H, W, 3) uint8."""
    h, w, _ = rgb.shape
    msg = Image(height=h, width=w, encoding='rgb8', is_bigendian=0, step=3 * w)
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.data = array.array('B', np.ascontiguousarray(rgb, dtype=np.uint8).tobytes())
    return msg


def camera_info_msg(k: Intrinsics, t: float, frame: str = 'camera') -> CameraInfo:
    """The pinhole's CameraInfo: no distortion, K and P from the intrinsics."""
    msg = CameraInfo(width=k.width, height=k.height, distortion_model='plumb_bob')
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.d = [0.0] * 5
    msg.k = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def command_from_msg(msg: TwistStamped) -> tuple[float, float]:
    """``(v, omega)`` of a ``cmd_vel`` message (its stamp is not used)."""
    return float(msg.twist.linear.x), float(msg.twist.angular.z)
