"""What every node of the CLIS graph shares: parameters, sim time, the executor and ``main``.

Parameters (declared once, frozen into dataclasses, validated at start): the CLIS sections of
``config/clis.yaml`` (``/**``; every graph node reads the same values as the headless runner),
the ``graph`` section of ``config/graph.yaml`` (condition, seed, arena, executor) and the node's
own section of ``config/graph.yaml``. Each is declared as a dotted ROS parameter with the file's
value as default, so ``--ros-args -p graph.condition:=sync`` or ``--params-file`` override it; a
bad value stops the node (exit code 2) with a message naming the key and its range.

Time: graph nodes follow ``/clock`` (``use_sim_time`` true) unless told otherwise, since the
robot interface (simulator or bridge) publishes it; decisions, staleness and episode times are
all in that clock.

Wakeups: under sim time the graph runs many times faster than real time, and what a node costs
is mostly the executor's work per wakeup (rclpy rebuilds its wait set in Python every time), so
a stream that a node needs only at some instants is taken *on demand*: its subscription is in
an :class:`OnDemand` callback group, its messages wait in their DDS queue, and the node takes
them (:func:`take_all`) when it needs them, or lets the executor wake it for them while it
waits for one (``group.active``). :meth:`GraphNode.clock_on_demand` does this for ``/clock``
in a node that reads its clock only now and then (the learner, the arbiter). The entities
that serve others now and then, the parameter services and the default QoS-incompatibility
event handlers, are not waited on at every wakeup either (:meth:`GraphNode.defer_housekeeping`):
they are served every ``graph.housekeeping_period`` of wall time (``ros2 param`` answers that
much later), which halves the entities of every wait.
"""

from __future__ import annotations

from collections.abc import Callable
import sys
import time
from typing import Any

import rclpy
from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType, JumpThreshold
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile

from clis_base.params import ConfigError, build, config_dir, dataclass, param, ros_parameters
from clis_base.ros.executor import EXECUTORS, make_executor
from clis_base.ros.process import (
    SHUTDOWN_RACES,
    realtime_logged,
    reraise_unless_shut_down,
    settle_heap,
)
from clis_base.ros.profiling import start_profile, stop_profile
from clis_base.ros.qos import STREAM_DEPTH, proposal_qos
from clis_base.ros.rclpy_private import clock_subscription, parameter_overrides, set_clock
from clis_base.ros.ros_params import declare_from_config, print_help_and_exit_if_asked
from clis_base.trace import dump as dump_trace

__all__ = ['GraphParams', 'GraphNode', 'OnDemand', 'make_executor', 'proposal_qos', 'run_node',
           'take_all']


@dataclass(frozen=True)
class GraphParams:
    """Settings every CLIS graph node shares (``config/graph.yaml``, section ``graph``)."""

    condition: str = param(doc='which modules run, on which periods: TIMING:MODULE+MODULE... '
                           '(async:innate+view+place+wall) or innate, view, place, sync, async')
    seed: int = param(0, 2**31 - 1, doc='seed of the run (each node derives its own streams)')
    arena_file: str = param(doc="arena description (the place module's map); '' = "
                                'config/arena.yaml')
    executor: str = param(choices=EXECUTORS, doc="rclpy executor: 'lean' "
                          "(clis_base.ros.executor.LeanExecutor), 'single' (rclpy's "
                          "SingleThreadedExecutor) or 'events' (rclpy's EventsExecutor)")
    liveliness_lease: float = param(0.1, 60.0, doc='[s wall] DDS liveliness lease of the '
                                    'proposals: the arbiter knows a module died this soon')
    housekeeping_period: float = param(0.001, 10.0, doc='[s wall] how often the parameter '
                                       'services and QoS-incompatibility events are served')
    realtime_priority: int = param(0, 99, doc='SCHED_FIFO priority of the nodes on the '
                                   'sensor-to-command path (modules, arbiter; not the learner); '
                                   '0 = default scheduling; > 0 also holds the CPU wake-up '
                                   'latency at 0 us (idle cores poll). Fail-soft without the '
                                   'right to it')

    def proposal_qos(self, depth: int = STREAM_DEPTH) -> QoSProfile:
        """QoS of a module's proposals with this ``liveliness_lease``: see :func:`proposal_qos`."""
        return proposal_qos(self.liveliness_lease, depth)


