"""The robot interface's ROS endpoints, created once for every node that is the robot.

The simulator node and the real robot's bridge (cr_bridge) publish the same topics with the
same types and QoS and take the same inputs (docs/robot.md#topics): this is the one place where
they are declared.
"""

from __future__ import annotations

from clis_base.params import ConfigError
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile

from cr_sim import conversions as conv
from cr_sim.core.arena import Arena

__all__ = ['open_robot_interface', 'parse_counts', 'unmatched']


def open_robot_interface(node: Node, arena: Arena, map_frame: str, cmd_vel_stamped: bool,
                         wait_for_learner: bool, command: str = 'cmd_vel', *,
                         publish_clock: bool = True, publish_camera: bool = True) -> None:
    """Create the interface's publishers on ``node`` (``node.pub_clock``, ``pub_ir``,
    ``pub_ir_ranges``, ``pub_camera``, ``pub_wheels``, ``pub_reward``, ``pub_episode``,
    ``pub_odom``, ``pub_arena``, ``pub_markers``), subscribe the ``command`` topic (``cmd_vel``, or
    ``wheels_cmd``: the wheels as decided, sensor_msgs/JointState) to ``node._on_cmd``
    (``node.sub_cmd``), serve ``reset`` with ``node._on_reset``, follow ``learner/progress``
    into ``node.gate.on_progress`` if ``wait_for_learner``, and publish the arena's markers
    (latched) in ``map_frame``."""
    from std_srvs.srv import Trigger
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.pub_clock = node.create_publisher(conv.Clock, '/clock', 10) if publish_clock else None
    node.pub_ir = node.create_publisher(conv.LaserScan, 'ir', conv.STREAM_DEPTH)
    node.pub_ir_ranges = node.create_publisher(conv.JointState, 'ir_ranges', conv.STREAM_DEPTH)
    node.pub_camera = (node.create_publisher(conv.JointState, 'camera', conv.STREAM_DEPTH)
                       if publish_camera else None)
    node.pub_wheels = node.create_publisher(conv.JointState, 'wheels', conv.STREAM_DEPTH)
    node.pub_reward = node.create_publisher(conv.Vector3Stamped, 'reward', conv.STREAM_DEPTH)
    node.pub_episode = node.create_publisher(
        conv.DiagnosticArray, 'episode',
        QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node.pub_odom = node.create_publisher(conv.Odometry, 'odom', conv.STREAM_DEPTH)
    node.pub_arena = node.create_publisher(conv.MarkerArray, 'arena', latched)
    node.pub_markers = node.create_publisher(conv.MarkerArray, 'markers', 10)
    if command == 'wheels_cmd':
        node.sub_cmd = node.create_subscription(conv.JointState, 'wheels_cmd', node._on_cmd, 10)
    else:
        cmd_type = conv.TwistStamped if cmd_vel_stamped else conv.Twist
        node.sub_cmd = node.create_subscription(cmd_type, 'cmd_vel', node._on_cmd, 10)
    node.create_service(Trigger, 'reset', node._on_reset)
    if wait_for_learner:
        node.create_subscription(conv.DiagnosticArray, 'learner/progress',
                                 lambda msg: _on_progress(node, msg),
                                 QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node.pub_arena.publish(conv.arena_markers(
        arena.wall_boxes(), arena.short_boxes(), arena.tall_boxes(),
        [(lm.x, lm.y) for lm in arena.landmarks],
        (arena.destination.x, arena.destination.y, arena.destination.goal_radius), map_frame))


def _on_progress(node: Node, msg) -> None:
    """The learner's progress (episode learned, parameters' version, what the next start is
    to carry) to the node's gate."""
    _, _, values = conv.event_from_msg(msg)
    try:
        node.gate.on_progress(int(values['episode']), int(values['version']), values)
    except (KeyError, ValueError):
        node.get_logger().warning(f'unreadable learner progress: {values}')


def parse_counts(entries: tuple[str, ...], where: str) -> dict[str, int]:
    """``('TOPIC:COUNT', ...)`` -> ``{TOPIC: COUNT}`` ('' entries ignored); a bad entry raises
    :class:`ConfigError` naming ``where[k]`` and the format."""
    counts = {}
    for k, entry in enumerate(entries):
        if not entry:
            continue
        topic, _, n = entry.rpartition(':')
        if not topic or not n.isdigit():
            raise ConfigError(f"{where}[{k}] = {entry!r} must be 'TOPIC:COUNT' (e.g. "
                              "'reward:1'), or '' for none")
        counts[topic] = int(n)
    return counts


def unmatched(node: Node, counts: dict[str, int]) -> list[str]:
    """Which of ``counts`` (topic -> how many) ``node`` has not matched yet: for a topic it
    publishes, its subscriptions; for one it subscribes to, its publishers. E.g. ``['reward:
    0 of 1']``; a topic the node neither publishes nor subscribes to is never matched."""
    matched: dict[str, int] = {}
    for pub in node.publishers:
        matched[pub.topic_name] = matched.get(pub.topic_name, 0) + pub.get_subscription_count()
    for sub in node.subscriptions:
        n = node.count_publishers(sub.topic_name)
        matched[sub.topic_name] = max(matched.get(sub.topic_name, 0), n)
    out = []
    for topic, want in counts.items():
        have = matched.get(node.resolve_topic_name(topic), 0)
        if have < want:
            out.append(f'{topic}: {have} of {want}')
    return out
