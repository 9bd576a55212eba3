"""When a module node decides, on which readings, with which draws, and what it publishes.

A module node (:mod:`clis_modules.module_node`) is the subscriptions, the publishers and the
timers of one module instance; :class:`ModuleSchedule` is everything it decides with them,
without ROS (no rclpy, no message types: plain values in, plain :data:`Action` values out),
so that it is tested like :class:`~clis_modules.core.decider.Decider`, which it drives.

Decision instants (paper II-E: module i decides "asynchronously", every ``tau_i``): under sim
time module i decides at ``t_0 + l tau_i`` of the running episode
(:class:`~cr_sim.core.instants.DecisionClock`), once per instant, whichever of its timer and
the clock sees the instant first (:meth:`ModuleSchedule.on_timer`,
:meth:`ModuleSchedule.on_clock`), on the readings of that instant, or of the first instant
after it if the clock ran past it; in real time on the newest readings at every timer.
A decision waits until a reading of each sensor the module reads has arrived for its instant
(:class:`Readings`); :attr:`ModuleSchedule.waiting` says that the node should be woken for
them.

Draws: at an instant ``t_0 + l tau_i`` the headless runner's agent stream ``(seed, 2)``,
replayed over the condition's decision instants (:mod:`cr_sim.core.streams`), so that the
proposals are the runner's bit for bit; off the tick grid (real time) a stream of the
module's own per episode (:func:`off_grid_rng`).

Observations: with other modules, at each instant at which another module decides and this
one does not, its features there (:meth:`Decider.observe`; the behaviour's state of (6) for
the learner), in order, once that instant's readings are in.

Parameters received during an episode wait for its end; a start that announces a parameter
version makes the first decision wait for it, at most ``params_timeout`` wall seconds.

The node calls an entry point (a reading, an episode event, parameters, its timer, the clock,
its wall timer) and then publishes what :meth:`ModuleSchedule.drain` gives, in order:
:class:`Propose`, :class:`Observe`, :class:`ResetTimer`, :class:`Say`. The clock, the wall
clock and the taking of the readings waiting in the node's queues are callables the node
passes in (a test passes its own).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
import time
import zlib

from cr_sim.core.instants import TOL, DecisionClock
from cr_sim.ros_support.trace import mark
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.decider import Decider, Percept
from clis_modules.core.modules import ModuleCore
from clis_modules.core.plugin import parse_condition
from clis_modules.core.proposal import Proposal
from clis_modules.core.streams import AgentStream, module_draws

__all__ = ['READINGS_DEPTH', 'STALL_WARNING', 'Propose', 'Observe', 'ResetTimer', 'Say',
           'Action', 'Readings', 'EpisodeState', 'NextDecision', 'LastDecision', 'Observed',
           'Stall', 'ModuleSchedule', 'off_grid_rng']

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
class Observe:
    """Publish the module's features ``features`` at instant ``t`` [s] (no decision there)."""

    t: float
    features: np.ndarray


@dataclass(frozen=True)
class ResetTimer:
    """Restart the decision timer now: its phase becomes ``t_0 + l tau_i``."""


@dataclass(frozen=True)
class Say:
    """Log ``text`` at ``level`` (``'warning'`` or ``'error'``)."""

    level: str
    text: str


Action = Propose | Observe | ResetTimer | Say


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
    marked: float = -math.inf       # the grid instant last marked due
    align: float | None = None      # restart the timer when the clock reaches this


@dataclass
class LastDecision:
    """The last decision and what was sent of it."""

    t: float = -math.inf            # stamp of its readings
    grid: float = -math.inf         # the instant it was due from
    proposal: Proposal | None = None
    stamp: float = math.nan         # clock time it was decided at
    wall: float = -math.inf         # wall time it was last sent


@dataclass
class Observed:
    """The episode whose other modules' instants are observed."""

    t0: float | None = None         # its start (None before the first)
    end: float = math.inf           # observed up to here (inf while it runs)
    k: int = 0                      # the next tick to observe at


