"""When a module node decides, on which readings, with which draws, and what it publishes.

A module node (:mod:`clis_modules.module_node`) is the subscriptions, the publishers and the
timers of one module instance; :class:`ModuleSchedule` is everything it decides with them,
without ROS (no rclpy, no message types: plain values in, plain :data:`Action` values out),
so that it is tested like :class:`~clis_modules.core.decider.Decider`, which it drives.

Decision instants (paper II-E: module i decides "asynchronously", every ``tau_i``): under sim
time module i decides at ``t_0 + l tau_i`` of the running episode
(:class:`~clis_base.instants.DecisionClock`), once per instant, whichever of its timer and
the clock sees the instant first (:meth:`ModuleSchedule.on_timer`,
:meth:`ModuleSchedule.on_clock`), on the readings of that instant, or of the first instant
after it if the clock ran past it; in real time on the newest readings at every timer.
A decision waits until a reading of each sensor the module reads has arrived for its instant
(:class:`Readings`, which gives them as :class:`InstantReadings`); :attr:`ModuleSchedule.waiting`
says that the node should be woken for them.

Draws: at an instant ``t_0 + l tau_i`` the headless runner's agent stream ``(seed, 2)``,
replayed over the condition's decision instants (:mod:`clis_base.agent_stream`), so that the
proposals are the runner's bit for bit; off the tick grid (real time) a stream of the
module's own per episode (:func:`off_grid_rng`).

Observations: with other modules, at each instant at which another module decides and this
one does not, its features there (:meth:`Decider.observe`; the behaviour's state of (6) for
the learner), in order, once that instant's readings are in.

Parameters received during an episode wait for its end; a start that announces a parameter
version makes the first decision wait for it, at most ``params_timeout`` wall seconds.

The node calls an entry point (a reading, an episode event, parameters, its timer, the clock,
its wall timer) and then carries out the actions :meth:`ModuleSchedule.pop_actions` gives, in
order: :class:`Propose`, :class:`PublishObservation`, :class:`ResetTimer`, :class:`Log`. The
clock, the wall clock and the taking of the readings waiting in the node's queues are
callables the node passes in (a test passes its own).

One module over 500 lines: the actions, the state of the decisions and the readings kept for
them are one state machine, the node's whole decision logic; :class:`Readings` has no user
but :class:`ModuleSchedule`, and the tests drive them together (``test/test_module_schedule.py``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
import time
from typing import NamedTuple
import zlib

from clis_base.instants import TOL, DecisionClock
from clis_base.trace import mark
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.decider import Decider, Percept
from clis_modules.core.draws import AgentStream, module_draws
from clis_modules.core.modules import ModuleCore
from clis_modules.core.plugin import parse_condition
from clis_modules.core.proposal import Proposal

__all__ = ['READINGS_DEPTH', 'STALL_WARNING', 'Propose', 'PublishObservation', 'ResetTimer',
           'Log', 'Action', 'CameraReading', 'IrReading', 'WheelReading', 'InstantReadings',
           'LearnedParameters', 'Readings', 'EpisodeState', 'NextDecision', 'LastDecision',
           'ObservationCursor', 'Stall', 'ModuleSchedule', 'off_grid_rng']

#: Wall seconds a due decision may wait before the module says why it waits.
STALL_WARNING = 2.0
#: Readings of ``camera`` and ``ir`` kept: more than the ticks of the longest period (1.2 s =
#: 24 ticks of 50 ms); the node's queues of them are as deep.
READINGS_DEPTH = 50
#: Wheel readings kept (a module integrates them up to its decision instants).
WHEELS_DEPTH = 2000


# ------------------------------------------------------------------------------ actions

@dataclass(frozen=True)
class Propose:
    """Publish ``proposal`` decided at clock time ``stamp`` [s]; ``again``: the last one sent
    again (the clock stands at its instant), else a new decision (then the belief display)."""

    proposal: Proposal
    stamp: float
    again: bool = False


@dataclass(frozen=True)
class PublishObservation:
    """Publish the module's features ``features`` at instant ``t`` [s], another module's
    decision instant (no decision of its own there)."""

    t: float
    features: np.ndarray


@dataclass(frozen=True)
class ResetTimer:
    """Restart the decision timer now: its phase becomes ``t_0 + l tau_i``."""


@dataclass(frozen=True)
class Log:
    """Log ``text`` at ``level`` (``'warning'`` or ``'error'``)."""

    level: str
    text: str


Action = Propose | PublishObservation | ResetTimer | Log


# ------------------------------------------------------------------------------ readings, values

class CameraReading(NamedTuple):
    """The camera's bearings of one instant."""

    t: float                        # the instant [s]
    dest_bearing: float             # of the destination [rad]; NaN: not seen
    landmark_bearings: np.ndarray   # (M,) of the landmarks, in the arena's order [rad]; NaN