#: The sections of ``clis.yaml`` that are not module instances (some node reads each).
_CLIS_SECTIONS = frozenset({'common', 'modules', 'arbiter', 'learner', 'instances'})


class OnDemand(CallbackGroup):
    """A callback group whose entities the executor waits on only while :attr:`active`.

    The messages of a subscription in it stay in the subscription's queue (its QoS depth)
    until the node takes them with :func:`take_all`, so the node is not woken for each one.
    Set ``active`` while the node waits for a message it needs: the executor then runs the
    subscription's callback as usual.
    """

    def __init__(self, active: bool = False) -> None:
        super().__init__()
        self.active = active

    def can_execute(self, entity) -> bool:
        return self.active

    def beginning_execution(self, entity) -> bool:
        return self.active

    def ending_execution(self, entity) -> None:
        pass


class Housekeeping(CallbackGroup):
    """A callback group the executor waits on only for a moment after each :meth:`open`
    (:meth:`GraphNode.defer_housekeeping`)."""

    def __init__(self) -> None:
        super().__init__()
        self.until = 0.0

    def open(self, seconds: float = 0.002) -> None:
        """Let the next waits of the executor (within ``seconds``) include the entities."""
        self.until = time.monotonic() + seconds

    def can_execute(self, entity) -> bool:
        return time.monotonic() < self.until

    def beginning_execution(self, entity) -> bool:
        return True

    def ending_execution(self, entity) -> None:
        pass


#: The default QoS event handlers that only report a mismatch found at discovery.
_MISMATCH_EVENTS = ('OFFERED_INCOMPATIBLE_QOS', 'REQUESTED_INCOMPATIBLE_QOS',
                    'INCOMPATIBLE_TYPE')


def take_all(sub) -> list:
    """Every message waiting in subscription ``sub``'s queue, oldest first, taken now (as the
    executor takes them, without running the callback)."""
    out = []
    with sub.handle:
        while (taken := sub.handle.take_message(sub.msg_type, sub.raw)) is not None:
            out.append(taken[0])
    return out


