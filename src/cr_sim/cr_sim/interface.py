"""The robot interface's ROS endpoints, created once for every node that is the robot.

The simulator node and the real robot's bridge (cr_bridge) publish the same topics with the
same types and QoS and take the same inputs (README, topic table): this is the one place where
they are declared.
"""

from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile

from cr_sim import conversions as conv
from cr_sim.core.arena import Arena

__all__ = ['open_robot_interface']


def open_robot_interface(node: Node, arena: Arena, map_frame: str, cmd_vel_stamped: bool,
                         wait_for_learner: bool) -> None:
    """Create the interface's publishers on ``node`` (``node.pub_clock``, ``pub_ir``,
    ``pub_camera``, ``pub_wheels``, ``pub_reward``, ``pub_episode``, ``pub_odom``,
    ``pub_arena``, ``pub_markers``), subscribe ``cmd_vel`` to ``node._on_cmd``
    (``node.sub_cmd``), serve ``reset`` with ``node._on_reset``, follow ``learner/progress``
    with ``node._on_progress`` if ``wait_for_learner``, and publish the arena's markers
    (latched) in ``map_frame``."""
    from std_srvs.srv import Trigger
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.pub_clock = node.create_publisher(conv.Clock, '/clock', 10)
    node.pub_ir = node.create_publisher(conv.LaserScan, 'ir', conv.STREAM_DEPTH)
    node.pub_camera = node.create_publisher(conv.JointState, 'camera', conv.STREAM_DEPTH)
    node.pub_wheels = node.create_publisher(conv.JointState, 'wheels', conv.STREAM_DEPTH)
    node.pub_reward = node.create_publisher(conv.Vector3Stamped, 'reward', conv.STREAM_DEPTH)
    node.pub_episode = node.create_publisher(
        conv.DiagnosticArray, 'episode',
        QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node.pub_odom = node.create_publisher(conv.Odometry, 'odom', conv.STREAM_DEPTH)
    node.pub_arena = node.create_publisher(conv.MarkerArray, 'arena', latched)
    node.pub_markers = node.create_publisher(conv.MarkerArray, 'markers', 10)
    cmd_type = conv.TwistStamped if cmd_vel_stamped else conv.Twist
    node.sub_cmd = node.create_subscription(cmd_type, 'cmd_vel', node._on_cmd, 10)
    node.create_service(Trigger, 'reset', node._on_reset)
    if wait_for_learner:
        node.create_subscription(conv.DiagnosticArray, 'learner/progress', node._on_progress,
                                 QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node.pub_arena.publish(conv.arena_markers(
        arena.wall_boxes(), arena.short_boxes(), arena.tall_boxes(),
        [(lm.x, lm.y) for lm in arena.landmarks],
        (arena.destination.x, arena.destination.y, arena.destination.goal_radius), map_frame))