class IrReading(NamedTuple):
    """The IR rays of one instant."""

    t: float                        # the instant [s]
    d_o: float                      # the nearest obstacle: the smallest ray [m] (inf: none)
    ir: np.ndarray                  # (n_ir,) every ray [m]


#: The IR reading of a module that reads no IR.
_NO_IR = IrReading(math.nan, math.nan, None)


class WheelReading(NamedTuple):
    """The wheel velocities of one instant."""

    t: float                        # the instant [s]
    v_left: float                   # [m/s]
    v_right: float                  # [m/s]


class InstantReadings(NamedTuple):
    """What the module reads of one instant, in the order of
    :class:`~clis_modules.core.plugin.Percept`'s fields (NaN, the landmarks unseen, None for a
    sensor it does not read)."""

    t: float                        # the instant [s]
    dest_bearing: float             # [rad]
    d_o: float                      # [m]
    landmark_bearings: np.ndarray   # (M,) [rad]
    ir: np.ndarray | None           # (n_ir,) [m]

    def percept(self, wheels: np.ndarray) -> Percept:
        """The :class:`~clis_modules.core.plugin.Percept` of these readings, with the wheel
        reading ``wheels`` (2,) [m/s]."""
        return Percept(self.t, self.dest_bearing, self.d_o, self.landmark_bearings, self.ir,
                       wheels)


class LearnedParameters(NamedTuple):
    """Parameters from the learner (the arguments of
    :meth:`~clis_modules.core.decider.Decider.set_parameters`)."""

    w: ArrayLike                    # (n,) value weights
    W: ArrayLike                    # (2, n) policy weights
    sigma: float
    version: int


# ------------------------------------------------------------------------------ state

@dataclass
class EpisodeState:
    """The running episode."""

    t0: float | None = None         # its start (None: none runs)
    ended: float = -math.inf        # stamp of the last end event
    version: int = 0                # parameter version its start announced
    deadline: float = 0.0           # wall time the wait for that version ends


@dataclass
class NextDecision:
    """The decision state machine: idle, or due and waiting for the readings of its instant."""

    due: bool = False               # a decision waits for readings
    since: float = -math.inf        # it uses readings from this instant on
    marked: float = -math.inf       # the decision instant last marked due
    align: float | None = None      # restart the timer when the clock reaches this


@dataclass
class LastDecision:
    """The last decision and what was sent of it."""

    t: float = -math.inf            # stamp of its readings
    instant: float = -math.inf      # the decision instant it was due from
    proposal: Proposal | None = None
    stamp: float = math.nan         # clock time it was decided at
    wall: float = -math.inf         # wall time it was last sent


@dataclass
class ObservationCursor:
    """Where the observations at the other modules' instants stand: the episode observed, and
    the next tick to observe at."""

    t0: float | None = None         # its start (None before the first)
    end: float = math.inf           # observed up to here (inf while it runs)
    k: int = 0                      # the next tick to observe at


