"""``ros2 run clis_modules module --ros-args -r __node:=NAME``: one CLIS module instance deciding
on its own timer (``innate``, ``view``, ``place``: the same for the paper's three).

The node's name is the module instance's (``config/clis.yaml``; a plug-in's name for a plug-in
with defaults, docs/modules.md): any plug-in runs in this one executable. Every ``tau_i`` of
the clock (its timer; under sim time also the ``/clock`` reaching ``t_0 + l tau_i``, whichever
comes first; 250/500/1200 ms in Async, the slowest period for all in Sync) the module reads the
latest readings of the sensors its plug-in declares, of ``camera``, ``ir`` and ``wheels`` (with
a ``motion`` hook, the place module's, every ``wheels`` reading since its last decision:
odometry), decides through the
same :class:`~clis_modules.core.decider.Decider` as the headless runner, and publishes its
proposal on ``~/proposal`` (sensor_msgs/JointState: sampled wheel command, policy mean and
sigma, V_i(x), features, stamped with the time of the sensor readings it used; layout in
:mod:`clis_modules.conversions`). The place module also publishes its belief on ``~/belief``
(nav_msgs/OccupancyGrid, marginal over heading; any module with a ``display`` hook).

The readings are taken when a decision is due, not as they arrive
(:class:`~clis_base.ros.graph_node.OnDemand`): they wait in their subscriptions' queues
(:data:`~clis_modules.core.schedule.READINGS_DEPTH` deep, more than the ticks of the longest
period) and the module takes them all at its decision instant; only if those of the instant
have not arrived yet does the executor wake the module for them. A module is so woken once per
tick (``/clock``) and at its decisions, not for every reading of every topic.

Episodes (``episode`` events of the robot interface): at a ``start`` the module forgets its
state (the place module's belief becomes uniform), decides at once on the first readings of
the new episode, and restarts its timer, so that its decisions fall at ``t_0 + l tau_i`` as in
the headless runner; after ``reached``/``timeout``/``reset`` it stays silent until the next
start.

Randomness: the headless runner's agent stream ``(seed, 2)``, replayed over the condition's
decision instants (:mod:`clis_base.agent_stream`: the node makes every module's and the
arbiter's draws in the runner's order and keeps its own), from the state the simulator
announces at each start; a decision off the tick grid (real time) draws from a stream of its
own.

Parameters from the learner (``~/params``, transient local: a restarted module gets the latest
at once) change only between episodes, as in the headless runner: they are applied before the
first decision of an episode. A ``start`` event that announces a parameter version
(``params_version``, from a simulator waiting for the learner) makes the module wait for those
parameters, at most ``module.params_timeout`` s of wall time, before its first decision.

The node is the subscriptions, the publishers and the timers; when to decide, on which
readings, with which draws, and what to publish at which instant is
:class:`~clis_modules.core.schedule.ModuleSchedule` (no ROS in it, tested without ROS): the
node calls it, then publishes what it gives.
"""

from __future__ import annotations

from collections.abc import Callable

from clis_base.params import ConfigError, dataclass, param
from clis_base.ros.graph_node import GraphNode, OnDemand, run_node, take_all
from clis_base.trace import mark
from cr_sim.core.arena import load_arena
from cr_sim.core.robot import load_robot_params
from cr_sim.core.sim import load_sim_params
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import OccupancyGrid
from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState

from clis_modules import conversions as conv
from clis_modules.core.modules import ModuleSetParams, arena_map, condition_periods, make_module
from clis_modules.core.plugin import parse_condition
from clis_modules.core.schedule import (
    READINGS_DEPTH,
    Log,
    ModuleSchedule,
    Propose,
    PublishObservation,
    ResetTimer,
)
from cr_sim import conversions as rconv

__all__ = ['ModuleNodeParams', 'ModuleNode', 'main', 'main_innate', 'main_view', 'main_place']

#: QoS of the latched topics (episode events, parameters).
LATCHED = QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL)
PARAMS_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
END_EVENTS = ('reached', 'timeout', 'reset')