@dataclass
class Stall:
    """The stall diagnosis: since when something waits, and whether it was said."""

    since: float | None = None      # wall time
    said: bool = False


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
    camera : deque of (t, destination bearing, landmark bearings)
    ir : deque of (t, d_o, every ray)
        Also the instants of a module reading no camera.
    wheels : deque of (t, v_left, v_right)
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
        self.camera.append((t, bearings.get('destination', math.nan), lm))

    def add_ir(self, t: float, ranges: np.ndarray) -> None:
        """Every IR ray [m] of instant ``t`` (``d_o``: the nearest)."""
        self.ir.append((t, float(np.min(ranges)) if ranges.size else math.inf, ranges))

    def add_wheels(self, t: float, v: np.ndarray) -> None:
        """Wheel velocities ``(v_left, v_right)`` [m/s] of instant ``t``."""
        if v.size == 2:
            self.wheels.append((t, float(v[0]), float(v[1])))

    def wheels_pending(self, t: float) -> bool:
        """Whether the module reads the wheels and their reading of ``t`` has not arrived (it
        travels on its own topic and may come after the others)."""
        return self.reads_wheels and self.integrated < t - TOL \
            and not (self.wheels and self.wheels[-1][0] >= t - TOL)

    def first_after(self, t0: float, last: float, since: float,
                    newest: bool) -> tuple | None:
        """An instant of the episode started at ``t0``, after ``last`` and not before
        ``since``, with a reading of each of camera and IR the module reads: ``(t, dest
        bearing, landmark bearings, d_o, rays)`` (NaN, None for a sensor it does not read);
        the first such instant, or with ``newest`` the newest."""
        if self.reads_camera:
            primary = self.camera
            ir = ({round(t, 6): (d_o, rays) for t, d_o, rays in self.ir}
                  if self.reads_ir else None)
        else:
            primary = [(t, math.nan, self.unseen, (d_o, rays)) for t, d_o, rays in self.ir]
            ir = None
        found = None
        for t, dest, lm, *rest in reversed(primary):
            if t < t0 - TOL or t <= last + TOL or t < since - TOL:
                break
            got = rest[0] if rest else (ir.get(round(t, 6)) if ir is not None
                                        else (math.nan, None))
            if got is not None:
                found = (t, dest, lm, *got)
                if newest:
                    break
        return found

    def at(self, t: float) -> tuple | None:
        """The readings of instant ``t`` the module reads: ``(dest bearing, landmark
        bearings, d_o, rays)``, or None while one has not arrived."""
        cam = None
        if self.reads_camera:
            cam = next(((dest, lm) for tc, dest, lm in reversed(self.camera)
                        if abs(tc - t) <= TOL), None)
            if cam is None:
                return None
        ir = (math.nan, None)
        if self.reads_ir:
            ir = next(((d_o, rays) for ti, d_o, rays in reversed(self.ir)
                       if abs(ti - t) <= TOL), None)
            if ir is None:
                return None
        dest, lm = cam if cam is not None else (math.nan, self.unseen)
        return dest, lm, *ir

    def integrate(self, t: float, decider: Decider, dt: float, on_ticks: bool) -> None:
        """Odometry: the wheel velocities of every step that ended after the last reading
        integrated, up to ``t``, each held since the previous reading; ``on_ticks`` (sim time):
        held a whole number of ticks ``dt``, as the headless runner integrates, when the
        stamps' difference is that to rounding."""
        while self.wheels and self.wheels[0][0] <= t + TOL:
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
        self.observed = Observed()
        self.stall = Stall()
        self.pending: tuple | None = None   # parameters received during an episode
        #: A due decision waits for readings of its instant: wake the node for them.
        self.waiting = False
        self._out: list[Action] = []

    def drain(self) -> list[Action]:
        """What to publish, in order, since the last call."""
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
        self._apply_pending()
        ep, due = self.episode, self.next
        ep.t0 = t0
        ep.version = int(values.get('params_version', 0))
        ep.deadline = self.wall() + self.params_timeout
        self.readings.integrated = t0
        self.observed = Observed(t0=t0)
        self._out.append(ResetTimer())
        due.marked = -math.inf
        if not self.sim_time:
            due.due, due.since = True, -math.inf
        else:
            now = self.now()
            if now < t0 - TOL:                  # the clock has not reached the start yet
                due.align = t0
                self._mark_due(t0)
            elif self._grid(now) >= now - TOL:  # the clock stands at a decision instant
                self._mark_due(self._grid(now))
            else:                               # (re)started between two: the next one
                due.marked = self._grid(now)
                due.align = due.marked + self.period
        self.try_decide()

    def end(self, t: float) -> None:
        """The episode ended at ``t`` (``reached``, ``timeout``, ``reset``): silent until the
        next start; the agent stream keeps the draws of its instants before ``t``."""
        ep = self.episode
        if ep.t0 is not None and (k_end := self.clock.tick(t, ep.t0)) is not None:
            self.stream.end_episode(k_end)
        if ep.t0 is not None:
            self.observed.end = t - 2 * TOL     # observed up to the end, not at it
        ep.t0, self.next.due, ep.ended = None, False, t
        # the end event may overtake the readings of the episode's last instants (their own
        # topics): what is in goes out now, the rest as it comes (clock, wall timer)
        self.take()
        self._observe_pending(t)

    def set_parameters(self, name: str, w: ArrayLike, W: ArrayLike,  # noqa: N803
                       sigma: float, version: int) -> None:
        """Parameters from the learner: applied between episodes, before the first decision
        of one, or when they are the version the episode was announced with (a module
        restarted mid-episode gets them late); else at the next start."""
        if name != self.name:
            self._out.append(Say('error', f'ignored parameters of {name!r} on my topic'))
            return
        self.pending = (w, W, sigma, version)
        ep = self.episode
        if ep.t0 is None or self.last.t < ep.t0 or version <= ep.version:
            self._apply_pending()
            self.try_decide()

    def on_timer(self) -> None:
        """The decision timer (period ``tau_i``)."""
        if self.episode.t0 is None:
            return
        if self.sim_time:
            self._mark_due(self._grid(self.now()))
        else:                                   # real time: decide on the newest readings
            self.next.due, self.next.since = True, -math.inf
            self.try_decide()

    def on_clock(self, t: float) -> None:
        """The clock moved to ``t`` (sim time)."""
        due = self.next
        if due.align is not None and t >= due.align - TOL:
            due.align = None
            self._out.append(ResetTimer())      # the timer's phase: t_0 + l tau_i
        # decisions follow the clock itself too, not the sim-time timer alone (one that did
        # not fire would leave its instants to the arbiter's lockstep timeout)
        if self.episode.t0 is not None and t >= self.episode.t0 - TOL:
            self._mark_due(self._grid(t))
        if not due.due:
            # between decisions the readings are taken when the clock wakes the node anyway,
            # so that a decision takes only its instant's on its path
            self.take()
            self._observe_pending(t)

    def on_wall(self) -> None:
        """The node's wall timer: readings, resending, the parameters' timeout, stalls."""
        now = self.wall()
        self.take()                             # the queues stay short between decisions
        if not self.next.due and self.observed.t0 is not None:
            self._observe_pending(self.now())
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
            self._out.append(Say(
                'warning', f'parameters version {ep.version} did not arrive within '
                f'{self.params_timeout} s: deciding with version {self.decider.version}'))
            ep.version = self.decider.version
            self.try_decide()

    def try_decide(self) -> None:
        """Decide if a decision is due and the readings of its instant are in (a reading
        arrived, or anything else may have made it possible)."""
        ep, due, rd = self.episode, self.next, self.readings
        if not due.due or ep.t0 is None or self.decider.version < ep.version:
            self.waiting = False
            return
        self.take()
        found = rd.first_after(ep.t0, self.last.t, due.since, newest=not self.sim_time)
        # until the readings of the instant are in, the node is woken for them
        self.waiting = True
        if found is None:
            return
        t, dest, lm, d_o, rays = found
        # under sim time odometry up to t needs the wheel reading of t too
        if self.sim_time and rd.wheels_pending(t):
            return
        self.waiting = False
        self._observe_pending(t - 2 * TOL)      # the other modules' instants before it
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
        p = self.decider.decide(Percept(t, dest, d_o, lm, rays, rd.last_wheels))
        due.due, self.last.t, self.last.grid = False, t, due.since
        stamp = self.now()
        self._out.append(Propose(p, stamp))
        self.last.proposal, self.last.stamp, self.last.wall = p, stamp, self.wall()

    # ------------------------------------------------------------------ internals

    def _grid(self, t: float) -> float:
        """The last decision instant ``t_0 + l tau_i`` at or before ``t``."""
        return self.clock.last_instant(self.index, t, self.episode.t0)

    def _mark_due(self, g: float) -> None:
        """Under sim time: decide on the readings of grid instant ``g`` (the simulator
        publishes an instant's readings before the clock reaches it), or on the first after
        it if the clock ran past it; once per grid instant, whichever of the timer and the
        clock sees it first."""
        due = self.next
        if g > due.marked + TOL:
            due.marked = g
            due.due, due.since = True, g
            self.try_decide()

    def _apply_pending(self) -> None:
        if self.pending is None:
            return
        try:
            self.decider.set_parameters(*self.pending)
        except ValueError as exc:
            self._out.append(Say('error', f'ignored parameters: {exc}'))
        self.pending = None

    def _observe_pending(self, limit: float) -> None:
        """At each instant up to ``limit`` at which another module decides and this one does
        not, its features there (:meth:`Decider.observe`: no draw, its state untouched), in
        order, once that instant's readings are in (the learner scores the acting module's
        behaviour density of (6) at the state this module had)."""
        obs, rd = self.observed, self.readings
        if not self.observes or obs.t0 is None:
            return
        dt = self.clock.dt
        limit = min(limit, obs.end)             # an ended episode: up to its end
        while (tj := obs.t0 + obs.k * dt) <= limit + TOL:
            due = self.clock.due_at(obs.k)
            if self.index in due and tj > self.last.t + TOL:
                return                          # its own decision first
            passed = tj < self.last.t - TOL or tj < rd.integrated - TOL
            if not due or self.index in due or passed:
                obs.k += 1
                continue
            found = rd.at(tj)
            if found is None or rd.wheels_pending(tj):
                return                          # its readings are on their way
            rd.integrate(tj, self.decider, dt, self.sim_time)
            dest, lm, d_o, rays = found
            b = self.decider.observe(Percept(tj, dest, d_o, lm, rays, rd.last_wheels))
            self._out.append(Observe(tj, b))
            obs.k += 1

    def _check_stall(self, now: float) -> None:
        """Say once why a decision has been due for long (a stalled lockstep explains
        itself)."""
        ep, due, rd, stall = self.episode, self.next, self.readings, self.stall
        if ep.t0 is not None and not due.due and self.sim_time \
                and self._grid(self.now()) > self.last.grid + TOL:
            why = f'no decision marked for {self._grid(self.now()):.3f}'
        elif ep.t0 is None and rd.camera and rd.camera[-1][0] > ep.ended + TOL:
            why = f'no start event seen, readings at {rd.camera[-1][0]:.3f}'
        elif due.due and ep.t0 is not None:
            why = 'due'
        else:
            stall.since = None
            return
        if stall.since is None:
            stall.since, stall.said = now, False
        elif not stall.said and now - stall.since >= STALL_WARNING:
            stall.said = True
            cams = [round(t, 3) for t, *_ in rd.camera][-3:]
            irs = [round(t, 3) for t, *_ in rd.ir][-3:]
            self._out.append(Say(
                'warning', f'{why}: waiting for {now - stall.since:.1f} s: t0 {ep.t0}, '
                f'clock {self.now():.3f}, due from {due.since:.3f}, last decision on '
                f'{self.last.t:.3f}, parameters {self.decider.version} (expected '
                f'{ep.version}), last camera {cams}, last ir {irs}'))
