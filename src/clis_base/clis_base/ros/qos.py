"""The QoS of the graph's streams: one home for the depth and the proposals' liveliness."""

from __future__ import annotations

from rclpy.duration import Duration
from rclpy.qos import LivelinessPolicy, QoSProfile

__all__ = ['STREAM_DEPTH', 'proposal_qos']

#: History depth (reliable, keep-last) of every stream of the robot interface and of the CLIS
#: graph, at the publisher and at the subscribers that must see every message (the learner,
#: the place module's odometry): a reader that falls this many messages behind the publisher
#: (a loaded machine, a recorder, ``ros2 topic echo``) still loses none. With depth 10 the
#: learner lost rewards and the place module wheel readings when a core was busy elsewhere.
STREAM_DEPTH = 1000


def proposal_qos(lease: float, depth: int = STREAM_DEPTH) -> QoSProfile:
    """QoS of a module's proposals, publisher and arbiter: automatic liveliness with a lease of
    ``lease`` wall seconds, so that the arbiter notices a killed module within it.

    DDS matches a publisher only if it offers a lease no longer than the one requested: a
    hand-made publisher of proposals must offer it too (the default, infinite, does not match).
    """
    return QoSProfile(depth=depth, liveliness=LivelinessPolicy.AUTOMATIC,
                      liveliness_lease_duration=Duration(seconds=lease))
