"""``ros2 run clis_app foxglove``: a live view of the running graph in Foxglove.

Serves the graph's topics on a Foxglove WebSocket (the Foxglove WebSocket protocol v1, which
the ``foxglove-sdk`` package that serves it names ``foxglove.sdk.v1``, formerly
``foxglove.websocket.v1``) bound to ``127.0.0.1:foxglove.port`` (default 8765; never another
interface: from another machine, tunnel it, e.g. ``ssh -L 8765:127.0.0.1:8765 HOST``). Open it
in the Foxglove app (Open connection, ``ws://127.0.0.1:8765``) with the layout
``config/foxglove_layout.json``: docs/foxglove.md.

Each topic is one channel with the bag's schema (encoding ``ros2msg``, named ``pkg/msg/Type``,
the text of :func:`clis_app.bags.mcap.message_definition`) and the bag's payloads: the
serialized CDR bytes as they came off the wire, never decoded. It serves the topics the
recorder records (:func:`clis_app.bags.recorder_node.graph_topics` at start, any other topic of
the graph as it appears, looked for every ``foxglove.discovery_period`` s; or only
``foxglove.topics``). The node subscribes *raw* to a topic only while a client subscribes to
its channel (an open Foxglove costs the graph what its panels show), and always to the
transient-local ones (whose last ``foxglove.replay`` messages a late client gets); it keeps the
subscriptions out of the executor and takes the waiting messages each ``foxglove.poll_period``
s of wall time (a take costs microseconds). A view that falls behind loses the oldest
messages, never slows a publisher. A topic's channel is advertised once the topic has a
publisher; each message is logged with its receive time (wall clock, as in the bags). A client
that reads slower than the graph publishes loses the oldest of the ``foxglove.backlog``
messages queued for it (the SDK's backpressure: the graph never waits for a viewer).

Decimation: a person needs a few frames per wall second, and the graph runs the sim many times
faster than real time. The high-rate topics of ``foxglove.decimated`` (every tick or decision
of the sim: ``/clock``, ``odom``, ``reward``, ``wheels``, ``camera``, ``ir``, ``markers``,
``cmd_vel``, the proposals, ``arbiter/action``) are forwarded at most ``foxglove.max_rate``
per wall second each: their subscription is best effort with a queue of one, so DDS keeps the
newest message for the view and drops the others before the node sees them (no resends by the
publisher, no Python work per dropped message), and the node takes it at most once per
``1 / max_rate`` s of wall time (on average: at the first poll after each multiple of that
period). Every message of the other topics is forwarded (reliable, ``foxglove.depth`` deep):
the arbiter's draws, the belief, the episode events, the parameters, the progress, the arena.
The bags (``clis run --record``) keep everything.

Two channels are derived for the layout:

* ``/foxglove/path`` (``nav_msgs/msg/Path``): the robot's path since the current episode's
  ``start`` (from the ``odom`` messages forwarded: poses at least ``foxglove.path_step`` m
  apart), sent every ``foxglove.path_period`` s of wall time while it grows (decoded only
  while a client subscribes to it);
* ``/foxglove/success`` (``geometry_msgs/msg/Vector3Stamped``, at each learned episode's end,
  from ``learner/progress``): ``x`` = share of the last ``foxglove.block`` learned episodes
  that reached the destination, ``y`` = learned episodes, ``z`` = 1 if this one reached it.

Parameters: ``config/foxglove.yaml`` (section ``foxglove``; ``-p foxglove.KEY:=VALUE``).

A client that subscribes late gets what a late ROS subscriber gets: the last
``foxglove.replay`` messages of each transient-local topic (the arena, the parameters, the
episode events, the learner's progress) and the last message of the derived channels are sent
again when it subscribes (clients already subscribed get them twice).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
import json
import time
from typing import Any

from clis_base.params import ConfigError, build, config_dir, dataclass, param, ros_parameters
from clis_base.ros.graph_node import GraphNode, OnDemand, run_node
from clis_base.ros.rclpy_private import parameter_overrides
from clis_base.ros.ros_params import declare_from_config
from clis_modules.core.modules import ModuleSetParams
from clis_modules.core.plugin import parse_condition
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from nav_msgs.msg import Odometry, Path
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidHandle
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from clis_app.bags.mcap import BagError, message_definition
from clis_app.bags.recorder_node import EXCLUDED, graph_topics, latched_topics, message_class
from clis_app.live.layout import (
    LAYOUT_CONDITION,
    PATH_TOPIC,
    SUCCESS_TOPIC,
    layout_json,
    shown_topics,
)
from cr_sim import conversions as rconv

__all__ = ['FoxgloveParams', 'FoxgloveNode', 'CONFIG_FILE', 'DEFAULT_PORT', 'HOST', 'main']

#: The only interface the WebSocket listens on.
HOST = '127.0.0.1'
DEFAULT_PORT = 8765
#: The channels the live view computes (a late subscriber gets their last message again).
DERIVED = frozenset({PATH_TOPIC, SUCCESS_TOPIC})
#: The node's parameter file (section ``foxglove``).
CONFIG_FILE = 'foxglove.yaml'


@dataclass(frozen=True)
class FoxgloveParams:
    """Settings of the live view (``config/foxglove.yaml``, section ``foxglove``)."""

    port: int = param(1, 65535, doc=f'TCP port of the WebSocket on {HOST}')
    topics: str = param(doc="comma-separated topics to serve; '' = every topic of the graph")
    depth: int = param(1, 100000, doc='queue depth of each subscription (older messages are '
                                      'dropped when the view falls behind)')
    poll_period: float = param(0.001, 1.0, doc='[s wall] how often the queues are emptied')
    discovery_period: float = param(0.05, 60.0, doc='[s wall] how often new topics are looked '
                                                    'for')
    path_step: float = param(0.0, 10.0, doc='[m] distance between two poses of the path')
    path_period: float = param(0.0, 60.0, doc='[s wall] least time between two path messages')
    block: int = param(1, 100000, doc='learned episodes over which the success rate is taken')
    backlog: int = param(16, 10**6, doc='messages queued per client (a client that lags loses '
                                        'the oldest)')
    max_rate: float = param(0.0, 1000.0, doc='[1/s wall] most messages forwarded per second of '
                                             'each decimated topic (0 = all of them)')
    replay: int = param(1, 1000, doc='last messages of a transient-local topic sent again to a '
                                     'client that subscribes late')
    decimated: str = param(doc='comma-separated high-rate topics forwarded at most max_rate '
                               'per wall second (the newest message), besides the proposals '
                               "of the condition's modules; the others: every message")
    wait_for_client: bool = param(doc='no odom subscription until a client subscribes to the '
                                      'channel of every shown topic that has a publisher '
                                      '(clis run --foxglove-wait: the simulator waits for it)')
    layout: str = param(doc="file the layout of the graph's condition is written to at start "
                            "('' = none; clis run: foxglove_layout.json in its folder)")


class FoxgloveNode(GraphNode):
    """Raw subscriptions forwarded to a Foxglove WebSocket server (module docstring)."""

    control_path = False                    # a viewer: never real-time

    def __init__(self) -> None:
        super().__init__('foxglove', clis_cls=ModuleSetParams,  # the modules' sections (no scipy)
                         check_condition=parse_condition)
        if 'use_sim_time' not in parameter_overrides(self):
            # wall time only (timers, log times): no /clock reader of its own, one less for the
            # simulator to deliver to (/clock is subscribed to as a channel while shown)
            self.set_parameters([Parameter('use_sim_time', Parameter.Type.BOOL, False)])
        import foxglove  # only here: the rest of the package runs without it

        self.fox = foxglove
        defaults = ros_parameters(config_dir() / CONFIG_FILE, '/**')
        values = declare_from_config(self, {'foxglove': defaults['foxglove']})
        self.cfg: FoxgloveParams = build(FoxgloveParams, values['foxglove'], where='foxglove')
        self.only = [self.resolve_topic_name(t.strip())
                     for t in self.cfg.topics.split(',') if t.strip()]
        self.types: dict[str, str] = {}                  # topic served -> its type
        self.subs: dict[str, tuple[str, Any]] = {}       # topic -> (type, subscription)
        self.odom = self.resolve_topic_name('odom')
        #: decimated topic -> wall time (monotonic) of its next take; its gap between takes
        self.due: dict[str, float] = {}
        self.gap = 1.0 / self.cfg.max_rate if self.cfg.max_rate > 0 else 0.0
        proposals = [f'{m}/proposal' for m in parse_condition(self.graph.condition).modules]
        self.decimated = frozenset(self.resolve_topic_name(t.strip()) for t in [
            *self.cfg.decimated.split(','), *proposals] if t.strip()) if self.gap else frozenset()
        self.dirty = False                               # a client (un)subscribed
        self.channels: dict[str, Any] = {}               # topic -> foxglove.Channel
        #: topic -> its last messages (payload, log time): ``foxglove.replay`` of a latched
        #: topic (sent again to a late subscriber), one of the others
        self.last: dict[str, deque[tuple[bytes, int]]] = {}
        self.by_id: dict[int, str] = {}                  # channel id -> topic
        self.counts: dict[str, int] = {}                 # topic -> messages forwarded
        #: topics whose last message a new subscriber gets (transient local; derived)
        self.latched = {PATH_TOPIC, SUCCESS_TOPIC}
        self.path: deque = deque()
        self.path_frame = ''
        self.path_sent = (0, 0.0)                        # (poses sent, wall time)
        self.reached: dict[int, int] = {}                # learned episode -> reached
        self.closed = False
        #: foxglove.wait_for_client: no odom subscription (the simulator's first episode waits
        #: for it with clis run --foxglove-wait) until a client watches (:meth:`_client_ready`)
        self.held = self.cfg.wait_for_client
        view = layout_json(self.graph.condition, self.clis)
        self.shown = frozenset(self.resolve_topic_name(t)
                               for t in shown_topics(json.loads(view)) if t not in DERIVED)
        if self.cfg.layout:
            from pathlib import Path
            Path(self.cfg.layout).parent.mkdir(parents=True, exist_ok=True)
            Path(self.cfg.layout).write_text(view, encoding='utf-8')
        from foxglove.websocket import ServerListener

        node = self

        class Listener(ServerListener):
            """The server's callbacks (its own thread; no-ops but this one)."""

            def on_subscribe(self, client: Any, channel: Any) -> None:
                node.on_subscribe(int(channel.id))

            def on_unsubscribe(self, client: Any, channel: Any) -> None:
                node.dirty = True

        self.listener = Listener()
        try:
            self.server = foxglove.start_server(name='clis', host=HOST, port=self.cfg.port,
                                                server_listener=self.listener,
                                                message_backlog_size=self.cfg.backlog)
        except Exception as exc:                         # noqa: BLE001 e.g. the port is taken
            raise ConfigError(f'foxglove.port: cannot serve on {HOST}:{self.cfg.port} '
                              f'({exc})') from None
        self._polled = OnDemand(active=False)            # taken by _poll, never by the executor
        wanted = {self.resolve_topic_name(t): typ
                  for t, typ in graph_topics(self.graph.condition, self.clis).items()}
        self.latched_names = latched_topics(self.graph.condition)
        if self.only:
            wanted = {t: wanted[t] for t in self.only if t in wanted}
        for topic, typ in wanted.items():
            self._add(topic, typ)
        self.channel(PATH_TOPIC, 'nav_msgs/msg/Path')
        self.channel(SUCCESS_TOPIC, 'geometry_msgs/msg/Vector3Stamped')
        self._sync()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.cfg.discovery_period, self._discover, clock=steady)
        self.create_timer(self.cfg.poll_period, self._poll, clock=steady)
        self.clock_on_demand()                           # under sim time if told so
        self.defer_housekeeping()
        shipped = f'config/foxglove_layout.json, the layout of {LAYOUT_CONDITION}'
        self.get_logger().info(f'Foxglove live view on ws://{HOST}:{self.server.port} (layout of '
                               f'{self.graph.condition}: {self.cfg.layout or shipped}; '
                               'docs/foxglove.md)')

    # ------------------------------------------------------------------ subscriptions

    def _add(self, topic: str, msg_type: str) -> None:
        """Serve ``topic`` (subscribed to while :meth:`_needed`)."""
        try:
            message_class(msg_type)
        except (AttributeError, ImportError, ValueError) as exc:
            self.get_logger().warning(f'{topic}: type {msg_type} not available ({exc}): '
                                      'not served', once=True)
            return
        offered = [i.qos_profile for i in self.get_publishers_info_by_topic(topic)]
        latched = any(topic == self.resolve_topic_name(t) for t in self.latched_names)
        if offered:                                      # as the publishers offer it
            latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
        self.types[topic] = msg_type
        if latched:
            self.latched.add(topic)

    def _needed(self, topic: str) -> bool:
        """Whether to subscribe to ``topic`` now: always to a latched topic (its last message
        is what a late client gets), else while a client subscribes to its channel (or, for
        ``odom``, to the path's)."""
        if topic == self.odom and self.held:
            return False
        if topic in self.latched:
            return True
        chan = self.channels.get(topic)
        if chan is not None and chan.has_sinks():
            return True
        return topic == self.odom and self.channels[PATH_TOPIC].has_sinks()

    def _sync(self) -> None:
        """Subscribe to the topics :meth:`_needed`, and unsubscribe from the others."""
        if self.held and self._client_ready():
            self.held = False
            self.get_logger().info('a client watches: the run starts (foxglove.wait_for_client)')
        for topic, msg_type in self.types.items():
            need = self._needed(topic)
            if need and topic not in self.subs:
                self._subscribe(topic, msg_type)
            elif not need and topic in self.subs:
                self.destroy_subscription(self.subs.pop(topic)[1])
                self.due.pop(topic, None)

    def _client_ready(self) -> bool:
        """Whether the robot (odom) has a publisher and a client has subscribed to the channel
        of every shown topic that has one."""
        if not self.count_publishers(self.odom):
            return False
        return all(t in self.channels and self.channels[t].has_sinks()
                   for t in self.shown if self.count_publishers(t))

    def _subscribe(self, topic: str, msg_type: str) -> None:
        """A raw subscription out of the executor. A decimated topic: best effort, a queue of
        one (DDS keeps the newest message and drops the others for this reader: no resends by
        the publisher, no Python work per dropped message); the others reliable (best effort
        if a publisher offers only that), ``foxglove.depth`` deep, transient local if latched."""
        if topic in self.decimated and topic not in self.latched:
            qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.VOLATILE)
            sub = self.create_subscription(message_class(msg_type), topic, lambda *_: None, qos,
                                           raw=True, callback_group=self._polled)
            self.subs[topic] = (msg_type, sub)
            self.due[topic] = 0.0
            return
        offered = [i.qos_profile for i in self.get_publishers_info_by_topic(topic)]
        reliable = not any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in offered)
        qos = QoSProfile(
            depth=self.cfg.depth,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=(DurabilityPolicy.TRANSIENT_LOCAL if topic in self.latched
                        else DurabilityPolicy.VOLATILE))
        sub = self.create_subscription(message_class(msg_type), topic, lambda *_: None, qos,
                                       raw=True, callback_group=self._polled)
        self.subs[topic] = (msg_type, sub)

    def _discover(self) -> None:
        """Serve new topics; advertise the channel of a topic once it has a publisher (a
        client then subscribes before its first message)."""
        if self.closed:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in self.types or topic.startswith('/foxglove/'):
                continue
            if (self.only and topic not in self.only) or (not self.only and topic in EXCLUDED):
                continue
            self._add(topic, types[0])
        for topic, msg_type in self.types.items():
            if topic not in self.channels and self.count_publishers(topic):
                self.channel(topic, msg_type)
        self._sync()

    # ------------------------------------------------------------------ forwarding

    def channel(self, topic: str, msg_type: str) -> Any | None:
        """The channel of ``topic`` (advertised now if new); None if its schema is unknown."""
        chan = self.channels.get(topic)
        if chan is None:
            try:
                text = message_definition(msg_type)
            except BagError as exc:
                self.get_logger().warning(f'{topic}: {exc}: not served', once=True)
                return None
            schema = self.fox.Schema(name=msg_type, encoding='ros2msg', data=text.encode())
            chan = self.fox.Channel(topic, schema=schema, message_encoding='cdr')
            self.channels[topic] = chan
            self.by_id[chan.id()] = topic
        return chan

    def send(self, topic: str, msg_type: str, data: bytes, log_ns: int) -> None:
        """Log ``data`` (CDR) on ``topic``'s channel and keep it as the topic's last message."""
        chan = self.channel(topic, msg_type)
        if chan is None:
            return
        last = self.last.get(topic)
        if last is None:
            keep = self.cfg.replay if topic in self.latched and topic not in DERIVED else 1
            last = self.last[topic] = deque(maxlen=keep)
        elif log_ns < last[-1][1]:
            log_ns = last[-1][1]                         # never back in time
        last.append((data, log_ns))
        self.counts[topic] = self.counts.get(topic, 0) + 1
        chan.log(data, log_time=log_ns)

    def _poll(self) -> None:
        """Forward every message waiting on any subscription, each topic's in the order they
        were published (not sorted by receive stamps, which are not monotonic within a topic);
        then the path."""
        if self.closed:
            return
        if self.dirty:                                   # a client (un)subscribed
            self.dirty = False
            self._sync()
        batch = []
        now = time.monotonic()
        for name, (typ, sub) in self.subs.items():
            due = self.due.get(name)
            if due is not None:                          # decimated: the newest, when due
                if now < due:
                    continue                             # DDS keeps only the newest meanwhile
                try:
                    with sub.handle:
                        got = sub.handle.take_message(sub.msg_type, True)
                except InvalidHandle:
                    continue
                if got is not None:                      # the next take, on a grid of 1/max_rate
                    self.due[name] = max(due + self.gap, now - self.gap)
                    batch.append((got[1].get('received_timestamp') or time.time_ns(),
                                  name, typ, got[0]))
                continue
            try:
                with sub.handle:
                    while (got := sub.handle.take_message(sub.msg_type, True)) is not None:
                        batch.append((got[1].get('received_timestamp') or time.time_ns(),
                                      name, typ, got[0]))   # in the order published
            except InvalidHandle:                        # destroyed meanwhile
                continue
        for recv, name, typ, data in batch:
            self.send(name, typ, data, recv)
            if name == self.odom and self.channels[PATH_TOPIC].has_sinks():
                self._on_odom(data)
            elif typ == 'diagnostic_msgs/msg/DiagnosticArray':
                self._on_event(name, data, recv)
        self._send_path()

    def on_subscribe(self, channel_id: int) -> None:
        """A client subscribed to a channel (the server's thread, the subscription in place):
        the last messages of a latched topic (``foxglove.replay``; the last of a derived
        channel), as DDS gives them to a late subscriber."""
        self.dirty = True
        topic = self.by_id.get(channel_id)
        if topic in self.latched:
            for data, log_ns in list(self.last.get(topic, ())):
                self.channels[topic].log(data, log_time=log_ns)

    # ------------------------------------------------------------------ derived channels

    def _on_odom(self, data: bytes) -> None:
        msg = deserialize_message(data, Odometry)
        p = msg.pose.pose.position
        if self.path:
            q = self.path[-1].pose.position
            if (p.x - q.x) ** 2 + (p.y - q.y) ** 2 < self.cfg.path_step ** 2:
                return
        self.path.append(PoseStamped(header=msg.header, pose=msg.pose.pose))
        self.path_frame = msg.header.frame_id

    def _send_path(self, force: bool = False) -> None:
        sent, when = self.path_sent
        if not self.path or len(self.path) == sent:
            return
        now = time.monotonic()
        if not force and now - when < self.cfg.path_period:
            return
        msg = Path(poses=list(self.path))
        msg.header.stamp, msg.header.frame_id = self.path[-1].header.stamp, self.path_frame
        self.send(PATH_TOPIC, 'nav_msgs/msg/Path', serialize_message(msg), time.time_ns())
        self.path_sent = (len(self.path), now)

    def _on_event(self, topic: str, data: bytes, recv: int) -> None:
        """An episode ``start`` clears the path; a learned episode's progress row updates the
        success rate."""
        try:
            msg = deserialize_message(data, DiagnosticArray)
            t, event, values = rconv.event_from_msg(msg)
        except (IndexError, ValueError):
            return
        if topic.endswith('/episode') and event == 'start':
            self._send_path(force=True)                  # the end of the last one
            self.path.clear()
            self.path_sent = (0, 0.0)
        elif topic.endswith('/progress') and values.get('learned') == '1':
            self._on_learned(msg, values, recv)

    def _on_learned(self, msg: DiagnosticArray, values: Mapping[str, str], recv: int) -> None:
        try:
            episode = int(float(values['episode']))
            self.reached[episode] = int(float(values.get('reached', 0)))
        except (KeyError, ValueError):
            return
        recent = [self.reached[e] for e in sorted(self.reached)[-self.cfg.block:]]
        out = Vector3Stamped()
        out.header.stamp = msg.header.stamp
        out.vector.x = sum(recent) / len(recent)
        out.vector.y = float(len(self.reached))
        out.vector.z = float(self.reached[episode])
        self.send(SUCCESS_TOPIC, 'geometry_msgs/msg/Vector3Stamped', serialize_message(out),
                  recv)

    def close(self) -> None:
        """Stop the server (called on Ctrl-C / SIGTERM by :func:`run_node`)."""
        if self.closed:
            return
        self.closed = True
        self.server.stop()
        counts = ', '.join(f'{t} {n}' for t, n in sorted(self.counts.items()))
        print(f'foxglove: {sum(self.counts.values())} messages served: {counts}', flush=True)


def main(args: list[str] | None = None) -> None:
    run_node(FoxgloveNode, 'foxglove', __doc__, args)


if __name__ == '__main__':
    main()
