"""Where the agent's random stream stands after each episode: kept by the learner, carried by
the next start.

Every draw of a run's modules and arbiter comes from one generator, the *agent stream*
(:class:`~clis_base.agent_stream.AgentStream`, ``default_rng([seed, 2])``), in the headless
runner's call order; the module and arbiter nodes each make every call of the run in that
order, so each holds the stream where the others do (docs/design.md §6, "Random streams"). A
node that starts mid-run (restarted, or a resumed run) needs the stream's state at the next
episode's start. The learner keeps it: what an episode draws depends only on its decision
instants and its length, which the learner sees in the ``start`` and end events, so
:class:`AgentState` replays the episode's instants at each end (as the nodes do) and the
learner's progress report asks the next start to carry the state (``agent_state``, for the
start after episode ``agent_after``). The learner reports before the simulator starts the next
episode (the learner gate), and its checkpoint keeps the state, so a resumed run's first start
carries it too. The simulator passes the text on without reading it: the agent stays the
agent's.

The stream is followed only while every episode's end is on the tick grid of its start (the
simulator under ``clis run``); one off the grid (a robot's own clock), or an episode whose
start was not seen, and the state is unknown: nothing is announced from then on, and the
nodes go on with their own streams.

Pure: no ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

from clis_base.agent_stream import AgentStream
from clis_base.instants import DecisionClock
import numpy as np

__all__ = ['AgentState']


class AgentState:
    """The agent stream's state after each episode (module docstring).

    Parameters
    ----------
    seed : int
        The run's seed (the stream is ``default_rng([seed, 2])``).
    periods : sequence of float
        The condition's decision periods ``tau_i`` [s], in module order.
    dt : float
        The tick [s] (a ``start`` event's ``dt`` replaces it).
    selection : str
        ``arbiter.selection`` (``episode`` or ``decision``).
    state : str, optional
        :meth:`AgentStream.state` after episode ``after`` (a resumed learner's checkpoint);
        '' = the stream's own start (a run from episode 1, ``after = 0``).
    after : int
        The episode the state follows.
    """

    def __init__(self, seed: int, periods: Sequence[float], dt: float, selection: str,
                 state: str = '', after: int = 0) -> None:
        self.periods = [float(p) for p in periods]
        self.stream = AgentStream(np.random.default_rng([seed, 2]), len(self.periods),
                                  selection, DecisionClock(self.periods, dt))
        if state:
            self.stream.set_state(state)
        self.after: int | None = after         # None: unknown from here on
        self.running: int | None = None        # the episode started and not ended
        self.t0 = math.nan

    def start(self, episode: int, t0: float, dt: float) -> None:
        """Episode ``episode`` started at ``t0`` with tick ``dt`` (an episode at or before the
        state's, from the ``episode`` topic's history, changes nothing)."""
        if self.after is None or episode <= self.after:
            return
        if episode != self.after + 1:
            self.after = None                   # an episode's start was not seen: unknown
            return
        if dt != self.stream.clock.dt:
            self.stream.clock = DecisionClock(self.periods, dt)
        self.stream.begin_episode()
        self.running, self.t0 = episode, float(t0)

    def end(self, episode: int, t: float) -> None:
        """Episode ``episode`` ended at ``t``: the stream after its instants ``k < k_end`` (an
        end at or before the state's episode changes nothing)."""
        if self.after is None or (self.running is None and episode <= self.after):
            return
        if episode != self.running:             # the end of an episode not seen starting
            self.after = self.running = None
            return
        k_end = self.stream.clock.tick(t, self.t0)
        self.running = None
        if k_end is None:                       # off the tick grid: the nodes' draws differ
            self.after = None
            return
        self.stream.end_episode(k_end)
        self.after = episode

    def announcement(self) -> dict[str, object]:
        """What the learner's report asks the next start to carry: ``agent_state`` and
        ``agent_after``; empty when the state is unknown or at the run's own start."""
        if self.after is None or self.running is not None or self.after == 0:
            return {}
        return {'agent_state': self.stream.state(), 'agent_after': self.after}
