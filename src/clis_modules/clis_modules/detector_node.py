"""``ros2 run clis_modules detector``: a robot's camera image as the ``camera`` topic.

Finds the destination and each landmark by colour in the frames of any robot's camera and
publishes what the simulator's omni-camera gives (docs/robot.md#topics), so that the modules
run on a robot through its standard topics. The robot is described by its profile
(``config/robots/NAME.yaml``, parameter ``profile``): the names of its topics, its camera
(a forward pinhole or a panoramic strip, field of view, mounting yaw) and the colour of each
target.

Subscribes (sensor-data QoS: best effort, so reliable and best-effort publishers both match):

* the profile's ``topics.image`` (sensor_msgs/Image, ``rgb8``, ``bgr8`` or ``rgba8``);
* its ``topics.camera_info`` (sensor_msgs/CameraInfo), if it has one and the camera is a
  pinhole: once it arrives its ``k`` replaces the profile's field of view for frames of its
  ``width`` x ``height`` (distortion is not corrected: ``d`` is ignored).

Both names are resolved absolute under the profile's ``topics.namespace`` (``/image_raw``,
``/robot1/image_raw``), so that the node itself may sit in a namespace of the CLIS graph;
``--ros-args -r /image_raw:=/front/image`` remaps them.

Publishes, for every frame:

* ``camera`` (sensor_msgs/JointState, the simulator's layout, frame ``base_link``, stamped
  with the image's stamp): ``name`` = ``destination`` and the landmarks, ``position`` =
  bearing (rad, relative to the heading, counter-clockwise positive, in (-pi, pi]), ``effort``
  = the blob's apparent angular width (rad, the angle between its outer column edges); NaN
  for a target not seen (no blob of at least ``camera.min_blob_px`` pixels of its colour);
* ``detector/overlay`` (sensor_msgs/Image, ``rgb8``, the image's stamp and frame): the frame
  with a rectangle round each blob in its target's colour, for Foxglove; built only while
  someone subscribes, or for every frame with ``overlay`` true.

The model per frame is :mod:`clis_modules.core.blobs` (HSV colour ranges, 8-connected
components, the largest one per target) through :class:`clis_modules.core.detector.Detector`.
A frame that cannot be read (an unsupported encoding, a truncated buffer) is dropped with one
error line, said once per encoding (or per kind of fault); the node keeps running.

Parameters: ``profile`` (a name of ``config/robots``, or a profile file; default ``cr``) and
``overlay`` (default true), e.g. ``--ros-args -p profile:=turtlebot4``.
"""

from __future__ import annotations

from clis_base.params import build, dataclass, param
from clis_base.ros.executor import make_executor
from clis_base.ros.process import start_node
from clis_base.ros.profiling import start_profile, stop_profile
from clis_base.ros.qos import STREAM_DEPTH
from clis_base.ros.ros_params import declare_from_config, print_help_and_exit_if_asked
from cr_sim.core.profile import RobotProfile, Topics, load_profile
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, JointState

from clis_modules.core.blobs import NAMED_RANGES, ColourRange, check_encoding
from clis_modules.core.detector import Detector
from clis_modules.image_conversions import camera_info_k, camera_msg, image_array, image_msg

__all__ = ['DetectorParams', 'DEFAULTS', 'BASE_FRAME', 'OVERLAY_TOPIC', 'absolute_topic',
           'detector_of', 'DetectorNode', 'main']

#: Frame of the ``camera`` messages: bearings are relative to the robot's heading.
BASE_FRAME = 'base_link'
#: The overlay's topic (relative).
OVERLAY_TOPIC = 'detector/overlay'


@dataclass(frozen=True)
class DetectorParams:
    """The detector node's parameters (``-p KEY:=VALUE``)."""

    profile: str = param(doc='robot profile: a name of config/robots (cr, turtlebot4, husky) '
                         'or a profile file')
    overlay: bool = param(doc='publish detector/overlay for every frame; false: only while '
                          'someone subscribes')


#: The parameters' defaults.
DEFAULTS = {'profile': 'cr', 'overlay': True}


def absolute_topic(topics: Topics, key: str) -> str:
    """Topic ``key`` of a profile (``'image'``, ``'camera_info'``) as an absolute name under
    its namespace: ``image_raw`` -> ``/image_raw``, or ``/robot1/image_raw`` in namespace
    ``robot1``; an absolute or private name as written; ``''`` for none."""
    name = topics.resolved(key)
    return name if not name or name.startswith(('/', '~')) else '/' + name


