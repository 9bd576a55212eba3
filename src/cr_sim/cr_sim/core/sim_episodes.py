"""The simulator's episodes, tick by tick: everything the ``sim`` node does but messaging.

:class:`SimEpisodes` drives one :class:`~cr_sim.core.sim.Simulator` through the episodes of a
run as the ``sim`` node (:mod:`cr_sim.sim_node`) serves them to the graph; the node only turns
its values into messages and its inputs into calls:

- **starts** from the start rule (:func:`~cr_sim.core.starts.draw_start`) on the starts'
  stream ``(seed, 1)``, the simulator on its own ``(seed, 0)``; the agent's stream is the
  agent's: a start carries, as ``agent_state``, the text the learner's last report asked it to
  carry (the learner keeps that stream's state, docs/design.md §6, "Random streams"), unread;
- **the clock**: ``/clock`` is monotonic over the run; episode ``n + 1`` starts one tick after
  episode ``n`` ended, ``T_{n+1} = T_n + t_end,n + dt``, so that every stamp belongs to one
  episode only; sim time is ``T_n + k dt`` at tick ``k`` of episode ``n``;
- **rewards**: each tick's reward ``r_k`` of the simulator into the return ``R = sum_k r_k``
  (:class:`~cr_sim.core.episodes.EpisodeBook`, shared with the real robot's bridge);
- **ends**: ``reached`` / ``timeout`` from the simulator, ``reset`` from outside; each reported
  once, with the resume state the next episode starts from;
- **resume state**: the robot's pose, wheels and contact, the clock of the next start, then
  the simulator's two random streams (:meth:`SimEpisodes.resume_state`), so that a run stopped
  after episode ``n`` and resumed from it (``first_episode = n + 1``) makes the episodes,
  rewards and stamps of the run that was not stopped, to the bit;
- **commands**: the wheels in force, replaced by a stop when older than ``watchdog`` s of sim
  time; under lockstep a command decided in an earlier episode is stale;
- **holds** (:class:`~cr_sim.core.gate.EpisodeGate`): the graph gate before the first episode,
  the learner gate before each start, lockstep at the decision instants, and whether the clock
  may run unwatched between them (:attr:`SimEpisodes.quiet`).

**World mode** (``episodes=False``, the node's ``node.episodes: false``): a plain robot world
for a node that makes the episodes itself from the robot's own sensors (the robot adapter of
the standard path). One unending run from the first start (the start rule as above): an
``endless`` :class:`~cr_sim.core.sim.Simulator` (the goal and the time limit end nothing),
never teleported (:meth:`SimEpisodes.start` places the robot once, :meth:`SimEpisodes.reset`
does nothing), no events, no rewards summed; the learner gate is switched off (the graph gate
before the run still holds). Lockstep, if on, holds the clock at every tick until a command
stamped at or after it arrives (the world does not know the controller's decision instants: the
robot adapter answers every reading, at a decision instant with the decision). The clock, the
commands, the watchdog and the readings are as above.

Pure: no ROS; wall time is read from an injected clock (``time.monotonic`` by default).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
import time

from clis_base.instants import DecisionClock
from clis_base.params import ConfigError
import numpy as np
from numpy.typing import ArrayLike

from cr_sim.core.arena import Arena
from cr_sim.core.episodes import EpisodeBook, Event, format_resume_state, parse_resume_state
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.observation import Observation
from cr_sim.core.sim import SimParams, Simulator, StepResult
from cr_sim.core.starts import draw_start

__all__ = ['GRAPH_POLL', 'READINGS', 'SimEpisodes']

#: Before the first episode, the graph's subscribers are looked at this often [wall s].
GRAPH_POLL = 0.05
#: ``'tick'``: the IR and the camera are read (their noise drawn) at every tick;
#: ``'instants'``: only at the decision instants, as the headless runner reads them.
READINGS = ('tick', 'instants')
#: Values of a resume state before its streams: pose (3), wheels (2), contact, clock.
_RESUME_VALUES = 7


class SimEpisodes:
    """The simulator's episodes (module docstring).

    Parameters
    ----------
    arena : Arena
    params : SimParams
    gate : EpisodeGate
        Its graph, learner and lockstep gates (``dt`` = ``params.episode.dt``).
    seed : int
        Of the streams ``(seed, 0)``, ``(seed, 1)``, ``(seed, 2)``.
    start : str
        Where episodes start (:func:`~cr_sim.core.starts.draw_start`).
    first_episode : int
        Number of the first episode (> 1: a resumed run, with ``resume_state``).
    resume_state : str
        ``''`` or :meth:`resume_state` of the episode before ``first_episode``.
    auto_reset : bool
        Start the next episode when one ends (else the clock runs on, the robot still, until
        :meth:`reset`).
    watchdog : float
        A command older than this [s of sim time] is replaced by a stop.
    decision_periods : sequence of float
        The controller's decision periods (0 entries ignored): the decision instants of the
        ``instants`` readings.
    readings : str
        One of :data:`READINGS`.
    episodes : bool
        Serve episodes (else world mode, module docstring: ``gate``'s learner gate is switched
        off, its lockstep holds at every tick).
    clock : callable
        Wall time [s], monotonic.

    Raises
    ------
    ConfigError
        ``instants`` readings without decision periods, or an unreadable ``resume_state``.
    """

    def __init__(self, arena: Arena, params: SimParams, gate: EpisodeGate, *, seed: int = 0,
                 start: str = 'A', first_episode: int = 1, resume_state: str = '',
                 auto_reset: bool = True, watchdog: float = 2.0,
                 decision_periods: Sequence[float] = (), readings: str = 'tick',
                 episodes: bool = True, clock: Callable[[], float] = time.monotonic) -> None:
        self.arena = arena
        self.params = params
        self.gate = gate
        self.now = clock
        self.start_mode = start
        self.auto_reset = auto_reset
        self.watchdog = watchdog
        self.readings = readings
        self.dt = params.episode.dt
        self.episodes = episodes
        if not episodes:                    # world mode: nothing waits for a learner
            gate.wait_for_learner = False
            gate.hold_periods, gate.clock = (), None    # lockstep: held at every tick
        self.placed = False                 # world mode: the robot stands at its start
        # the headless runner's streams: the simulator (seed, 0) and the starts (seed, 1), each
        # continuous over the episodes (a resumed run sets them from resume_state)
        self.sim = Simulator(arena, params, np.random.default_rng([seed, 0]),
                             endless=not episodes)
        self.start_rng = np.random.default_rng([seed, 1])
        periods = [p for p in decision_periods if p > 0.0]
        self.clock = DecisionClock(periods, self.dt) if periods else None
        if readings == 'instants' and self.clock is None:
            raise ConfigError("node.readings = 'instants' needs node.lockstep_periods")
        self.u = np.zeros(2)                # the command in force, since u_time (sim.t)
        self.u_time = -np.inf
        self.book = EpisodeBook(gate, first_episode)
        self.time_offset = 0.0              # T_n: /clock at the running episode's start
        if resume_state:
            self._resume(resume_state)
        # sensor-to-command round trips of the held instants [wall s], the newest 100,000
        self.round_trips: deque[float] = deque(maxlen=100_000)
        self.graph_check_at = 0.0           # next look at the graph's subscribers (wall)

    # ------------------------------------------------------------------ time

    @property
    def episode(self) -> int:
        """The last episode started (``first_episode - 1`` before the first)."""
        return self.book.episode

    @property
    def sim_time(self) -> float:
        """Sim time since the run started, ``T_n + t`` (monotonic across episodes)."""
        return self.time_offset + self.sim.t

    def _next_offset(self) -> float:
        """``T_{n+1} = T_n + (t_end + dt)``: the next episode starts one tick after the end."""
        return self.time_offset + (self.sim.t + self.dt)

    # ------------------------------------------------------------------ resume state

    def resume_state(self) -> str:
        """What the next episode starts from, exactly (``node.resume_state``): the robot's
        pose, wheels and contact (:meth:`Simulator.carried`) and the clock, as hex floats,
        then the random streams (the simulator's, the starts'), as URL-safe base64 of their
        JSON (:func:`~cr_sim.core.episodes.format_resume_state`)."""
        streams = {'sim': self.sim.random_state(), 'starts': self.start_rng.bit_generator.state}
        return format_resume_state((*self.sim.carried(), self._next_offset()), streams)

    def _resume(self, text: str) -> None:
        """Stand where the episode before ``first_episode`` left the robot, the clock and the
        random streams."""
        try:
            values, streams = parse_resume_state(text, _RESUME_VALUES)
            self.sim.carry(values[:6])
            self.sim.set_random_state(streams['sim'])
            self.start_rng.bit_generator.state = streams['starts']
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f'node.resume_state = {text!r}: {exc}') from None
        self.time_offset = values[6]

    # ------------------------------------------------------------------ episodes

    def first(self, ready: bool = True) -> bool:
        """Before the first episode: whether to start it now (``ready``: the graph's
        subscribers are matched; else the graph gate holds it)."""
        return self.book.first(self.now(), ready)

    def start(self) -> Event | None:
        """Start the next episode: its ``start`` event (``episode``, ``start``, ``pose``,
        ``params_version`` under the learner gate, ``dt``, then ``agent_state`` if the learner
        announced one for it (:meth:`~cr_sim.core.gate.EpisodeGate.announced`)). World mode:
        place the robot at its start the first time, nothing after; no event (None)."""
        if not self.episodes and self.placed:
            return None
        if self.book.started_any:           # not this run's first: one tick after the end
            self.time_offset = self._next_offset()
        start, heading = draw_start(self.start_mode, self.arena, self.start_rng)
        self.sim.reset(start=start, heading=heading)
        self.u[:] = 0.0
        self.u_time = -np.inf
        if not self.episodes:
            self.placed = True
            return None
        ev = self.book.start(self.sim_time, start=start,
                             pose=' '.join(f'{p:.3f}' for p in self.sim.pose))
        ev.values['dt'] = repr(self.dt)
        if (announced := self.gate.announced(self.book.episode)) is not None:
            ev.values['agent_state'] = announced
        return ev

    def step(self) -> StepResult | None:
        """One tick: the command in force (a stop after ``watchdog``) for ``dt``, its reward
        into the return (not in world mode: no rewards); None when the episode is over and
        waits for :meth:`reset` (the clock runs on by a tick)."""
        if self.sim.done:
            self.time_offset += self.dt
            return None
        u = self.u if self.sim.t - self.u_time <= self.watchdog else np.zeros(2)
        res = self.sim.step(u)
        if self.episodes:
            self.book.add(res.reward)
        return res

    def end(self, name: str) -> Event | None:
        """End the running episode (``reached``, ``timeout``, ``reset``): its event, with the
        ``resume_state`` of the next start; None if none runs (an end is reported once)."""
        if not self.book.running:
            return None
        return self.book.end(name, self.sim_time, self.sim.t, resume_state=self.resume_state())

    def finish(self, res: StepResult) -> tuple[Event | None, bool]:
        """After :meth:`step`: the end event of an episode the tick ended (else None), and
        whether to start the next one now (``auto_reset``, and the learner gate open)."""
        if not res.done:
            return None, False
        ev = self.end('reached' if res.reached else 'timeout')
        return ev, self.auto_reset and self.book.release(self.now())

    def reset(self) -> Event | None:
        """End the running episode from outside (the ``reset`` service; the next one starts
        at once, whatever the clock held for): its event, None if none runs. World mode:
        nothing (None)."""
        if not self.episodes:
            return None
        self.gate.state = 'run'
        return self.end('reset')

    # ------------------------------------------------------------------ readings, commands

    def readings_now(self, readings: bool = True) -> tuple[Observation | None, np.ndarray]:
        """``(observation, wheels)`` of the current tick; the observation None when the IR
        and the camera are not read now (``instants``: off the decision instants, and not at
        the tick an episode ends on, ``readings`` False)."""
        if self.readings == 'instants' and not (
                readings and self.clock.is_instant(self.sim.t, 0.0)):
            return None, np.array(self.sim.carried()[3:5])
        obs = self.sim.observe()
        return obs, obs.wheels

    def published(self, t: float) -> None:
        """The readings of sim time ``t`` went out (lockstep may hold the clock there)."""
        self.gate.published(t, self.now())

    def stale(self, stamp: float | None) -> bool:
        """Under lockstep, whether a command stamped ``stamp`` was decided in an earlier
        episode (it is ignored)."""
        return bool(self.episodes and self.gate.lockstep and stamp
                    and stamp < self.book.t0 - 1e-6)

    def command(self, u: ArrayLike, stamp: float | None) -> tuple[float, float | None]:
        """The wheels ``u`` (clamped by the simulator) are in force from now on:
        ``(held, round_trip)``, the instant the clock was held at and the sensor-to-command
        round trip [wall s] when ``u`` answers it (else None)."""
        self.u = u
        self.u_time = self.sim.t
        held = self.gate.t
        rtt = self.gate.on_command(stamp, self.now())
        if rtt is not None:
            self.round_trips.append(rtt)
        return held, rtt

    def round_trip_summary(self) -> str | None:
        """p50, p99 and max of the round trips kept; None without any."""
        if not self.round_trips:
            return None
        rtt = np.array(self.round_trips) * 1e3
        return (f'sensor-to-command round trip over the last {rtt.size} held instants: p50 '
                f'{np.percentile(rtt, 50):.2f} ms, p99 {np.percentile(rtt, 99):.2f} ms, max '
                f'{rtt.max():.2f} ms')

    # ------------------------------------------------------------------ holds

    @property
    def holding(self) -> bool:
        """Whether the clock stands still (:class:`~cr_sim.core.gate.EpisodeGate`)."""
        return self.gate.holding

    @property
    def quiet(self) -> bool:
        """Lockstep at the decision instants only, clock running: until the next instant the
        clock waits for no message (the controller's command cannot change before it), so the
        node need not serve its callbacks at every tick."""
        g = self.gate
        return g.lockstep and not g.free and bool(g.hold_periods) \
            and 0.0 not in g.hold_periods

    def check_hold(self, missing: Callable[[], list[str]]
                   ) -> tuple[str | None, list[tuple[str, str]]]:
        """While holding: ``(action, said)``, the gate's action (``'start'``: start the next
        episode, ``'resend'``: publish the readings again, ``'go'``, None) and what to log,
        ``(level, text)``. Before the first episode, ``missing()`` (the graph's subscribers
        not matched yet; not free to ask) is asked every :data:`GRAPH_POLL` s."""
        said: list[tuple[str, str]] = []
        ready = True
        if self.gate.state == 'graph':          # the graph's subscribers not all matched yet
            if self.now() < self.graph_check_at:
                return None, said
            self.graph_check_at = self.now() + GRAPH_POLL
            lacking = missing()
            ready = not lacking
            if ready:
                said.append(('info', 'the graph is connected (node.start_subscribers)'))
            elif self.now() >= self.gate.deadline:
                said.append(('warning', 'not matched: ' + ', '.join(lacking)))
        action, warning = self.book.poll(self.now(), ready)
        if warning:
            said.append(('warning', warning))
        return action, said
