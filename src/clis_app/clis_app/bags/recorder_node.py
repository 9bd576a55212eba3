"""``ros2 run clis_app recorder``: record topics of the graph into a bag (MCAP, rosbag2).

Subscribes *raw* (the serialized CDR bytes, never decoded) to every topic of the CLIS graph
(:data:`GRAPH_TOPICS`, subscribed at start so that nothing published after the recorder is up
is missed) and to every other topic that appears (looked for every
``recorder.discovery_period`` s; ``/rosout`` and ``/parameter_events`` excepted), or only to
``recorder.topics`` (comma-separated) if given. Each message is written with its receive and
publish stamps from the message info (wall clock, ns since the epoch); a topic's channel
carries the QoS its publishers offer and its type hash (``get_publishers_info_by_topic``).

No loss at the graph's rates: the subscriptions stay out of the executor and a
``recorder.poll_period`` timer takes every waiting message at once (rclpy's executor costs about
100 us per message, a take about 3 us); the queues are ``recorder.depth`` deep; and the process
uses ``config/fastdds_recorder.xml`` (UDP loopback, 4 MiB receive buffer: samples wait in the
kernel while the recorder waits for a core; over shared memory a starved recorder lost them).

The bag is the folder ``recorder.path`` (``NAME_0.mcap`` + ``metadata.yaml``, see
:mod:`clis_app.bags.mcap`). Every ``recorder.flush_interval`` s of wall time the open chunk is
written out and ``metadata.yaml`` refreshed, so a crash loses at most that interval; Ctrl-C
(SIGINT/SIGTERM) finishes the file (summary, indexes). ``recorder.on_exists: number`` records
into ``PATH.1``, ``PATH.2``... when PATH holds a bag already (a restarted recorder under
``clis run``); ``fail`` stops with exit code 2.
"""

from __future__ import annotations

import importlib
from pathlib import Path
import time
from typing import Any

from clis_base.params import ConfigError, dataclass, param
from clis_base.ros.graph_node import GraphNode, run_node
from clis_learner.core.config import ClisParams, params_hash
from clis_modules.core.plugin import parse_condition
from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidHandle
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from clis_app.bags.mcap import BagError, BagWriter, qos_dict
from clis_app.graph.ros_env import RECORDER_PROFILE_NAME, use_profile

__all__ = ['RecorderParams', 'RecorderNode', 'GRAPH_TOPICS', 'LATCHED_TOPICS', 'graph_topics',
           'latched_topics', 'qos_to_dict',
           'qos_from_dict', 'message_class', 'main']

#: Topics of the graph and their types (relative names; docs/graph.md, docs/robot.md), but
#: those of the module instances, which depend on the condition (:func:`graph_topics`).
GRAPH_TOPICS = {
    '/clock': 'rosgraph_msgs/msg/Clock',
    'ir': 'sensor_msgs/msg/LaserScan',
    'ir_ranges': 'sensor_msgs/msg/JointState',
    'camera': 'sensor_msgs/msg/JointState',
    'wheels': 'sensor_msgs/msg/JointState',
    'reward': 'geometry_msgs/msg/Vector3Stamped',
    'episode': 'diagnostic_msgs/msg/DiagnosticArray',
    'odom': 'nav_msgs/msg/Odometry',
    'arena': 'visualization_msgs/msg/MarkerArray',
    'markers': 'visualization_msgs/msg/MarkerArray',
    'cmd_vel': 'geometry_msgs/msg/TwistStamped',
    'wheels_cmd': 'sensor_msgs/msg/JointState',
    'arbiter/selection': 'sensor_msgs/msg/JointState',
    'arbiter/action': 'sensor_msgs/msg/JointState',
    'learner/progress': 'diagnostic_msgs/msg/DiagnosticArray',
}
#: Topics published transient local (their last messages reach a late subscriber), but the
#: module instances' ``params`` (:func:`latched_topics`).
LATCHED_TOPICS = frozenset({'episode', 'arena', 'learner/progress'})


