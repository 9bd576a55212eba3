"""Message conversions of the robot interface: the one place where core values meet ROS types.

The simulator node and the real-robot bridge publish the same interface (docs/robot.md#topics):

============  =================================  ==================================================
topic         type                               content
============  =================================  ==================================================
cmd_vel       geometry_msgs/TwistStamped         command in; plain Twist by parameter
wheels_cmd    sensor_msgs/JointState             command in, the simulator's alternative to
                                                 cmd_vel (node.command): velocity = (v_left,
                                                 v_right) m/s, the wheels exactly as decided
ir            sensor_msgs/LaserScan              7 IR beams, distance from the body surface (m)
ir_ranges     sensor_msgs/JointState             the same beams at full precision: name = ir_0 ...
                                                 (right to left), position = range (m, float64)
camera        sensor_msgs/JointState             blob bearings: name = destination + landmarks,
                                                 position = bearing rad (NaN = not seen)
wheels        sensor_msgs/JointState             executed wheel velocities (m/s), odometry input
reward        geometry_msgs/Vector3Stamped       x = reward of the tick, y = episode return,
                                                 z = episode index
episode       diagnostic_msgs/DiagnosticArray    episode events (start, reached, timeout)
odom          nav_msgs/Odometry                  ground truth pose (display/evaluation only)
markers       visualization_msgs/MarkerArray     arena and robot
/clock        rosgraph_msgs/Clock                sim time
============  =================================  ==================================================
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
import math

from builtin_interfaces.msg import Time
from clis_base.ros.qos import STREAM_DEPTH  # noqa: F401 - the interface streams' depth
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Twist, TwistStamped, Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, LaserScan
from visualization_msgs.msg import Marker, MarkerArray

from cr_sim.core.robot import twist_to_wheels, wheels_to_twist

WHEEL_NAMES = ('left_wheel', 'right_wheel')
EPISODE_STATUS = 'episode'


def to_time(t: float) -> Time:
    """Seconds (float) to builtin_interfaces/Time, rounded to the nearest nanosecond (so that
    180.99999999997 is 181 s, not 180 s + a nanosecond field that wrapped around)."""
    sec, nanosec = divmod(int(round(t * 1e9)), 1_000_000_000)
    return Time(sec=int(sec), nanosec=int(nanosec))


def from_time(stamp: Time) -> float:
    """builtin_interfaces/Time to seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def clock_msg(t: float) -> Clock:
    return Clock(clock=to_time(t))


def wheels_from_cmd(msg: Twist | TwistStamped | JointState, wheel_base: float) -> np.ndarray:
    """(v_left, v_right) in m/s from a Twist or TwistStamped command, or from a ``wheels_cmd``
    JointState (its two velocities as sent: no round trip through (v, w), which is exact only
    to rounding); not yet clamped.

    Raises
    ------
    ValueError
        A JointState without exactly two velocities.
    """
    if isinstance(msg, JointState):
        if len(msg.velocity) != 2:
            raise ValueError(f'wheels_cmd needs 2 velocities (v_left, v_right), got '
                             f'{len(msg.velocity)}')
        return np.array(msg.velocity, float)
    twist = msg.twist if isinstance(msg, TwistStamped) else msg
    return np.asarray(twist_to_wheels(twist.linear.x, twist.angular.z, wheel_base), float)


def wheels_cmd_msg(u: Sequence[float], t: float, frame: str) -> JointState:
    """A ``wheels_cmd`` message: the wheel velocities ``u`` = (v_left, v_right) [m/s]."""
    msg = JointState(name=list(WHEEL_NAMES), velocity=[float(v) for v in u])
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    return msg


def cmd_stamp(msg: Twist | TwistStamped | JointState) -> float | None:
    """The stamp [s] of a TwistStamped or wheels_cmd command (the time of the readings it was
    decided on); None for a plain Twist."""
    return None if isinstance(msg, Twist) else from_time(msg.header.stamp)


def cmd_from_wheels(u: Sequence[float], wheel_base: float, t: float, frame: str,
                    stamped: bool = True) -> Twist | TwistStamped:
    """A cmd_vel message for wheel velocities ``u`` = (v_left, v_right)."""
    v, w = wheels_to_twist(u[0], u[1], wheel_base)
    twist = Twist()
    twist.linear.x, twist.angular.z = float(v), float(w)
    if not stamped:
        return twist
    msg = TwistStamped(twist=twist)
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    return msg