@dataclass
class Stall:
    """The stall diagnosis: since when something waits, and whether it was said."""

    since: float | None = None      # wall time
    said: bool = False
    readings: float = -math.inf     # the latest reading's time when last looked at


# ------------------------------------------------------------------------------ readings

class Readings:
    """The readings of the sensors a module reads, kept until its decision instants.

    Parameters
    ----------
    sensors : set of str
        What the module reads of ``camera``, ``ir`` and ``wheels``.
    landmarks : sequence of str
        Landmark names, in the order of ``Percept.landmark_bearings``.

    Attributes
    ----------
    camera : deque of CameraReading
    ir : deque of IrReading
        Also the instants of a module reading no camera.
    wheels : deque of WheelReading
    integrated : float
        Stamp of the last wheel reading integrated (odometry up to it).
    last_wheels : ndarray, shape (2,)
        The wheel reading last taken.
    """

    def __init__(self, sensors: set[str], landmarks: Sequence[str]) -> None:
        self.reads_camera = 'camera' in sensors
        self.reads_ir = 'ir' in sensors or not self.reads_camera
        self.reads_wheels = 'wheels' in sensors
        self.landmarks = list(landmarks)
        self.unseen = np.full(len(self.landmarks), math.nan)    # no camera read: none seen
        self.camera: deque = deque(maxlen=READINGS_DEPTH)
        self.ir: deque = deque(maxlen=READINGS_DEPTH)
        self.wheels: deque = deque(maxlen=WHEELS_DEPTH)
        self.integrated = -math.inf
        self.last_wheels = np.zeros(2)

    def add_camera(self, t: float, bearings: Mapping[str, float]) -> None:
        """Camera bearings [rad] of instant ``t`` by name (``destination`` and landmarks)."""
        lm = np.array([bearings.get(name, math.nan) for name in self.landmarks])
        self.camera.append(CameraReading(t, bearings.get('destination', math.nan), lm))

    def add_ir(self, t: float, ranges: np.ndarray) -> None:
        """Every IR ray [m] of instant ``t`` (``d_o``: the nearest)."""
        self.ir.append(IrReading(t, float(np.min(ranges)) if ranges.size else math.inf, ranges))

    def add_wheels(self, t: float, v: np.ndarray) -> None:
        """Wheel velocities ``(v_left, v_right)`` [m/s] of instant ``t``."""
        if v.size == 2:
            self.wheels.append(WheelReading(t, float(v[0]), float(v[1])))

    def wheels_pending(self, t: float) -> bool:
        """Whether the module reads the wheels and their reading of ``t`` has not arrived (it
        travels on its own topic and may come after the others)."""
        return self.reads_wheels and self.integrated < t - TOL \
            and not (self.wheels and self.wheels[-1].t >= t - TOL)

    def first_after(self, t0: float, last: float, since: float,
                    newest: bool) -> InstantReadings | None:
        """An instant of the episode started at ``t0``, after ``last`` and not before
        ``since``, with a reading of each of camera and IR the module reads, and its readings;
        the first such instant, or with ``newest`` the newest."""
        if self.reads_camera:
            # the camera's instants, newest first, each with the IR reading of its instant
            # (None: not in yet)
            ir = {round(r.t, 6): r for r in self.ir} if self.reads_ir else None
            instants = ((c, ir.get(round(c.t, 6)) if ir is not None else _NO_IR)
                        for c in reversed(self.camera))
        else:
            # the IR's instants, newest first, no landmark seen
            instants = ((CameraReading(r.t, math.nan, self.unseen), r) for r in reversed(self.ir))
        found = None
        for cam, ir_at in instants:
            if cam.t < t0 - TOL or cam.t <= last + TOL or cam.t < since - TOL:
                break
            if ir_at is not None:
                found = InstantReadings(cam.t, cam.dest_bearing, ir_at.d_o,
                                        cam.landmark_bearings, ir_at.ir)
                if newest:
                    break
        return found

    def at(self, t: float) -> InstantReadings | None:
        """The readings of instant ``t`` the module reads, or None while one has not
        arrived."""
        cam = CameraReading(t, math.nan, self.unseen)
        if self.reads_camera:
            cam = next((c for c in reversed(self.camera) if abs(c.t - t) <= TOL), None)
            if cam is None:
                return None
        ir_at = _NO_IR
        if self.reads_ir:
            ir_at = next((r for r in reversed(self.ir) if abs(r.t - t) <= TOL), None)
            if ir_at is None:
                return None
        return InstantReadings(t, cam.dest_bearing, ir_at.d_o, cam.landmark_bearings, ir_at.ir)

    def integrate(self, t: float, decider: Decider, dt: float, on_ticks: bool) -> None:
        """Odometry: the wheel velocities of every step that ended after the last reading
        integrated, up to ``t``, each held since the previous reading; ``on_ticks`` (sim time):
        held a whole number of ticks ``dt``, as the headless runner integrates, when the
        stamps' difference is that to rounding."""
        while self.wheels and self.wheels[0].t <= t + TOL:
            tw, vl, vr = self.wheels.popleft()
            if tw > self.integrated + TOL:
                held = tw - self.integrated
                ticks = round(held / dt)
                if on_ticks and ticks >= 1 and abs(held - ticks * dt) <= TOL:
                    held = ticks * dt
                decider.on_wheels(vl, vr, held)
                self.integrated = tw
            self.last_wheels = np.array((vl, vr))