def graph_topics(condition: str, clis: Any) -> dict[str, str]:
    """:data:`GRAPH_TOPICS` with the topics of ``condition``'s module instances, in its order
    (``proposal``, ``params``, ``observation`` when there are several, and what each plug-in
    declares in its ``topics``)."""
    topics = dict(GRAPH_TOPICS)
    modules = parse_condition(condition).modules
    for name in modules:
        plugin = clis.module(name)[0]
        topics[f'{name}/proposal'] = topics[f'{name}/params'] = 'sensor_msgs/msg/JointState'
        if len(modules) > 1:
            topics[f'{name}/observation'] = 'sensor_msgs/msg/JointState'
        topics.update({f'{name}/{t}': typ for t, typ in plugin.topics.items()})
    return topics


def latched_topics(condition: str) -> frozenset:
    """:data:`LATCHED_TOPICS` with the ``params`` of ``condition``'s module instances."""
    return LATCHED_TOPICS | {f'{name}/params' for name in parse_condition(condition).modules}


#: Never recorded unless asked for by name.
EXCLUDED = frozenset({'/rosout', '/parameter_events'})


@dataclass(frozen=True)
class RecorderParams:
    """Settings of the recorder (``config/graph.yaml``, section ``recorder``)."""

    path: str = param(doc="bag folder to write; '' = bags/record-DATE")
    topics: str = param(doc="comma-separated topics to record; '' = every topic of the graph")
    on_exists: str = param(choices=('fail', 'number'),
                           doc="PATH holds a bag: 'fail' (exit 2) or record into PATH.1, ...")
    flush_interval: float = param(0.05, 60.0, doc='wall seconds between chunk flushes')
    discovery_period: float = param(0.01, 10.0, doc='wall seconds between looks for new topics')
    depth: int = param(1, 1000000, doc='queue depth of each subscription (no loss in bursts)')
    poll_period: float = param(0.0005, 0.5, doc='wall seconds between takes of the queues')
    compression: str = param(choices=('zstd', 'lz4', 'none'), doc='chunk compression')
    chunk_size: int = param(4096, 2**30, doc='uncompressed bytes per chunk')
    wait_for: str = param(doc="comma-separated topics whose publishers are matched before the "
                              "episode events are subscribed to ('' = none; clis run: the "
                              "modules' and the arbiter's, as the simulator's first episode "
                              'waits for that subscription)')
    wait_timeout: float = param(0.0, 3600.0, doc='wall seconds to wait for them at most')


def message_class(msg_type: str) -> type:
    """The Python class of ``pkg/msg/Type`` (ImportError / AttributeError if absent)."""
    pkg, ns, name = msg_type.split('/')
    return getattr(importlib.import_module(f'{pkg}.{ns}'), name)


def _policy_name(value: Any) -> str:
    return value.name.lower() if hasattr(value, 'name') else str(value).lower()


def qos_to_dict(qos: QoSProfile) -> dict[str, Any]:
    """An rclpy QoS profile as one map of ``offered_qos_profiles``."""
    return qos_dict(_policy_name(qos.history), int(qos.depth), _policy_name(qos.reliability),
                    _policy_name(qos.durability), qos.deadline.nanoseconds,
                    qos.lifespan.nanoseconds, _policy_name(qos.liveliness),
                    qos.liveliness_lease_duration.nanoseconds,
                    bool(qos.avoid_ros_namespace_conventions))


def qos_from_dict(d: dict[str, Any], min_depth: int = 10) -> QoSProfile:
    """A publisher profile from a recorded QoS map: its reliability and durability, keep-last
    with the recorded depth (at least ``min_depth`` when it is unknown, 0)."""
    depth = int(d.get('depth', 0) or 0)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth if depth > 0 else min_depth,
        reliability=(ReliabilityPolicy.BEST_EFFORT if d.get('reliability') == 'best_effort'
                     else ReliabilityPolicy.RELIABLE),
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if d.get('durability') == 'transient_local'
                    else DurabilityPolicy.VOLATILE),
        liveliness=LivelinessPolicy.AUTOMATIC)