def ir_msg(ir: np.ndarray, angles: Sequence[float], ir_range: float, t: float,
           frame: str) -> LaserScan:
    """The IR beams as one LaserScan (beams must be evenly spaced in angle)."""
    msg = LaserScan()
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.angle_min, msg.angle_max = float(angles[0]), float(angles[-1])
    msg.angle_increment = float((angles[-1] - angles[0]) / max(len(angles) - 1, 1))
    msg.range_min, msg.range_max = 0.0, float(ir_range)
    msg.ranges = [float(r) for r in ir]
    return msg


def ir_from_msg(msg: LaserScan) -> tuple[float, np.ndarray]:
    return from_time(msg.header.stamp), np.asarray(msg.ranges, float)


def ir_ranges_msg(ir: np.ndarray, t: float, frame: str) -> JointState:
    """The IR beams at full precision (LaserScan's ranges are float32): ``name`` = ``ir_0``
    ... in the LaserScan's order, ``position`` = range [m] (float64). The modules read these,
    so the graph's percepts are the headless runner's to the bit (docs/design.md §6)."""
    msg = JointState(name=[f'ir_{k}' for k in range(len(ir))],
                     position=[float(r) for r in ir])
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    return msg


def ir_ranges_from_msg(msg: JointState) -> tuple[float, np.ndarray]:
    return from_time(msg.header.stamp), np.asarray(msg.position, float)


def bearings_msg(names: Sequence[str], bearings: Iterable[float], t: float,
                 frame: str) -> JointState:
    """Camera blob bearings (rad, relative to heading); NaN marks a blob not seen."""
    msg = JointState(name=list(names), position=[float(b) for b in bearings])
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    return msg


def bearings_from_msg(msg: JointState) -> tuple[float, dict[str, float]]:
    return from_time(msg.header.stamp), dict(zip(msg.name, msg.position))


def wheels_msg(wheels: Sequence[float], t: float, frame: str) -> JointState:
    msg = JointState(name=list(WHEEL_NAMES), velocity=[float(v) for v in wheels])
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    return msg


def wheels_from_msg(msg: JointState) -> tuple[float, np.ndarray]:
    return from_time(msg.header.stamp), np.asarray(msg.velocity, float)


def reward_msg(r: float, episode_return: float, episode: int, t: float) -> Vector3Stamped:
    msg = Vector3Stamped()
    msg.header.stamp = to_time(t)
    msg.vector.x, msg.vector.y, msg.vector.z = float(r), float(episode_return), float(episode)
    return msg


def reward_from_msg(msg: Vector3Stamped) -> tuple[float, float, int]:
    """(time, reward, episode index)."""
    return from_time(msg.header.stamp), msg.vector.x, int(msg.vector.z)


def status_msg(name: str, level: bytes, message: str, values: Mapping[str, object], t: float,
               hardware_id: str = 'cr') -> DiagnosticArray:
    """One stamped DiagnosticStatus: ``name``, ``level`` (``DiagnosticStatus.OK`` ...), a
    message and the key/values as text (the events here, the bridge's link report)."""
    status = DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = to_time(t)
    return msg


def event_msg(name: str, event: str, t: float, /, **values: object) -> DiagnosticArray:
    """A stamped event: one DiagnosticStatus named ``name`` with ``message = event`` and the
    key/values as text (episode events here, the learner's progress in the graph)."""
    return status_msg(name, DiagnosticStatus.OK, event, values, t)


def event_from_msg(msg: DiagnosticArray) -> tuple[float, str, dict[str, str]]:
    """``(t, event, {key: value text})`` of :func:`event_msg`."""
    status = msg.status[0]
    return from_time(msg.header.stamp), status.message, {kv.key: kv.value
                                                         for kv in status.values}


def episode_msg(event: str, t: float, /, **values: object) -> DiagnosticArray:
    """An episode event (``start``, ``reached``, ``timeout``, ``reset``) with key/values."""
    return event_msg(EPISODE_STATUS, event, t, **values)


#: Decodes :func:`episode_msg` (any :func:`event_msg`).
episode_from_msg = event_from_msg