# ------------------------------------------------------------------------------ the schedule

def off_grid_rng(seed: int, name: str, episode: int) -> np.random.Generator:
    """The draws of module ``name``'s decisions off the decision instants (real time) in
    ``episode``: ``(seed, 2, index, episode)``, the index of a paper module its place in the
    paper's Async condition (innate 0, view 1, place 2), of another the CRC-32 of its name."""
    paper = parse_condition('async').modules
    index = paper.index(name) if name in paper else zlib.crc32(name.encode())
    return np.random.default_rng([seed, 2, index, episode])


class ModuleSchedule:
    """One module instance's decisions in the graph (module docstring).

    Parameters
    ----------
    module : ModuleCore
        The module (its name is the instance's).
    condition : sequence of (str, float)
        ``(name, tau_i)`` of the condition's modules, in its order
        (:func:`~clis_modules.core.modules.condition_periods`); ``module`` is one of them.
    seed : int
        The run's seed (the agent stream ``(seed, 2)``).
    selection : str
        ``arbiter.selection`` (which instants the arbiter draws at, in the agent stream).
    dt : float
        The simulator's tick [s] until a start event announces another.
    wheel_base : float
        Distance between the wheels [m].
    landmarks : sequence of str
        Landmark names, in the order of the module's landmark bearings.
    sim_time : bool
        Whether the node follows the simulator's clock (decision instants on the tick grid).
    params_timeout : float
        Wall seconds a start waits for the parameter version it announces.
    resend_period : float
        Wall seconds the clock stands at the last proposal's instant before it is sent again.
    now : callable
        The node's clock [s].
    wall : callable
        Wall time [s] (monotonic).
    take : callable
        Takes the readings waiting in the node's queues into :attr:`readings`.
    """

    def __init__(self, module: ModuleCore, condition: Sequence[tuple[str, float]], *,
                 seed: int, selection: str, dt: float, wheel_base: float,
                 landmarks: Sequence[str], sim_time: bool = True, params_timeout: float = 0.0,
                 resend_period: float = 1.0, now: Callable[[], float],
                 wall: Callable[[], float] = time.monotonic,
                 take: Callable[[], None] = lambda: None) -> None:
        names = [n for n, _ in condition]
        self.name = module.name
        self.index = names.index(self.name)
        self.taus = [tau for _, tau in condition]
        self.period = self.taus[self.index]
        self.seed = int(seed)
        self.sim_time = bool(sim_time)
        self.params_timeout, self.resend_period = float(params_timeout), float(resend_period)
        self.now, self.wall, self.take = now, wall, take
        # with other modules: its features at their instants (sim time)
        self.observes = len(names) > 1 and self.sim_time
        self.clock = DecisionClock(self.taus, dt)
        self.stream = AgentStream(np.random.default_rng([self.seed, 2]), len(names), selection,
                                  self.clock)
        self.draws = module_draws(self.stream, self.index)
        self.off_grid = off_grid_rng(self.seed, self.name, 0)
        self.decider = Decider(module, self.off_grid, wheel_base)
        sensors = set(module.sensors) | ({'wheels'} if module.on_motion else set())
        self.readings = Readings(sensors, landmarks)
        self.episode = EpisodeState()
        self.next = NextDecision()
        self.last = LastDecision()
        self.cursor = ObservationCursor()
        self.stall = Stall()
        #: Parameters received during an episode, applied at its end.
        self.pending_params: LearnedParameters | None = None
        #: A due decision waits for readings of its instant: wake the node for them.
        self.waiting = False
        self._out: list[Action] = []

    def pop_actions(self) -> list[Action]:
        """The actions since the last call, in order (the node carries them out); they are
        removed from the schedule."""
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ entry points

    def start(self, t0: float, values: Mapping[str, object]) -> None:
        """A ``start`` event at ``t0`` with its ``values``: the tick ``dt`` and the agent
        stream's state it announces (else the stream goes on from the last end), the
        parameter version to wait for (``params_version``), the ``episode`` number. The module
        forgets its state, and decides at once on the first readings of the episode."""
        dt = float(values.get('dt', self.clock.dt))
        if dt != self.clock.dt:
            self.clock = self.stream.clock = DecisionClock(self.taus, dt)
        if 'agent_state' in values:
            self.stream.set_state(values['agent_state'])
        else:
            self.stream.begin_episode()
        self.decider.reset()
        self.off_grid = off_grid_rng(self.seed, self.name, int(values.get('episode', 0)))
        self._apply_pending_params()
        ep, decision = self.episode, self.next
        ep.t0 = t0
        ep.version = int(values.get('params_version', 0))
        ep.deadline = self.wall() + self.params_timeout
        self.readings.integrated = t0
        self.cursor = ObservationCursor(t0=t0)
        self._out.append(ResetTimer())
        decision.marked = -math.inf
        if not self.sim_time:
            decision.due, decision.since = True, -math.inf
        else:
            now = self.now()
            if now < t0 - TOL:                  # the clock has not reached the start yet
                decision.align = t0
                self._mark_due(t0)
            elif self._last_instant(now) >= now - TOL:  # the clock stands at an instant
                self._mark_due(self._last_instant(now))
            else:                               # (re)started between two: the next one
                decision.marked = self._last_instant(now)
                decision.align = decision.marked + self.period
        self.try_decide()

    def end(self, t: float) -> None:
        """The episode ended at ``t`` (``reached``, ``timeout``, ``reset``): silent until the
        next start; the agent stream keeps the draws of its instants before ``t``."""
        ep = self.episode
        if ep.t0 is not None and (k_end := self.clock.tick(t, ep.t0)) is not None:
            self.stream.end_episode(k_end)
        if ep.t0 is not None:
            self.cursor.end = t - 2 * TOL       # observed up to the end, not at it
        ep.t0, self.next.due, ep.ended = None, False, t
        # the end event may overtake the readings of the episode's last instants (their own
        # topics): what is in goes out now, the rest as it comes (clock, wall timer)
        self.take()
        self._observe_up_to(t)

    def set_parameters(self, name: str, w: ArrayLike, W: ArrayLike,  # noqa: N803
                       sigma: float, version: int) -> None:
        """Parameters from the learner: applied between episodes, before the first decision
        of one, or when they are the version the episode was announced with (a module
        restarted mid-episode gets them late); else at the next start."""
        if name != self.name:
            self._out.append(Log('error', f'ignored parameters of {name!r} on my topic'))
            return
        self.pending_params = LearnedParameters(w, W, sigma, version)
        ep = self.episode
        if ep.t0 is None or self.last.t < ep.t0 or version <= ep.version:
            self._apply_pending_params()
            self.try_decide()

    def on_timer(self) -> None:
        """The decision timer (period ``tau_i``)."""
        if self.episode.t0 is None:
            return
        if self.sim_time:
            self._mark_due(self._last_instant(self.now()))
        else:                                   # real time: decide on the newest readings
            self.next.due, self.next.since = True, -math.inf
            self.try_decide()

    def on_clock(self, t: float) -> None:
        """The clock moved to ``t`` (sim time)."""
        decision = self.next
        if decision.align is not None and t >= decision.align - TOL:
            decision.align = None
            self._out.append(ResetTimer())      # the timer's phase: t_0 + l tau_i
        # decisions follow the clock itself too, not the sim-time timer alone (one that did
        # not fire would leave its instants to the arbiter's lockstep timeout)
        if self.episode.t0 is not None and t >= self.episode.t0 - TOL:
            self._mark_due(self._last_instant(t))
        if not decision.due:
            # between decisions the readings are taken when the clock wakes the node anyway,
            # so that a decision takes only its instant's on its path
            self.take()
            self._observe_up_to(t)

    def on_wall(self) -> None:
        """The node's wall timer: readings, resending, the parameters' timeout, stalls."""
        now = self.wall()
        self.take()                             # the queues stay short between decisions
        if not self.next.due and self.cursor.t0 is not None:
            self._observe_up_to(self.now())
        if self.next.due:
            # a reading taken here is one whose callback will not run: decide on it here
            self.try_decide()
        self._check_stall(now)
        # under sim time the clock stands at the instant of the last proposal until the
        # arbiter has it: send it again if that takes long (lost while the graph connected)
        last = self.last
        if self.sim_time and last.proposal is not None and self.episode.t0 is not None \
                and now - last.wall >= self.resend_period and self.now() <= last.t + TOL:
            self._out.append(Propose(last.proposal, last.stamp, again=True))
            last.wall = now
        ep = self.episode
        if self.next.due and self.decider.version < ep.version \
                and self.wall() >= ep.deadline:
            self._out.append(Log(
                'warning', f'parameters version {ep.version} did not arrive within '
                f'{self.params_timeout} s: deciding with version {self.decider.version}'))
            ep.version = self.decider.version
            self.try_decide()

    def try_decide(self) -> None:
        """Decide if a decision is due and the readings of its instant are in (a reading
        arrived, or anything else may have made it possible)."""
        ep, decision, rd = self.episode, self.next, self.readings
        if not decision.due or ep.t0 is None or self.decider.version < ep.version:
            self.waiting = False
            return
        self.take()
        found = rd.first_after(ep.t0, self.last.t, decision.since, newest=not self.sim_time)
        # until the readings of the instant are in, the node is woken for them
        self.waiting = True
        if found is None:
            return
        t = found.t
        # under sim time odometry up to t needs the wheel reading of t too
        if self.sim_time and rd.wheels_pending(t):
            return
        self.waiting = False
        self._observe_up_to(t - 2 * TOL)      # the other modules' instants before it
        rd.integrate(t, self.decider, self.clock.dt, self.sim_time)
        mark(f'{self.name}_decide', t)
        # the draws of the instant: the agent stream's (the runner's), or off the grid a
        # stream of the module's own
        k = self.clock.tick(t, ep.t0)
        if k is not None and self.clock.is_due(self.index, k):
            self.stream.instant(k)
            self.decider.rng = self.draws
        else:
            self.decider.rng = self.off_grid
        p = self.decider.decide(found.percept(rd.last_wheels))
        decision.due, self.last.t, self.last.instant = False, t, decision.since
        stamp = self.now()
        self._out.append(Propose(p, stamp))
        self.last.proposal, self.last.stamp, self.last.wall = p, stamp, self.wall()

    # ------------------------------------------------------------------ internals

    def _last_instant(self, t: float) -> float:
        """The module's last decision instant ``t_0 + l tau_i`` at or before ``t``."""
        return self.clock.last_instant(self.index, t, self.episode.t0)

    def _mark_due(self, instant: float) -> None:
        """Under sim time: decide on the readings of decision instant ``instant`` (the
        simulator publishes an instant's readings before the clock reaches it), or on the
        first after it if the clock ran past it; once per instant, whichever of the timer and
        the clock sees it first."""
        decision = self.next
        if instant > decision.marked + TOL:
            decision.marked = instant
            decision.due, decision.since = True, instant
            self.try_decide()

    def _apply_pending_params(self) -> None:
        if self.pending_params is None:
            return
        try:
            self.decider.set_parameters(*self.pending_params)
        except ValueError as exc:
            self._out.append(Log('error', f'ignored parameters: {exc}'))
        self.pending_params = None

    def _observe_up_to(self, limit: float) -> None:
        """At each instant up to ``limit`` at which another module decides and this one does
        not, its features there (:meth:`Decider.observe`: no draw, its state untouched), in
        order, once that instant's readings are in (the learner scores the acting module's
        behaviour density of (6) at the state this module had)."""
        obs, rd = self.cursor, self.readings
        if not self.observes or obs.t0 is None:
            return
        dt = self.clock.dt
        limit = min(limit, obs.end)             # an ended episode: up to its end
        while (tj := obs.t0 + obs.k * dt) <= limit + TOL:
            due_modules = self.clock.due_at(obs.k)
            if self.index in due_modules and tj > self.last.t + TOL:
                return                          # its own decision first
            passed = tj < self.last.t - TOL or tj < rd.integrated - TOL
            if not due_modules or self.index in due_modules or passed:
                obs.k += 1
                continue
            found = rd.at(tj)
            if found is None or rd.wheels_pending(tj):
                return                          # its readings are on their way
            rd.integrate(tj, self.decider, dt, self.sim_time)
            b = self.decider.observe(found.percept(rd.last_wheels))
            self._out.append(PublishObservation(tj, b))
            obs.k += 1

    def _check_stall(self, now: float) -> None:
        """Log once why a decision has been due for long (a stalled lockstep explains
        itself)."""
        ep, decision, rd, stall = self.episode, self.next, self.readings, self.stall
        if ep.t0 is not None and not decision.due and self.sim_time \
                and self._last_instant(self.now()) > self.last.instant + TOL:
            why = f'no decision marked for {self._last_instant(self.now()):.3f}'
        elif ep.t0 is None and rd.camera and rd.camera[-1].t > ep.ended + TOL:
            if rd.camera[-1].t > stall.readings + TOL:
                # readings still come: the robot wanders to its next start, nothing stalls
                stall.readings, stall.since = rd.camera[-1].t, None
                return
            why = f'no start event seen, readings at {rd.camera[-1].t:.3f}'
        elif decision.due and ep.t0 is not None:
            why = 'due'
        else:
            stall.since = None
            return
        if stall.since is None:
            stall.since, stall.said = now, False
        elif not stall.said and now - stall.since >= STALL_WARNING:
            stall.said = True
            cams = [round(c.t, 3) for c in rd.camera][-3:]
            irs = [round(r.t, 3) for r in rd.ir][-3:]
            self._out.append(Log(
                'warning', f'{why}: waiting for {now - stall.since:.1f} s: t0 {ep.t0}, '
                f'clock {self.now():.3f}, due from {decision.since:.3f}, last decision on '
                f'{self.last.t:.3f}, parameters {self.decider.version} (expected '
                f'{ep.version}), last camera {cams}, last ir {irs}'))
