"""The simulator's sensors as a robot's standard topics: ``image_raw``, ``camera_info``, ``scan``.

So that the path any ROS 2 robot takes (a camera image read by ``clis_modules detector``, a
LaserScan read as the profile's sectors) runs on the simulator too, the simulator node
publishes, beside its own interface (docs/robot.md#topics), for a robot profile
(``config/robots/NAME.yaml``; the simulator's is ``cr``):

=============  ========================  =========================================================
topic          type                      content
=============  ========================  =========================================================
image_raw      sensor_msgs/Image, rgb8   the arena rendered by :func:`cr_sim.core.render.render`
                                         from the true pose through the profile's camera model
                                         (``camera.camera_model()``: the ``cr`` profile's
                                         omni-camera strip, 360 x 40 px, the heading at the
                                         middle column; a pinhole for a forward camera); no
                                         noise (the ``camera`` topic's bearings have the
                                         simulator's bearing noise, the image has none)
camera_info    sensor_msgs/CameraInfo    a pinhole profile only: its intrinsics (``k``, ``p``;
                                         ``plumb_bob`` with zero distortion). A panoramic strip
                                         has none: no pinhole matrix describes it, and the
                                         profile's camera section is its model (the ``cr``
                                         profile's ``topics.camera_info`` is '' accordingly)
scan           sensor_msgs/LaserScan     the IR beams as the profile's scan section reads them:
                                         one ray per sector, ``angle_min`` = the first sector's
                                         direction minus ``scan.yaw_deg``, ``angle_increment``
                                         the sectors' spacing (the ``cr`` profile: 7 rays from
                                         -pi/2 by pi/6), ``ranges`` the IR readings [m] from
                                         the body's surface (``scan.from_surface``; else plus
                                         ``body.radius``), ``range_max`` the profile's
                                         ``scan.range_max`` (plus the radius likewise; the
                                         ``cr`` profile: the IR range, 0.5 m, which is what
                                         "nothing in range" reads)
=============  ========================  =========================================================

All stamped with the reading's sim time in the robot's body frame; the names are relative.
Each message is built only while its topic has a subscriber (a frame costs a few milliseconds
to render: the ``cr`` strip about 2 ms, a 320 x 240 pinhole about 8 ms). The ``cr`` profile's
``scan`` is the simulator's ``ir`` LaserScan, unchanged (:func:`scan_msg` equals
:func:`cr_sim.conversions.ir_msg` for it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

from clis_base.ros.qos import STREAM_DEPTH
import numpy as np
from numpy.typing import ArrayLike
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, LaserScan

from cr_sim.conversions import to_time
from cr_sim.core.arena import Arena
from cr_sim.core.camera import Pinhole
from cr_sim.core.profile import RobotProfile, load_profile
from cr_sim.core.render import RenderParams, Scene, render
from cr_sim.core.sim import SensorParams

__all__ = ['ScanLayout', 'scan_layout', 'scan_msg', 'image_msg', 'camera_info_msg',
           'StandardTopics']

#: QoS of image_raw and camera_info: reliable (best-effort subscribers match it too), a few
#: frames deep.
IMAGE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


@dataclass(frozen=True)
class ScanLayout:
    """The rays of the LaserScan that carries the IR readings.

    Attributes
    ----------
    angle_min, angle_increment : float
        Direction of ray 0 and the step to the next, in the scan's frame [rad] (its angle 0
        at ``scan.yaw_deg`` from the heading).
    count : int
        Rays: one per IR beam.
    range_max : float
        The scan's ``range_max`` [m].
    offset : float
        Added to each IR reading (0 from the body's surface; the body radius from its
        centre) [m].
    """

    angle_min: float
    angle_increment: float
    count: int
    range_max: float
    offset: float

    @property
    def angle_max(self) -> float:
        """Direction of the last ray [rad]."""
        return self.angle_min + (self.count - 1) * self.angle_increment


def scan_layout(profile: RobotProfile,
                ir_angles_deg: Sequence[float] | None = None) -> ScanLayout:
    """The scan of a profile's sectors (one ray per sector, at its centre direction).

    Parameters
    ----------
    profile : RobotProfile
    ir_angles_deg : sequence of float, optional
        The simulator's IR directions (``sensors.ir_angles_deg``): the sectors must be these.

    Raises
    ------
    ValueError
        Sectors that are not evenly spaced (a LaserScan's rays are), or not the IR beams.
    """
    angles = np.array(profile.scan.angles_deg, dtype=np.float64)
    if ir_angles_deg is not None and not np.array_equal(
            angles, np.asarray(ir_angles_deg, dtype=np.float64)):
        raise ValueError(f'scan.sectors angle_deg {angles.tolist()} of the profile are not '
                         f'the IR beams sensors.ir_angles_deg {list(ir_angles_deg)}')
    steps = np.diff(angles)
    if len(steps) and not np.allclose(steps, steps[0], rtol=0.0, atol=1e-9):
        raise ValueError(f'scan.sectors angle_deg {angles.tolist()} are not evenly spaced: a '
                         'LaserScan has one angle_increment')
    offset = 0.0 if profile.scan.from_surface else profile.body.radius
    return ScanLayout(math.radians(angles[0] - profile.scan.yaw_deg),
                      math.radians(steps[0]) if len(steps) else 0.0, len(angles),
                      profile.scan.range_max + offset, offset)


def scan_msg(ir: ArrayLike, layout: ScanLayout, t: float, frame: str) -> LaserScan:
    """The IR readings ``ir`` (shape (count,), [m] from the body's surface, in the order of
    the sectors) as a LaserScan stamped ``t`` [s]."""
    ranges = np.asarray(ir, dtype=np.float64).reshape(-1) + layout.offset
    if ranges.size != layout.count:
        raise ValueError(f'{ranges.size} IR readings for a scan of {layout.count} rays')
    msg = LaserScan()
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.angle_min, msg.angle_max = float(layout.angle_min), float(layout.angle_max)
    msg.angle_increment = float(layout.angle_increment)
    msg.range_min, msg.range_max = 0.0, float(layout.range_max)
    msg.ranges = [float(r) for r in ranges]
    return msg


def image_msg(rgb: np.ndarray, t: float, frame: str) -> Image:
    """An ``rgb8`` Image of ``rgb`` (shape (H, W, 3), uint8) stamped ``t`` [s]."""
    a = np.ascontiguousarray(rgb, dtype=np.uint8)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f'an rgb8 image is of shape (H, W, 3), got {a.shape}')
    msg = Image(height=a.shape[0], width=a.shape[1], encoding='rgb8', is_bigendian=0,
                step=3 * a.shape[1])
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.data = a.tobytes()
    return msg


def camera_info_msg(camera: Pinhole, t: float, frame: str) -> CameraInfo:
    """The intrinsics of a pinhole camera (no distortion: ``plumb_bob``, ``d`` = 0)."""
    msg = CameraInfo(width=camera.width, height=camera.height, distortion_model='plumb_bob')
    msg.header.stamp, msg.header.frame_id = to_time(t), frame
    msg.d = [0.0] * 5
    msg.k = [camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


class StandardTopics:
    """The publishers of ``image_raw``, ``camera_info`` (a pinhole profile) and ``scan`` on
    ``node`` (module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
        The simulator node.
    arena : Arena
        The arena it simulates (rendered with :meth:`Scene.from_arena`).
    profile_name : str
        A robot profile (``cr``: the simulator's robot), or a profile file.
    sensors : SensorParams, optional
        The simulator's sensors: the rendered targets are cut at their ``camera_range`` and
        ``destination_range`` (default: :class:`RenderParams`'), and the profile's sectors
        must be their ``ir_angles_deg``.
    frame : str
        ``header.frame_id`` of every message: the robot's body frame.

    Raises
    ------
    ConfigError
        The profile does not load (naming its key and range).
    ValueError
        Its scan sectors cannot carry the IR beams (:func:`scan_layout`).
    """

    def __init__(self, node: Node, arena: Arena, profile_name: str, *,
                 sensors: SensorParams | None = None, frame: str = 'base_link') -> None:
        self.profile = load_profile(profile_name)
        self.camera = self.profile.camera.camera_model()
        params = RenderParams() if sensors is None else RenderParams(
            camera_range=sensors.camera_range, destination_range=sensors.destination_range)
        self.scene = Scene.from_arena(arena, params)
        self.layout = scan_layout(self.profile,
                                  None if sensors is None else sensors.ir_angles_deg)
        self.frame = frame
        self.pub_image = node.create_publisher(Image, 'image_raw', IMAGE_QOS)
        self.pub_info = (node.create_publisher(CameraInfo, 'camera_info', IMAGE_QOS)
                         if isinstance(self.camera, Pinhole) else None)
        self.pub_scan = node.create_publisher(LaserScan, 'scan', STREAM_DEPTH)

    def messages(self, t: float, pose: ArrayLike, ir: ArrayLike
                 ) -> list[tuple[Publisher, Image | CameraInfo | LaserScan]]:
        """The messages of one reading instant, for the topics that have a subscriber.

        Parameters
        ----------
        t : float
            Sim time of the reading [s].
        pose : array_like, shape (3,)
            True pose ``(x, y, theta)`` [m, m, rad].
        ir : array_like, shape (n_ir,)
            The IR readings of that instant [m] (``Observation.ir``).

        Returns
        -------
        list of (Publisher, message)
            In the order image, camera_info, scan.
        """
        out: list[tuple[Publisher, Image | CameraInfo | LaserScan]] = []
        if self.pub_image.get_subscription_count():
            out.append((self.pub_image, image_msg(render(self.scene, self.camera, pose), t,
                                                  self.frame)))
        if self.pub_info is not None and self.pub_info.get_subscription_count():
            out.append((self.pub_info, camera_info_msg(self.camera, t, self.frame)))
        if self.pub_scan.get_subscription_count():
            out.append((self.pub_scan, scan_msg(ir, self.layout, t, self.frame)))
        return out

    def publish(self, t: float, pose: ArrayLike, ir: ArrayLike) -> None:
        """Publish :meth:`messages` of one reading instant."""
        for pub, msg in self.messages(t, pose, ir):
            pub.publish(msg)