class GraphNode(Node):
    """A node of the CLIS graph: parameters from the config files (module docstring).

    Parameters
    ----------
    name : str
        Node name.
    section : str or None
        The node's own section of ``config/graph.yaml``.
    section_cls : type or None
        Its frozen parameter dataclass.
    clis_cls : type
        Dataclass of the ``clis.yaml`` sections the node reads (the modules'
        ``ModuleSetParams``, or the learner's ``ClisParams``).
    check_condition : callable, optional
        ``check_condition(graph.condition)`` raises ValueError on a condition that is none
        (the modules' one parser, ``clis_modules.core.plugin.parse_condition``): the node stops
        at start naming ``graph``.

    Attributes
    ----------
    control_path : bool
        Whether the node is on the sensor-to-command path (``graph.realtime_priority``
        applies to it): the modules and the arbiter, not the learner nor the recorder.
    clis : the ``clis_cls`` instance
    graph : GraphParams
    cfg : the ``section_cls`` instance (None without a section)
    """

    control_path = True

    def __init__(self, name: str, section: str | None = None, section_cls: type | None = None,
                 *, clis_cls: type,
                 check_condition: Callable[[str], object] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        if 'use_sim_time' not in parameter_overrides(self):   # not set by the user: follow
            self.set_parameters([Parameter('use_sim_time', Parameter.Type.BOOL, True)])
        graph_file = config_dir() / 'graph.yaml'
        graph = ros_parameters(graph_file, '/**')
        clis = ros_parameters(config_dir() / 'clis.yaml', '/**')
        # the class's sections, and the module instances (every section no class names)
        sections = {f for f in clis_cls.__dataclass_fields__}
        others = _CLIS_SECTIONS - sections
        defaults = {k: v for k, v in clis.items() if k in sections or k not in others}
        defaults['graph'] = graph['graph']
        if section is not None:
            defaults[section] = graph[section]
        values = declare_from_config(self, defaults)
        self.graph: GraphParams = build(GraphParams, values.pop('graph'), where='graph')
        if check_condition is not None:
            try:
                check_condition(self.graph.condition)
            except ValueError as exc:
                raise ConfigError(f'graph: {exc}') from exc
        self.cfg = (build(section_cls, values.pop(section), where=section)
                    if section is not None else None)
        self.clis = build(clis_cls, values)
        self._clock_sub = None                   # /clock taken on demand (clock_on_demand)

    def now_s(self) -> float:
        """The node's clock (sim time under ``/clock``) in seconds."""
        if self._clock_sub is not None:
            self.take_clock()
        return self.get_clock().now().nanoseconds * 1e-9

    def defer_housekeeping(self) -> None:
        """Serve the parameter services and the QoS-mismatch event handlers only every
        ``graph.housekeeping_period`` of wall time instead of waiting on them at every wakeup
        (module docstring). Call it last in ``__init__``: it moves what exists then."""
        group = Housekeeping()
        moved = [srv for srv in self.services]
        moved += [w for w in self.waitables if not isinstance(w.callback_group, OnDemand)
                  and any(str(getattr(w, 'event_type', '')).endswith(e)
                          for e in _MISMATCH_EVENTS)]
        for entity in moved:
            entity.callback_group = group
            group.add_entity(entity)
        self.create_timer(self.graph.housekeeping_period, group.open,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def clock_on_demand(self) -> None:
        """Under sim time, take ``/clock`` only when the node reads its clock (:meth:`now_s`,
        :meth:`take_clock`) instead of being woken for every message: for a node whose
        callbacks are driven by other topics and wall timers (no sim-time timer of its own).
        The clock then moves, and :meth:`on_clock_advance` callbacks run, when it is read."""
        sub = clock_subscription(self)
        if sub is None or not self.sim_time:
            return
        group = OnDemand()
        # the subscription and its QoS event handlers (left in a group the executor waits
        # on, they keep its wait returning at once while /clock messages wait untaken)
        for entity in [sub, *getattr(sub, 'event_handlers', [])]:
            entity.callback_group = group
            group.add_entity(entity)
        self._clock_sub = sub

    def take_clock(self) -> None:
        """Bring the clock to the newest ``/clock`` waiting (:meth:`clock_on_demand`)."""
        msgs = take_all(self._clock_sub)
        if msgs:
            set_clock(self, msgs[-1])

    @property
    def sim_time(self) -> bool:
        """Whether the node follows ``/clock``."""
        return bool(self.get_parameter('use_sim_time').value)

    def on_clock_advance(self, callback: Callable[[float], None]) -> None:
        """Call ``callback(t)`` whenever the clock moves forward (under sim time: at every
        ``/clock`` message), right after the new time is set."""
        threshold = JumpThreshold(min_forward=Duration(nanoseconds=1), min_backward=None,
                                  on_clock_change=False)
        self._jump_handles = [*getattr(self, '_jump_handles', []),
                              self.get_clock().create_jump_callback(
                                  threshold, post_callback=lambda _: callback(self.now_s()))]


def run_node(factory: Callable[[], GraphNode], name: str, doc: str | None,
             args: list[str] | None = None) -> None:
    """``main`` of a graph node: ``--help``, init, build (exit 2 on a bad parameter), spin until
    Ctrl-C / SIGTERM, clean shutdown."""
    print_help_and_exit_if_asked(doc, args)
    rclpy.init(args=args)
    try:
        node = factory()
    except (ConfigError, ValueError) as exc:
        print(f'{name}: bad parameter: {exc}', file=sys.stderr, flush=True)
        rclpy.try_shutdown()
        raise SystemExit(2) from None
    executor = make_executor(node.graph.executor, node.get_logger())
    executor.add_node(node)
    settle_heap()
    if node.control_path and node.graph.realtime_priority:
        realtime_logged(node.graph.realtime_priority, node.get_logger())
    profiler = start_profile()
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SHUTDOWN_RACES:
        reraise_unless_shut_down()          # a shutdown racing the executor is a clean stop
    finally:
        stop_profile(profiler, name)
        dump_trace(name)
        close = getattr(node, 'close', None)
        if callable(close):
            close()
        node.destroy_node()
        rclpy.try_shutdown()