class _Polled(CallbackGroup):
    """A callback group the executor never runs: its subscriptions stay out of the wait set
    and :meth:`RecorderNode._poll` takes their messages."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


class RecorderNode(GraphNode):
    """Raw subscriptions into a :class:`~clis_app.bags.mcap.BagWriter` (module docstring)."""

    control_path = False                    # records: never real-time

    def __init__(self) -> None:
        super().__init__('recorder', 'recorder', RecorderParams, clis_cls=ClisParams,
                         check_condition=parse_condition)
        path = Path(self.cfg.path or f'bags/record-{time.strftime("%Y%m%d-%H%M%S")}')
        path = self._free_path(path)
        custom = {'condition': self.graph.condition, 'seed': str(self.graph.seed),
                  'arena_file': self.graph.arena_file, 'params_hash': params_hash(self.clis)}
        try:
            self.writer = BagWriter(path, chunk_size=self.cfg.chunk_size,
                                    compression=self.cfg.compression, custom_data=custom)
        except (BagError, OSError) as exc:
            raise ConfigError(f'recorder.path: {exc}') from None
        self.only = [self._absolute(t) for t in self.cfg.topics.split(',') if t.strip()]
        self.subs: dict[str, tuple[str, Any]] = {}       # topic -> (type, subscription)
        self._polled = _Polled()
        self.closed = False
        wanted = {self._absolute(t): typ
                  for t, typ in graph_topics(self.graph.condition, self.clis).items()}
        self.latched_names = latched_topics(self.graph.condition)
        if self.only:
            wanted = {t: wanted[t] for t in self.only if t in wanted}
        # the episode topic first: clis run starts the simulator once it is subscribed; with
        # recorder.wait_for, last, once the publishers of those topics are matched (a
        # publisher's first messages go out before DDS has matched it with the recorder: under
        # load a bag once missed a module's first 58 proposals)
        self.episode = self._absolute('episode')
        self.waiting = [self._absolute(t) for t in self.cfg.wait_for.split(',') if t.strip()]
        self.wait_deadline = time.monotonic() + self.cfg.wait_timeout
        if self.episode not in wanted:
            self.waiting = []
        for topic in sorted(wanted, key=lambda t: t != self.episode):
            if not (self.waiting and topic == self.episode):
                self._subscribe(topic, wanted[topic])
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if self.waiting:
            self._wait_timer = self.create_timer(0.02, lambda: self._end_wait(
                wanted[self.episode]), clock=steady)
        self.create_timer(self.cfg.discovery_period, self._discover, clock=steady)
        self.create_timer(self.cfg.flush_interval, self._flush, clock=steady)
        self.create_timer(self.cfg.poll_period, self._poll, clock=steady)
        self.get_logger().info(
            f'recording into {self.writer.path} '
            f'({", ".join(self.only) if self.only else "every topic of the graph"})')

    def _end_wait(self, episode_type: str) -> None:
        """Subscribe to the episode events once every topic of ``recorder.wait_for`` has a
        matched publisher (or after ``recorder.wait_timeout``, saying which has none)."""
        missing = [t for t in self.waiting
                   if t not in self.subs or not self.subs[t][1].get_publisher_count()]
        if missing and time.monotonic() < self.wait_deadline:
            return
        if missing:
            self.get_logger().warning('no publisher matched within recorder.wait_timeout: '
                                      + ', '.join(missing))
        self.waiting = []
        self.destroy_timer(self._wait_timer)
        self._subscribe(self.episode, episode_type)

    def _free_path(self, path: Path) -> Path:
        def taken(p: Path) -> bool:
            return (p / 'metadata.yaml').exists() or any(p.glob('*.mcap'))

        if not taken(path) or self.cfg.on_exists == 'fail':
            return path
        k = 1
        while taken(path.with_name(f'{path.name}.{k}')):
            k += 1
        return path.with_name(f'{path.name}.{k}')

    def _absolute(self, topic: str) -> str:
        return self.resolve_topic_name(topic.strip())

    def _subscribe(self, topic: str, msg_type: str) -> None:
        try:
            cls = message_class(msg_type)
        except (AttributeError, ImportError, ValueError) as exc:
            self.get_logger().warning(f'{topic}: type {msg_type} not available ({exc}): '
                                      'not recorded', once=True)
            return
        old = self.subs.pop(topic, None)
        if old is not None:
            self.destroy_subscription(old[1])
        latched = any(topic == self._absolute(t) for t in self.latched_names)
        offered = [i.qos_profile for i in self.get_publishers_info_by_topic(topic)]
        if offered:                                     # adapt to the publishers (rosbag2)
            latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
        reliable = not any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in offered)
        qos = QoSProfile(
            depth=self.cfg.depth,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                        else DurabilityPolicy.VOLATILE))
        sub = self.create_subscription(cls, topic, lambda *_: None, qos, raw=True,
                                       callback_group=self._polled)
        self.subs[topic] = (msg_type, sub)

    def _poll(self) -> None:
        """Take every message waiting on any subscription and write them in receive order.

        The subscriptions are outside the executor (:class:`_Polled`): rclpy's executor costs
        ~100 us per message, a take ~3 us; each subscription's DDS queue (``recorder.depth``)
        holds what arrives between two polls."""
        if self.closed:
            return
        batch = []
        for name, (typ, sub) in self.subs.items():
            try:
                with sub.handle:
                    while (got := sub.handle.take_message(sub.msg_type, True)) is not None:
                        batch.append((got[1], name, typ, got[0]))
            except InvalidHandle:                        # destroyed meanwhile (resubscribed)
                continue
        if not batch:
            return
        batch.sort(key=lambda b: b[0].get('received_timestamp') or 0)
        for info, name, typ, data in batch:
            if name not in self.writer.topics:
                self._add_channel(name, typ)
            recv = info.get('received_timestamp') or time.time_ns()
            self.writer.write(name, data, recv, info.get('source_timestamp') or recv,
                              int(info.get('publication_sequence_number') or 0))

    def _add_channel(self, topic: str, msg_type: str) -> None:
        infos = [i for i in self.get_publishers_info_by_topic(topic) if i.topic_type == msg_type]
        hashes = [str(i.topic_type_hash) for i in infos]
        hash_ = next((h for h in hashes if h.startswith('RIHS')), '')   # else the type's own
        profiles = [qos_to_dict(i.qos_profile) for i in infos]
        if not profiles:                                # gone already: what we asked for
            profiles = [qos_to_dict(self.subs[topic][1].qos_profile)]
        self.writer.add_topic(topic, msg_type, profiles, hash_)

    def _discover(self) -> None:
        if self.closed:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in EXCLUDED and topic not in self.only:
                continue
            if self.only and topic not in self.only:
                continue
            msg_type = types[0]
            if topic in self.subs and self.subs[topic][0] == msg_type:
                continue
            if self.waiting and topic == self.episode:     # subscribed once they are matched
                continue
            if topic in self.writer.topics:             # recorded with another type already
                continue
            self._subscribe(topic, msg_type)

    def _flush(self) -> None:
        if not self.closed:
            self.writer.flush()

    def close(self) -> None:
        """Finish the bag (called on Ctrl-C / SIGTERM by :func:`run_node`)."""
        if self.closed:
            return
        self._poll()                                    # what arrived since the last poll
        self.closed = True
        self.writer.close()
        counts = ', '.join(f'{t.name} {t.count}' for t in self.writer.topics.values())
        print(f'recorder: {self.writer.message_count} messages in {self.writer.path}'
              f'{": " + counts if counts else ""}', flush=True)


def use_recorder_profile() -> None:
    """Load ``config/fastdds_recorder.xml`` (UDP loopback with a large receive buffer: no
    loss when this process waits for a core) instead of the project's loopback profile; a
    profile of the user's own is kept."""
    use_profile(RECORDER_PROFILE_NAME)


def main(args: list[str] | None = None) -> None:
    use_recorder_profile()
    run_node(RecorderNode, 'recorder', __doc__, args)


if __name__ == '__main__':
    main()