@dataclass(frozen=True)
class ModuleNodeParams:
    """Settings of a module node (``config/graph.yaml``, section ``module``)."""

    params_timeout: float = param(0.0, 600.0, doc='wall seconds to wait for announced '
                                  'parameters at an episode start')
    frame: str = param(doc="frame of the place module's belief grid")
    resend_period: float = param(0.01, 60.0, doc='wall seconds the clock stands at the '
                                 'instant of the last proposal before it is sent again')


class ModuleNode(GraphNode):
    """Subscriptions, publishers and timers around a :class:`ModuleSchedule` (module
    docstring).

    Parameters
    ----------
    name : str, optional
        The module instance (the node's name; ``-r __node:=NAME`` overrides it).
    """

    def __init__(self, name: str | None = None) -> None:
        super().__init__(name or 'module', 'module', ModuleNodeParams,
                         clis_cls=ModuleSetParams, check_condition=parse_condition)
        name = self.get_name()                  # the instance (``-r __node:=NAME``)
        listed = condition_periods(self.clis, self.graph.condition)
        periods = dict(listed)
        if name not in periods:
            raise ConfigError(f'graph.condition = {self.graph.condition!r} has no {name} '
                              f'module (it runs {", ".join(periods)})')
        arena = load_arena(self.graph.arena_file or None)
        module = make_module(self.clis, name, periods[name], *arena_map(arena))
        # the tick dt comes with each start event (config/sim.yaml's until then)
        self.core = ModuleSchedule(
            module, listed, seed=self.graph.seed, selection=self.clis.arbiter.selection,
            dt=load_sim_params().episode.dt, wheel_base=load_robot_params().wheel_base,
            landmarks=[lm.name for lm in arena.landmarks], sim_time=self.sim_time,
            params_timeout=self.cfg.params_timeout, resend_period=self.cfg.resend_period,
            now=self.now_s, take=self._take_readings)
        # compiled kernels ready before the node joins the graph (Decider.warm_up: a kernel
        # compiled at the first decision would miss the lockstep's first instants)
        self.core.decider.warm_up(len(arena.landmarks))
        self.trace_clock, self.trace_pub = f'{name}_clock', f'{name}_pub'

        self.pub = self.create_publisher(JointState, '~/proposal', self.graph.proposal_qos())
        # the module's features at the other modules' instants (the behaviour's state of (6)
        # for the learner, as the headless runner records it): with more than one module
        self.pub_obs = (self.create_publisher(JointState, '~/observation', rconv.STREAM_DEPTH)
                        if len(listed) > 1 else None)
        self.pub_belief = (self.create_publisher(OccupancyGrid, '~/belief', 10)
                           if module.display is not None else None)
        # the readings of the plug-in's sensors, taken at the decision instants (docstring)
        self.on_demand = OnDemand()
        rd = self.core.readings
        wanted = [('camera', rd.reads_camera, READINGS_DEPTH, self._add_camera),
                  ('ir_ranges', rd.reads_ir, READINGS_DEPTH, self._add_ir),
                  ('wheels', rd.reads_wheels, rconv.STREAM_DEPTH, self._add_wheels)]
        self.readings = [(self.create_subscription(
            JointState, topic, self._on_reading(add), depth, callback_group=self.on_demand),
            add) for topic, reads, depth, add in wanted if reads]
        self.create_subscription(DiagnosticArray, 'episode', self._on_episode, LATCHED)
        self.create_subscription(JointState, '~/params', self._on_params, PARAMS_QOS)
        self.timer = self.create_timer(self.core.period, self._on_timer)
        if self.sim_time:
            self.on_clock_advance(self._on_clock)
        # wall clock: waiting for parameters while the simulator holds its clock
        self.create_timer(0.05, self._on_wall, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.defer_housekeeping()
        self.get_logger().info(
            f'{name}: condition {self.graph.condition}, period {self.core.period} s, '
            f'v_max {module.v_max:.3f} m/s, {module.n} features')

    # ------------------------------------------------------------------ inputs

    def _add_camera(self, msg: JointState) -> None:
        self.core.readings.add_camera(*rconv.bearings_from_msg(msg))

    def _add_ir(self, msg: JointState) -> None:
        # the full-precision beams (``ir``'s LaserScan carries float32): the runner's percept
        self.core.readings.add_ir(*rconv.ir_ranges_from_msg(msg))

    def _add_wheels(self, msg: JointState) -> None:
        self.core.readings.add_wheels(*rconv.wheels_from_msg(msg))

    def _take_readings(self) -> None:
        """Take every reading waiting in the subscriptions' queues (in arrival order)."""
        for sub, add in self.readings:
            for msg in take_all(sub):
                add(msg)

    def _on_reading(self, add: Callable[[JointState], None]) -> Callable[[JointState], None]:
        """The callback of a reading: run only while a due decision waits for the readings
        of its instant (:attr:`ModuleSchedule.waiting`)."""
        def on_reading(msg: JointState) -> None:
            add(msg)
            self._run(self.core.try_decide)
        return on_reading

    def _on_episode(self, msg: DiagnosticArray) -> None:
        t, event, values = rconv.episode_from_msg(msg)
        if event == 'start':
            self._run(self.core.start, t, values)
        elif event in END_EVENTS:
            self._run(self.core.end, t)

    def _on_params(self, msg: JointState) -> None:
        try:
            params = conv.params_from_msg(msg)
        except ValueError as exc:
            self.get_logger().error(f'ignored parameters: {exc}')
            return
        self._run(self.core.set_parameters, *params)

    def _on_timer(self) -> None:
        self._run(self.core.on_timer)

    def _on_clock(self, t: float) -> None:
        mark(self.trace_clock, t)
        self._run(self.core.on_clock, t)

    def _on_wall(self) -> None:
        self._run(self.core.on_wall)

    # ------------------------------------------------------------------ outputs

    def _run(self, step: Callable[..., None], *args: object) -> None:
        """Call the schedule, then publish what it gives, in order, and let the executor wake
        the node for the readings of a due decision only while it waits for them."""
        step(*args)
        for action in self.core.pop_actions():
            if isinstance(action, Propose):
                self.pub.publish(conv.proposal_msg(action.proposal, action.stamp))
                if not action.again:
                    self._decided(action.proposal.t)
            elif isinstance(action, PublishObservation):
                self.pub_obs.publish(conv.observation_msg(self.core.name, action.t,
                                                          action.features))
            elif isinstance(action, ResetTimer):
                self.timer.reset()
            elif isinstance(action, Log):
                getattr(self.get_logger(), action.level)(action.text)
        self.on_demand.active = self.core.waiting

    def _decided(self, t: float) -> None:
        mark(self.trace_pub, t)
        # display only: built only for a subscriber (RViz, Foxglove, a recorder), after the
        # proposal, which the arbiter waits for
        if self.pub_belief is not None and self.pub_belief.get_subscription_count():
            grid, cell, origin = self.core.decider.module.display()
            self.pub_belief.publish(conv.belief_msg(grid, cell, origin, t, self.cfg.frame))


def main(args: list[str] | None = None, name: str | None = None) -> None:
    """``ros2 run clis_modules module --ros-args -r __node:=NAME`` (any module instance)."""
    run_node(lambda: ModuleNode(name), name or 'module', __doc__, args)


def main_innate(args: list[str] | None = None) -> None:
    """``ros2 run clis_modules innate``."""
    main(args, 'innate')


def main_view(args: list[str] | None = None) -> None:
    """``ros2 run clis_modules view``."""
    main(args, 'view')


def main_place(args: list[str] | None = None) -> None:
    """``ros2 run clis_modules place``."""
    main(args, 'place')


if __name__ == '__main__':       # python -m clis_modules.module_node NAME [--ros-args ...]
    import sys
    main(sys.argv[:1] + sys.argv[2:], sys.argv[1] if len(sys.argv) > 1 else 'innate')
