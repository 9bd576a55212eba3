"""When the robot interface lets an episode run: the learner's and the arbiter's gates.

On the real Cyber Rodent the learner learns while the robot wanders to its next start, and the
robot does not move before it has a command. Under sim time the simulator must wait for the
same two things explicitly, or it outruns the graph (a tick takes microseconds):

- **learner gate** (``wait_for_learner``): after an episode ends (and before the first one),
  the next episode starts only once the learner has reported that episode on its progress
  topic (or ``learner_timeout`` wall seconds passed). The start then announces the parameter
  version the learner reached, so that the modules wait for those parameters.
- **graph gate** (before the first episode): the first episode starts only once the node's
  topics have the subscribers the graph will have (the caller says when: ``ready``), or
  ``graph_timeout`` wall seconds passed. A message published before DDS has matched a
  subscriber is not delivered to it: a learner matched late would miss the first rewards and
  not learn the episode, a module the first instants.
- **lockstep** (``lockstep``): after publishing the readings of an instant, the clock stands
  there until a command decided on readings of that instant arrives (its stamp is at or after
  it), or ``command_timeout`` wall seconds passed. The controller (the CLIS arbiter) answers
  every instant once every decision due then is in, so that, as in the headless runner, each
  decision is made on the readings of its instant and acts from that instant on, however slow
  the machine. After a timeout (no controller) the clock runs free until a command arrives.
  With ``hold_periods`` (the controller's decision periods ``tau_i``) the clock stands only at
  the instants ``t_0 + l tau_i`` of the episode: between them the command cannot change (the
  arbiter changes it only on decisions), so the run is the same, with one round trip through
  the graph per decision instead of one per tick.

A pure state machine: times are passed in (wall seconds, any monotonic origin), so the
simulator node and the bridge share it and tests drive it without ROS.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from clis_base.instants import TOL, DecisionClock

__all__ = ['EpisodeGate']

#: Two stamps closer than this [s] are the same instant.
_TOL = TOL


@dataclass
class EpisodeGate:
    """The gates of the module docstring.

    Parameters
    ----------
    wait_for_learner, learner_timeout : bool, float
        Learner gate and its wall timeout [s].
    lockstep, command_timeout : bool, float
        Lockstep and its wall timeout [s].
    resend_period : float
        While waiting for a command, the readings are published again this often [wall s]
        (a message lost while the graph was connecting does not stall the run).
    hold_periods : tuple of float
        Lockstep holds only at ``t_0 + l tau`` for these ``tau`` [s]; empty (or a 0): at every
        instant.
    graph_timeout : float
        Graph gate: wall seconds to wait for the subscribers before the first episode.
    dt : float
        The simulator's tick [s]: the instants of ``hold_periods`` are counted in ticks
        (:class:`~clis_base.instants.DecisionClock`).

    Attributes
    ----------
    state : str
        ``'run'`` (the clock runs), ``'graph'`` (waiting for the graph's subscribers before
        the first episode), ``'learner'`` (waiting to start the next episode) or
        ``'command'`` (waiting for the command of the instant just published).
    free : bool
        Lockstep suspended after a timeout, until the next command.
    learned : tuple of int
        ``(episode, version)`` the learner reported last (``(-1, 0)``: nothing yet).
    """

    wait_for_learner: bool = False
    learner_timeout: float = 30.0
    lockstep: bool = False
    command_timeout: float = 2.0
    resend_period: float = 0.2
    hold_periods: tuple[float, ...] = ()
    graph_timeout: float = 30.0
    dt: float = 0.05

    def __post_init__(self) -> None:
        self.clock = (DecisionClock(self.hold_periods, self.dt)
                      if self.hold_periods and 0.0 not in self.hold_periods else None)
        self.state = 'run'
        self.learned = (-1, 0)
        self._announce: tuple[int, str] | None = None   # (agent_after, agent_state)
        self.episode = 0                 # the episode waited for ('learner') or running
        self.t = -math.inf               # the instant waiting for its command (sim time)
        self.deadline = math.inf         # wall deadline of the current wait
        self.free = False
        self.resend_at = math.inf
        self.t0 = math.nan               # start of the running episode (sim time)
        self.held_at = math.nan          # wall time the held instant's readings went out

    @property
    def holding(self) -> bool:
        """Whether the clock must stand still."""
        return self.state != 'run'

    def first(self, now: float, ready: bool = True) -> bool:
        """Before the first episode: whether to start it at once. Not before the graph is
        ``ready`` (its subscribers matched; :meth:`poll` is told when), then not before the
        learner's first report (episode 0: it is up)."""
        if not ready:
            self.state, self.deadline = 'graph', now + self.graph_timeout
            return False
        return self.ended(0, now)

    def ended(self, episode: int, now: float) -> bool:
        """Episode ``episode`` ended at wall time ``now``: whether to start the next at once."""
        self.episode = episode
        if not self.wait_for_learner or self.learned[0] >= episode:
            self.state = 'run'
            return True
        self.state, self.deadline = 'learner', now + self.learner_timeout
        return False

    def started(self, episode: int, t0: float = math.nan) -> None:
        """Episode ``episode`` started at sim time ``t0``."""
        self.episode, self.t0 = episode, float(t0)

    def holds_at(self, t: float) -> bool:
        """Whether lockstep holds the clock at instant ``t`` (a decision instant)."""
        if self.clock is None or not math.isfinite(self.t0):
            return True
        # decisions at t_0 + l tau_i
        return self.clock.is_instant(t, self.t0)

    def published(self, t: float, now: float) -> None:
        """The readings of sim time ``t`` were published at wall time ``now``."""
        if self.lockstep and not self.free and self.state == 'run' and self.holds_at(t):
            self.t, self.state, self.deadline = t, 'command', now + self.command_timeout
            self.resend_at = now + self.resend_period
            self.held_at = now

    def on_progress(self, episode: int, version: int, values: dict | None = None) -> None:
        """The learner reported ``episode`` (``version`` = its parameter version); ``values``:
        the report's other values, of which ``agent_state`` with ``agent_after`` is kept for
        the start after episode ``agent_after`` (:meth:`announced`)."""
        self.learned = (episode, version)
        values = values or {}
        if 'agent_state' in values and 'agent_after' in values:
            self._announce = (int(values['agent_after']), str(values['agent_state']))

    def announced(self, episode: int) -> str | None:
        """The text the learner asked the start of ``episode`` to carry (the agent's random
        stream where the learner has it after episode ``episode - 1``, docs/design.md §6): the
        simulator passes it on as ``agent_state`` without reading it. None if none."""
        a = self._announce
        return a[1] if a is not None and a[0] == episode - 1 else None

    def on_command(self, stamp: float | None, now: float = math.nan) -> float | None:
        """A command arrived at wall time ``now``, decided on readings at sim time ``stamp``
        (None: unstamped). Returns the sensor-to-command round trip [wall s] when it answers
        the instant the clock is held at (from the first publication of that instant's
        readings; NaN without ``now``), else None."""
        if stamp is None or stamp >= self.t - _TOL:
            self.free = False
            if self.state == 'command':
                self.state = 'run'
                return now - self.held_at
        return None

    @property
    def version(self) -> int:
        """The learner's parameter version (announced at the next start)."""
        return self.learned[1]

    def poll(self, now: float, ready: bool = True) -> tuple[str | None, str | None]:
        """At wall time ``now``: ``(action, warning)``; action ``'start'`` = start the next
        episode now, ``'go'`` = let the clock run, ``'resend'`` = publish the readings of the
        instant again, None = keep waiting. ``warning`` says which wait timed out. ``ready``:
        whether the graph's subscribers are matched now (graph gate)."""
        if self.state == 'graph':
            if not ready and now < self.deadline:
                return None, None
            warning = None if ready else (f'the graph was not connected within '
                                          f'{self.graph_timeout} s: starting anyway')
            return ('start' if self.ended(0, now) else None), warning
        if self.state == 'learner':
            if self.learned[0] >= self.episode:
                self.state = 'run'
                return 'start', None
            if now >= self.deadline:
                self.state = 'run'
                return 'start', (f'the learner did not report episode {self.episode} within '
                                 f'{self.learner_timeout} s: starting the next one')
        elif self.state == 'command':
            if now >= self.deadline:
                self.state, self.free = 'run', True
                return 'go', (f'no command for t = {self.t:.3f} s (episode {self.episode}) '
                              f'within {self.command_timeout} s: the clock runs free until '
                              'one arrives')
            if now >= self.resend_at:
                self.resend_at = now + self.resend_period
                return 'resend', None
        return None, None
