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
(:class:`~clis_modules.graph_node.OnDemand`): they wait in their subscriptions' queues
(:data:`READINGS_DEPTH` deep, more than the ticks of the longest period) and the module takes
them all at its decision instant; only if those of the instant have not arrived yet does the
executor wake the module for them. A module is so woken once per tick (``/clock``) and at its
decisions, not for every reading of every topic.

Episodes (``episode`` events of the robot interface): at a ``start`` the module forgets its
state (the place module's belief becomes uniform), decides at once on the first readings of
the new episode, and restarts its timer, so that its decisions fall at ``t_0 + l tau_i`` as in
the headless runner; after ``reached``/``timeout``/``reset`` it stays silent until the next
start.

Randomness: the headless runner's agent stream ``(seed, 2)``, replayed over the condition's
decision instants (:mod:`cr_sim.core.streams`: the node makes every module's and the
arbiter's draws in the runner's order and keeps its own), from the state the simulator
announces at each start; a decision off the tick grid (real time) draws from a stream of its
own.

Parameters from the learner (``~/params``, transient local: a restarted module gets the latest
at once) change only between episodes, as in the headless runner: they are applied before the
first decision of an episode. A ``start`` event that announces a parameter version
(``params_version``, from a simulator waiting for the learner) makes the module wait for those
parameters, at most ``module.params_timeout`` s of wall time, before its first decision.
"""

from __future__ import annotations

from collections import deque
import math
import time
import zlib

from cr_sim.core.instants import TOL, DecisionClock
from cr_sim.core.params import ConfigError, dataclass, param
from cr_sim.core.robot import load_robot_params
from cr_sim.core.sim import load_sim_params
from cr_sim.ros_support.trace import mark
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import OccupancyGrid
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState

from clis_modules import conversions as conv
from clis_modules.core.decider import Decider, Percept
from clis_modules.core.modules import MODULE_NAMES, arena_map, condition_periods, make_module
from clis_modules.core.streams import AgentStream, module_draws
from clis_modules.graph_node import GraphNode, OnDemand, run_node, take_all
from cr_sim import conversions as rconv

__all__ = ['ModuleNodeParams', 'ModuleNode', 'main', 'main_innate', 'main_view', 'main_place']

#: Two stamps closer than this [s] are the same instant.
_TOL = TOL
#: Wall seconds a due decision may wait before the module logs why it waits.
STALL_WARNING = 2.0
#: QoS of the latched topics (episode events, parameters).
LATCHED = QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL)
PARAMS_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
END_EVENTS = ('reached', 'timeout', 'reset')
#: Queue depth of the ``camera`` and ``ir`` subscriptions, taken at the decision instants: more
#: than the ticks of the longest period (1.2 s = 24 ticks of 50 ms).
READINGS_DEPTH = 50


@dataclass(frozen=True)
class ModuleNodeParams:
    """Settings of a module node (``config/graph.yaml``, section ``module``)."""

    params_timeout: float = param(0.0, 600.0, doc='wall seconds to wait for announced '
                                  'parameters at an episode start')
    frame: str = param(doc="frame of the place module's belief grid")
    resend_period: float = param(0.01, 60.0, doc='wall seconds the clock stands at the '
                                 'instant of the last proposal before it is sent again')


class ModuleNode(GraphNode):
    """Thin glue around a :class:`Decider` (module docstring)."""

    def __init__(self, kind: str | None = None) -> None:
        super().__init__(kind or 'module', 'module', ModuleNodeParams)
        kind = self.get_name()                  # the instance (``-r __node:=NAME``)
        listed = condition_periods(self.clis, self.graph.condition)
        periods = dict(listed)
        if kind not in periods:
            raise ConfigError(f'graph.condition = {self.graph.condition!r} has no {kind} '
                              f'module (it runs {", ".join(periods)})')
        arena = self.arena()
        module = make_module(self.clis, kind, periods[kind], *arena_map(arena))
        self.period = periods[kind]
        # the draws' stream: the paper's modules by their index, others by their name
        self.kind_index = (MODULE_NAMES.index(kind) if kind in MODULE_NAMES
                           else zlib.crc32(kind.encode()))
        self.sensors = set(module.sensors) | ({'wheels'} if module.on_motion else set())
        # the decisions' draws: the headless runner's agent stream (seed, 2), replayed over
        # the condition's decision instants (cr_sim.core.streams); the tick dt comes with each
        # start event (config/sim.yaml's until then)
        self.index = [name for name, _ in listed].index(kind)
        self.taus = [tau for _, tau in listed]
        self.clock = DecisionClock(self.taus, load_sim_params().episode.dt)
        self.stream = AgentStream(np.random.default_rng([self.graph.seed, 2]), len(listed),
                                  self.clis.arbiter.selection, self.clock)
        self.draws = module_draws(self.stream, self.index)
        self.off_grid_rng = self._episode_rng(0)
        self.decider = Decider(module, self.off_grid_rng, load_robot_params().wheel_base)
        # compiled kernels ready before the node joins the graph (Decider.warm_up: a kernel
        # compiled at the first decision would miss the lockstep's first instants)
        self.decider.warm_up(len(arena.landmarks))
        self.t0: float | None = None            # start of the running episode (None: none)
        self.due = False                        # a decision waits for fresh readings
        self.last_t = -math.inf                 # stamp of the last decision's readings
        self.due_t = -math.inf                  # a decision uses readings from this instant on
        self.align: float | None = None         # reset the timer's phase at this clock time
        self.expect_version = 0                 # parameter version announced by the start
        self.wait_until = 0.0                   # wall deadline of that wait
        self.pending = None                     # parameters received during an episode
        self.sent = None                        # (proposal, wall time) published last
        self.due_wall = None                    # wall time the pending decision became due
        self.stall_said = False
        self.ended_t = -math.inf
        self.last_grid = -math.inf
        self.marked = -math.inf                 # the grid instant last marked due
        self.camera: deque = deque(maxlen=READINGS_DEPTH)  # (stamp, dest, landmark bearings)
        self.ir: deque = deque(maxlen=READINGS_DEPTH)      # (stamp, d_o, every ray)
        self.last_wheels = np.zeros(2)          # the wheel reading last taken
        self.wheels: deque = deque(maxlen=2000)  # (stamp, v_left, v_right)
        self.wheels_t = -math.inf               # stamp of the last wheels reading used
        self.landmarks = [lm.name for lm in arena.landmarks]
        self._unseen = np.full(len(self.landmarks), math.nan)   # no camera read: none seen
        self.trace_clock, self.trace_decide, self.trace_pub = (
            f'{kind}_clock', f'{kind}_decide', f'{kind}_pub')

        self.pub = self.create_publisher(JointState, '~/proposal', self.graph.proposal_qos())
        # the module's features at the other modules' instants (the behaviour's state of (6)
        # for the learner, as the headless runner records it): with more than one module
        self.pub_obs = (self.create_publisher(JointState, '~/observation', rconv.STREAM_DEPTH)
                        if len(listed) > 1 else None)
        self.obs_k = 0                          # the next tick of the episode to observe at
        # the episode observed (its start; None before the first) and its end (inf while it
        # runs): an ended episode's last observations may still wait for their readings
        self.obs_t0: float | None = None
        self.obs_end = math.inf
        self.pub_belief = (self.create_publisher(OccupancyGrid, '~/belief', 10)
                           if module.display is not None else None)
        # the readings of the plug-in's sensors, taken at the decision instants (docstring)
        self.on_demand = OnDemand()
        self.readings = []
        if 'camera' in self.sensors:
            self.readings.append((self.create_subscription(
                JointState, 'camera', self._on_camera, READINGS_DEPTH,
                callback_group=self.on_demand), self._add_camera))
        if 'ir' in self.sensors or 'camera' not in self.sensors:
            self.readings.append((self.create_subscription(
                JointState, 'ir_ranges', self._on_ir, READINGS_DEPTH,
                callback_group=self.on_demand),
                self._add_ir))
        if 'wheels' in self.sensors:
            self.readings.append((self.create_subscription(
                JointState, 'wheels', self._on_wheels, rconv.STREAM_DEPTH,
                callback_group=self.on_demand), self._add_wheels))
        self.create_subscription(DiagnosticArray, 'episode', self._on_episode, LATCHED)
        self.create_subscription(JointState, '~/params', self._on_params, PARAMS_QOS)
        self.timer = self.create_timer(self.period, self._on_timer)
        if self.sim_time:
            self.on_clock_advance(self._on_clock)
        # wall clock: waiting for parameters while the simulator holds its clock
        self.create_timer(0.05, self._on_wall, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.defer_housekeeping()
        self.get_logger().info(
            f'{kind}: condition {self.graph.condition}, period {self.period} s, '
            f'v_max {module.v_max:.3f} m/s, {module.n} features')

    # ------------------------------------------------------------------ inputs

    def _add_camera(self, msg: JointState) -> None:
        t, bearings = rconv.bearings_from_msg(msg)
        lm = np.array([bearings.get(name, math.nan) for name in self.landmarks])
        self.camera.append((t, bearings.get('destination', math.nan), lm))

    def _add_ir(self, msg: JointState) -> None:
        # the full-precision beams (``ir``'s LaserScan carries float32): the runner's percept
        t, ranges = rconv.ir_ranges_from_msg(msg)
        self.ir.append((t, float(np.min(ranges)) if ranges.size else math.inf, ranges))

    def _add_wheels(self, msg: JointState) -> None:
        t, v = rconv.wheels_from_msg(msg)
        if v.size == 2:
            self.wheels.append((t, float(v[0]), float(v[1])))

    def _take_readings(self) -> None:
        """Take every reading waiting in the subscriptions' queues (in arrival order)."""
        for sub, add in self.readings:
            for msg in take_all(sub):
                add(msg)

    # woken for a reading (only while a due decision waits for the readings of its instant)
    def _on_camera(self, msg: JointState) -> None:
        self._add_camera(msg)
        self._try_decide()

    def _on_ir(self, msg: JointState) -> None:
        self._add_ir(msg)
        self._try_decide()

    def _on_wheels(self, msg: JointState) -> None:
        self._add_wheels(msg)
        self._try_decide()

    def _on_episode(self, msg: DiagnosticArray) -> None:
        t, event, values = rconv.episode_from_msg(msg)
        if event == 'start':
            self._start_stream(values)
            self._start(t, int(values.get('params_version', 0)), int(values.get('episode', 0)))
        elif event in END_EVENTS:
            if self.t0 is not None and (k_end := self.clock.tick(t, self.t0)) is not None:
                self.stream.end_episode(k_end)      # the draws of its instants before t
            if self.t0 is not None:
                self.obs_end = t - 2 * _TOL         # observed up to the end, not at it
            self.t0, self.due, self.ended_t = None, False, t
            # the end event may overtake the readings of the episode's last instants (their
            # own topics): what is in goes out now, the rest as it comes (clock, wall timer)
            self._take_readings()
            self._observe_pending(t)

    def _on_params(self, msg: JointState) -> None:
        try:
            name, w, W, sigma, version = conv.params_from_msg(msg)  # noqa: N806
        except ValueError as exc:
            self.get_logger().error(f'ignored parameters: {exc}')
            return
        if name != self.decider.name:
            self.get_logger().error(f'ignored parameters of {name!r} on my topic')
            return
        self.pending = (w, W, sigma, version)
        # between episodes, before the first decision of one, or the parameters this episode
        # was announced with (a module restarted mid-episode gets them late)
        if self.t0 is None or self.last_t < self.t0 or version <= self.expect_version:
            self._apply_pending()
            self._try_decide()

    def _on_timer(self) -> None:
        if self.t0 is None:
            return
        if self.sim_time:
            self._mark_due(self._grid(self.now_s()))
        else:                                   # real time: decide on the newest readings
            self.due, self.due_t = True, -math.inf
            self._try_decide()

    def _grid(self, t: float) -> float:
        """The last decision instant ``t_0 + l tau_i`` at or before ``t``."""
        return self.clock.last_instant(self.index, t, self.t0)

    def _start_stream(self, values: dict) -> None:
        """At a start event: the tick and the agent stream's state it announces (a simulator
        keeping the stream: docs/design.md §6), else the stream goes on from the last end."""
        dt = float(values.get('dt', self.clock.dt))
        if dt != self.clock.dt:
            self.clock = self.stream.clock = DecisionClock(self.taus, dt)
        if 'agent_state' in values:
            self.stream.set_state(values['agent_state'])
        else:
            self.stream.begin_episode()

    def _mark_due(self, g: float) -> None:
        """Under sim time: decide on the readings of grid instant ``g`` (the simulator
        publishes an instant's readings before the clock reaches it), or on the first after
        it if the clock ran past it; once per grid instant, whichever of the timer and the
        clock sees it first."""
        if g > self.marked + _TOL:
            self.marked = g
            self.due, self.due_t = True, g
            self._try_decide()

    def _on_clock(self, t: float) -> None:
        mark(self.trace_clock, t)
        if self.align is not None and t >= self.align - _TOL:
            self.align = None
            self.timer.reset()                  # the timer's phase: t_0 + l tau_i
        # Decisions follow the clock itself: rclpy's sim-time timer fires on the same
        # instants, but a run on a loaded machine once saw it not fire for a whole episode
        # (every instant then waited out the arbiter's lockstep timeout)
        if self.t0 is not None and t >= self.t0 - _TOL:
            self._mark_due(self._grid(t))
        if not self.due:
            # between its decisions the module takes the readings when the clock wakes it
            # anyway (no wakeup of their own), so that a decision takes only its instant's
            # instead of a period's worth (72 messages for the place module) on its path
            self._take_readings()
            self._observe_pending(t)

    def _on_wall(self) -> None:
        now = time.monotonic()
        self._take_readings()                   # the queues stay short between decisions
        if not self.due and self.obs_t0 is not None:
            self._observe_pending(self.now_s())
        if self.due:
            # a due decision waits for readings, and the executor runs the timers of a wakeup
            # before its subscriptions: a reading this took is one whose callback will not
            # run, so decide on it here (else, on a loaded host where every wakeup finds this
            # timer due, the decision waited for the next instant or the arbiter's timeout)
            self._try_decide()
        self._check_stall(now)
        # under sim time the clock stands at the instant of the last proposal until the
        # arbiter has it: send it again if that takes long (lost while the graph connected)
        if self.sim_time and self.sent is not None and self.t0 is not None \
                and now - self.sent[1] >= self.cfg.resend_period \
                and self.now_s() <= self.last_t + _TOL:
            self.pub.publish(self.sent[0])
            self.sent = (self.sent[0], now)
        if self.due and self.decider.version < self.expect_version \
                and time.monotonic() >= self.wait_until:
            self.get_logger().warning(
                f'parameters version {self.expect_version} did not arrive within '
                f'{self.cfg.params_timeout} s: deciding with version {self.decider.version}')
            self.expect_version = self.decider.version
            self._try_decide()

    def _check_stall(self, now: float) -> None:
        """Say once why a decision has been due for long (a stalled lockstep explains itself)."""
        if self.t0 is not None and not self.due and self.sim_time \
                and self._grid(self.now_s()) > self.last_grid + _TOL:
            why = f'no decision marked for {self._grid(self.now_s()):.3f}'
        elif self.t0 is None and self.camera and self.camera[-1][0] > self.ended_t + _TOL:
            why = f'no start event seen, readings at {self.camera[-1][0]:.3f}'
        elif self.due and self.t0 is not None:
            why = 'due'
        else:
            self.due_wall = None
            return
        if self.due_wall is None:
            self.due_wall, self.stall_said = now, False
        elif not self.stall_said and now - self.due_wall >= STALL_WARNING:
            self.stall_said = True
            cams = [round(t, 3) for t, *_ in self.camera][-3:]
            irs = [round(t, 3) for t, *_ in self.ir][-3:]
            self.get_logger().warning(
                f'{why}: waiting for {now - self.due_wall:.1f} s: t0 {self.t0}, '
                f'clock {self.now_s():.3f}, due from {self.due_t:.3f}, last decision on '
                f'{self.last_t:.3f}, parameters {self.decider.version} (expected '
                f'{self.expect_version}), last camera {cams}, last ir {irs}')

    # ------------------------------------------------------------------ decisions

    def _episode_rng(self, episode: int) -> np.random.Generator:
        """The draws of a decision off the decision instants (real time, no tick grid): from
        (seed, 2, module, episode)."""
        return np.random.default_rng([self.graph.seed, 2, self.kind_index, episode])

    def _start(self, t0: float, version: int, episode: int = 0) -> None:
        self.decider.reset()
        self.off_grid_rng = self._episode_rng(episode)
        self._apply_pending()
        self.t0 = t0
        self.expect_version = version
        self.wait_until = time.monotonic() + self.cfg.params_timeout
        self.wheels_t = t0
        self.obs_k = 0
        self.obs_t0, self.obs_end = t0, math.inf
        self.timer.reset()
        self.marked = -math.inf
        if not self.sim_time:
            self.due, self.due_t = True, -math.inf
        else:
            now = self.now_s()
            if now < t0 - _TOL:                 # the clock has not reached the start yet
                self.align = t0
                self._mark_due(t0)
            elif self._grid(now) >= now - _TOL:  # the clock stands at a decision instant
                self._mark_due(self._grid(now))
            else:                               # (re)started between two: the next one
                self.marked = self._grid(now)
                self.align = self.marked + self.period
        self._try_decide()

    def _apply_pending(self) -> None:
        if self.pending is None:
            return
        try:
            self.decider.set_parameters(*self.pending)
        except ValueError as exc:
            self.get_logger().error(f'ignored parameters: {exc}')
        self.pending = None

    def _readings(self) -> tuple | None:
        """An instant of this episode with a reading of each of the module's camera and IR
        (those it reads), newer than the last decision: ``(t, dest bearing, landmark bearings,
        d_o, rays)`` (NaN, None for a sensor it does not read); under sim time the first at or
        after the due instant, in real time the newest."""
        if 'camera' in self.sensors:
            primary = self.camera
            ir = ({round(t, 6): (d_o, rays) for t, d_o, rays in self.ir}
                  if 'ir' in self.sensors else None)
        else:
            primary = [(t, math.nan, self._unseen, (d_o, rays)) for t, d_o, rays in self.ir]
            ir = None
        found = None
        for t, dest, lm, *rest in reversed(primary):
            if t < self.t0 - _TOL or t <= self.last_t + _TOL or t < self.due_t - _TOL:
                break
            got = rest[0] if rest else (ir.get(round(t, 6)) if ir is not None
                                        else (math.nan, None))
            if got is not None:
                found = (t, dest, lm, *got)
                if not self.sim_time:
                    break
        return found

    def _integrate_wheels(self, t: float) -> None:
        """Odometry: the wheel velocities of every step that ended after the last reading
        used, up to ``t`` (each held since the previous reading)."""
        while self.wheels and self.wheels[0][0] <= t + _TOL:
            tw, vl, vr = self.wheels.popleft()
            if tw > self.wheels_t + _TOL:
                # held for a whole number of ticks under sim time: that many dt exactly, as
                # the headless runner integrates (the stamps' difference is dt to rounding)
                held = tw - self.wheels_t
                ticks = round(held / self.clock.dt)
                if self.sim_time and ticks >= 1 and abs(held - ticks * self.clock.dt) <= _TOL:
                    held = ticks * self.clock.dt
                self.decider.on_wheels(vl, vr, held)
                self.wheels_t = tw
            self.last_wheels = np.array((vl, vr))

    def _reading_at(self, t: float) -> tuple | None:
        """The readings of instant ``t`` the module reads: ``(dest bearing, landmark
        bearings, d_o, rays)``, or None while one has not arrived."""
        cam = None
        if 'camera' in self.sensors:
            cam = next(((dest, lm) for tc, dest, lm in reversed(self.camera)
                        if abs(tc - t) <= _TOL), None)
            if cam is None:
                return None
        ir = (math.nan, None)
        if 'ir' in self.sensors or 'camera' not in self.sensors:
            ir = next(((d_o, rays) for ti, d_o, rays in reversed(self.ir)
                       if abs(ti - t) <= _TOL), None)
            if ir is None:
                return None
        dest, lm = cam if cam is not None else (math.nan, self._unseen)
        return dest, lm, *ir

    def _observe_pending(self, limit: float) -> None:
        """Under sim time, with other modules: at each instant up to ``limit`` at which
        another module decides and this one does not, its features there
        (:meth:`Decider.observe`: no draw, its state untouched) on ``~/observation``, in
        order, once that instant's readings are in (the headless runner records the acting
        module's; the learner uses those of the module that acted)."""
        if self.pub_obs is None or not self.sim_time or self.obs_t0 is None:
            return
        dt = self.clock.dt
        limit = min(limit, self.obs_end)        # an ended episode: up to its end
        while (tj := self.obs_t0 + self.obs_k * dt) <= limit + _TOL:
            due = self.clock.due_at(self.obs_k)
            if self.index in due and tj > self.last_t + _TOL:
                return                          # its own decision first
            passed = tj < self.last_t - _TOL or tj < self.wheels_t - _TOL
            if not due or self.index in due or passed:
                self.obs_k += 1
                continue
            found = self._reading_at(tj)
            if found is None or ('wheels' in self.sensors and self.wheels_t < tj - _TOL
                                 and not (self.wheels and self.wheels[-1][0] >= tj - _TOL)):
                return                          # its readings are on their way
            self._integrate_wheels(tj)
            dest, lm, d_o, rays = found
            b = self.decider.observe(Percept(tj, dest, d_o, lm, rays, self.last_wheels))
            self.pub_obs.publish(conv.observation_msg(self.decider.name, tj, b))
            self.obs_k += 1

    def _try_decide(self) -> None:
        if not self.due or self.t0 is None or self.decider.version < self.expect_version:
            self.on_demand.active = False
            return
        self._take_readings()
        found = self._readings()
        # until the readings of the instant are in, the executor wakes the module for them
        self.on_demand.active = True
        if found is None:
            return
        t, dest, lm, d_o, rays = found
        # a module reading the wheels (the place module: odometry up to t) under sim time waits
        # for the wheel reading of t too (it travels on its own topic and may come later)
        if 'wheels' in self.sensors and self.sim_time and self.wheels_t < t - _TOL \
                and not (self.wheels and self.wheels[-1][0] >= t - _TOL):
            return
        self.on_demand.active = False
        self._observe_pending(t - 2 * _TOL)     # the other modules' instants before it
        self._integrate_wheels(t)
        mark(self.trace_decide, t)
        # the draws of the instant: the agent stream's (the runner's), or off the grid a
        # stream of the module's own
        k = self.clock.tick(t, self.t0)
        if k is not None and self.clock.is_due(self.index, k):
            self.stream.instant(k)
            self.decider.rng = self.draws
        else:
            self.decider.rng = self.off_grid_rng
        p = self.decider.decide(Percept(t, dest, d_o, lm, rays, self.last_wheels))
        self.due, self.last_t, self.last_grid = False, t, self.due_t
        msg = conv.proposal_msg(p, self.now_s())
        self.pub.publish(msg)
        mark(self.trace_pub, t)
        self.sent = (msg, time.monotonic())
        # display only: built only for a subscriber (RViz, Foxglove, a recorder), after the
        # proposal, which the arbiter waits for
        if self.pub_belief is not None and self.pub_belief.get_subscription_count():
            grid, cell, origin = self.decider.module.display()
            self.pub_belief.publish(conv.belief_msg(grid, cell, origin, t, self.cfg.frame))


def main(args: list[str] | None = None, kind: str | None = None) -> None:
    """``ros2 run clis_modules module --ros-args -r __node:=NAME`` (any module instance)."""
    run_node(lambda: ModuleNode(kind), kind or 'module', __doc__, args)


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