def detector_of(profile: RobotProfile) -> Detector:
    """The detector of a profile's camera (``camera.camera_model()``, ``camera.min_blob_px``)
    and colours (a colour name: :data:`~clis_modules.core.blobs.NAMED_RANGES`; an explicit
    HSV box as given)."""
    targets = {}
    for name in ('destination', *profile.colours.landmark_names):
        spec = profile.colours.of(name)
        if spec.hsv is None:
            targets[name] = NAMED_RANGES[spec.name]
        else:
            h = spec.hsv
            targets[name] = ColourRange(h.hue_lo, h.hue_hi, h.sat_lo, h.sat_hi, h.val_lo,
                                        h.val_hi)
    return Detector(profile.camera.camera_model(), targets, profile.camera.min_blob_px)


class DetectorNode(Node):
    """Thin glue: Image (+ CameraInfo) -> :class:`~clis_modules.core.detector.Detector` ->
    ``camera`` (+ ``detector/overlay``)."""

    def __init__(self) -> None:
        super().__init__('detector')
        self.cfg = build(DetectorParams, declare_from_config(self, DEFAULTS))
        self.profile = load_profile(self.cfg.profile)
        self.core = detector_of(self.profile)
        image_topic = absolute_topic(self.profile.topics, 'image')
        info = absolute_topic(self.profile.topics, 'camera_info')
        pinhole = self.profile.camera.model == 'pinhole'
        self._said: set[tuple[str, str]] = set()
        self.pub_camera = self.create_publisher(JointState, 'camera', STREAM_DEPTH)
        self.pub_overlay = self.create_publisher(
            Image, OVERLAY_TOPIC, QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE))
        sub = self.create_subscription(Image, image_topic, self._on_image,
                                       qos_profile_sensor_data)
        self.image_topic = sub.topic_name             # as remapped
        self.info_topic = ''
        if info and pinhole:
            sub = self.create_subscription(CameraInfo, info, self._on_info,
                                           qos_profile_sensor_data)
            self.info_topic = sub.topic_name
        model = self.core.nominal
        self.get_logger().info(
            f'profile {self.cfg.profile}: {self.profile.camera.model} camera '
            f'{model.width} x {model.height} px on {self.image_topic}'
            + (f' (intrinsics from {self.info_topic})' if self.info_topic else '')
            + f'; targets {", ".join(self.core.names)}')

    def _once(self, kind: str, key: str, text: str) -> None:
        """Log ``text`` as an error the first time ``(kind, key)`` happens."""
        if (kind, key) not in self._said:
            self._said.add((kind, key))
            self.get_logger().error(text)

    def _on_info(self, msg: CameraInfo) -> None:
        width, height, k = camera_info_k(msg)
        try:
            if self.core.set_intrinsics(width, height, k):
                self.get_logger().info(f'intrinsics from {self.info_topic}: {width} x {height} '
                                       f'px, fx {k[0]:g}, cx {k[2]:g}, fy {k[4]:g}, cy {k[5]:g}')
        except ValueError as exc:
            self._once('info', str(exc), f'ignored camera_info on {self.info_topic}: {exc}; '
                       'the camera model in force is kept')

    def _on_image(self, msg: Image) -> None:
        try:
            check_encoding(msg.encoding)
        except ValueError as exc:
            self._once('encoding', msg.encoding, f'dropped a frame of {self.image_topic}: {exc}')
            return
        try:
            image = image_array(msg)
            found = self.core.frame(image, msg.encoding)
        except ValueError as exc:              # a buffer or a size no model takes
            self._once('frame', str(exc), f'dropped a frame of {self.image_topic}: {exc}')
            return
        self.pub_camera.publish(camera_msg(found.names, found.bearings, found.widths,
                                           msg.header.stamp, BASE_FRAME))
        if self.cfg.overlay or self.pub_overlay.get_subscription_count():
            self.pub_overlay.publish(image_msg(self.core.overlay(image, msg.encoding, found),
                                               msg.header.stamp, msg.header.frame_id))


def main(args: list[str] | None = None) -> None:
    print_help_and_exit_if_asked(__doc__, args)
    node, _ = start_node('detector', DetectorNode, args, flag_signals=False)
    executor = make_executor('lean', node.get_logger())
    executor.add_node(node)
    profiler = start_profile()
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        stop_profile(profiler, 'detector')
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