def odom_msg(pose: np.ndarray, wheels: np.ndarray, wheel_base: float, t: float,
             frame: str, child_frame: str) -> Odometry:
    """Ground-truth pose (x, y, theta) and body twist as nav_msgs/Odometry."""
    msg = Odometry()
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.child_frame_id = child_frame
    x, y, theta = (float(p) for p in pose)
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation.z = math.sin(theta / 2.0)
    msg.pose.pose.orientation.w = math.cos(theta / 2.0)
    v, w = wheels_to_twist(wheels[0], wheels[1], wheel_base)
    msg.twist.twist.linear.x, msg.twist.twist.angular.z = float(v), float(w)
    return msg


def _box_marker(mid: int, ns: str, box: Sequence[float], height: float,
                rgba: Sequence[float], frame: str) -> Marker:
    """A CUBE marker for an axis-aligned box ``(xmin, ymin, xmax, ymax)``."""
    m = Marker(id=mid, ns=ns, type=Marker.CUBE, action=Marker.ADD)
    m.header.frame_id = frame
    m.pose.position.x = (box[0] + box[2]) / 2.0
    m.pose.position.y = (box[1] + box[3]) / 2.0
    m.pose.position.z = height / 2.0
    m.pose.orientation.w = 1.0
    m.scale.x, m.scale.y, m.scale.z = box[2] - box[0], box[3] - box[1], height
    m.color.r, m.color.g, m.color.b, m.color.a = (float(c) for c in rgba)
    return m


def arena_markers(walls: Sequence[Sequence[float]], short: Sequence[Sequence[float]],
                  tall: Sequence[Sequence[float]], landmarks: Sequence[tuple[float, float]],
                  destination: tuple[float, float, float], frame: str) -> MarkerArray:
    """Static arena: walls, short (green) and tall (dark) obstacles, landmarks, destination."""
    markers = []
    for k, box in enumerate(walls):
        markers.append(_box_marker(k, 'walls', box, 0.3, (0.6, 0.6, 0.6, 1.0), frame))
    for k, box in enumerate(short):
        markers.append(_box_marker(k, 'short_obstacles', box, 0.1, (0.1, 0.7, 0.2, 1.0), frame))
    for k, box in enumerate(tall):
        markers.append(_box_marker(k, 'tall_obstacles', box, 0.5, (0.2, 0.2, 0.3, 1.0), frame))
    for k, (x, y) in enumerate(landmarks):
        m = Marker(id=k, ns='landmarks', type=Marker.CYLINDER, action=Marker.ADD)
        m.header.frame_id = frame
        m.pose.position.x, m.pose.position.y, m.pose.position.z = float(x), float(y), 0.25
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = 0.08
        m.scale.z = 0.5
        m.color.r, m.color.g, m.color.b, m.color.a = 0.9, 0.5 + 0.1 * k, 0.1, 1.0
        markers.append(m)
    x, y, radius = destination
    m = Marker(id=0, ns='destination', type=Marker.CYLINDER, action=Marker.ADD)
    m.header.frame_id = frame
    m.pose.position.x, m.pose.position.y, m.pose.position.z = float(x), float(y), 0.005
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = 2.0 * radius
    m.scale.z = 0.01
    m.color.r, m.color.g, m.color.b, m.color.a = 1.0, 0.1, 0.1, 0.8
    markers.append(m)
    return MarkerArray(markers=markers)


def robot_marker(pose: np.ndarray, radius: float, t: float, frame: str) -> Marker:
    """The robot as an ARROW-topped disc at its ground-truth pose."""
    m = Marker(id=0, ns='robot', type=Marker.ARROW, action=Marker.ADD)
    m.header.stamp, m.header.frame_id = to_time(t), frame
    m.points = [Point(x=float(pose[0]), y=float(pose[1]), z=0.05),
                Point(x=float(pose[0] + 2 * radius * math.cos(pose[2])),
                      y=float(pose[1] + 2 * radius * math.sin(pose[2])), z=0.05)]
    m.scale.x, m.scale.y, m.scale.z = 0.04, 0.08, 0.08
    m.color.r, m.color.g, m.color.b, m.color.a = 0.1, 0.3, 1.0, 1.0
    return m
