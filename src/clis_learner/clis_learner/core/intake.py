"""The learner's episode logic over its input streams, without ROS (live node and bags alike).

:class:`EpisodeStream` is what the learner node does with the records of its topics (module
proposals, the arbiter's actions and draws, rewards, episode events), in whatever order they
arrive: they go into a :class:`~clis_learner.core.memory.StreamBuffer`; an episode seen from its
``start`` event is cut out of it when it has ended and is *closed*, and the same
:class:`~clis_learner.core.learner.Learner` as the headless runner learns from it. The learner
node (:mod:`clis_learner.learner_node`) feeds it live, closing an ended episode once its last
reward arrived (or a wall-clock timeout); ``clis learn`` feeds it the same records decoded from
a bag by the same conversions, closing an ended episode at the next ``start`` or at the end of
the bag. Either way the same records give the same parameters.

An episode is learned only if the stream holds it from its start: its first reward arrived
within the shortest decision period after the start (the learner came up late, or was
restarted, otherwise).

It is the one episode assembly of the project: the headless runner feeds it too, directly
(``whole=True``: every record of every episode, rewards only where they are not 0), and takes
the same row (:attr:`Closed.core`) from it; the learner node feeds it from its topics and
``clis learn`` from a bag, both through :func:`clis_learner.intake_topics.feed`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from typing import Any

from clis_base.instants import DecisionClock
from clis_modules.core.modules import ModuleCore
from clis_modules.core.proposal import Proposal
import numpy as np

from clis_learner.core.config import ClisParams
from clis_learner.core.episodes import episode_row
from clis_learner.core.guard import Divergence, DivergenceGuard
from clis_learner.core.learner import Learner
from clis_learner.core.memory import TIME_TOL, EpisodeMemory, StreamBuffer, episode_time

__all__ = ['Closed', 'EpisodeStream']


@dataclass(frozen=True)
class Closed:
    """One closed episode: its row (:func:`~clis_learner.core.episodes.episode_row` plus the
    stream's columns; ``complete`` = 0 when the rewards received do not sum to the
    simulator's return, i.e. reward messages were lost), whether it was learned, and the
    simulator's return."""

    row: dict[str, Any]
    learned: bool
    t_end: float
    episode: int
    sim_return: float = math.nan
    #: the row of :func:`~clis_learner.core.episodes.episode_row` alone (the runner's)
    core: dict[str, Any] | None = None
    #: the modules the divergence guard reported at this episode (first time only)
    diverged: tuple[Divergence, ...] = ()


class EpisodeStream:
    """Records of the learner's streams in, closed (and learned) episodes out.

    Parameters
    ----------
    modules : sequence of ModuleCore
        The condition's modules (updated in place when an episode is learned).
    params : ClisParams
    condition : str
        For the rows.
    seed : int
        For the rows.
    version : int
        Episodes learned so far (a resumed checkpoint's).
    dt : float
        The simulator's tick [s] (the decision instants are counted in ticks; a start event
        may say another: :meth:`start`).
    whole : bool
        Every record of every episode is fed (the headless runner): every episode is held from
        its start, whatever its first reward; the records of an episode come in time order,
        between its :meth:`start` and its :meth:`end`, so each goes straight into the
        episode's :class:`~clis_learner.core.memory.EpisodeMemory` (what
        :meth:`~clis_learner.core.memory.StreamBuffer.cut` would make of them, without the
        buffer).
    """

    def __init__(self, modules: Sequence[ModuleCore], params: ClisParams, condition: str,
                 seed: int, version: int = 0, dt: float = 0.05, whole: bool = False) -> None:
        self.whole = whole
        self.modules = list(modules)
        self.names = [m.name for m in self.modules]
        self.condition, self.seed, self.version = condition, seed, int(version)
        self.min_period = min(m.period for m in self.modules)
        self.clock = DecisionClock([m.period for m in self.modules], dt)
        self.learner = Learner(self.modules, params)
        self.guard = DivergenceGuard(self.names, [m.gamma for m in self.modules])
        self.buffer = StreamBuffer(self.names)
        self.memory = EpisodeMemory(self.names)
        self.episode: dict | None = None        # the running episode (seen from its start)
        self.closing: dict | None = None        # the ended episode waiting for its records
        self.first_reward_t = math.inf          # stamp of the first reward of the stream
        self.reward_t = -math.inf               # newest reward stamp (the watermark)
        self.stop_t = -math.inf                 # newest stop of the arbiter
        self.draws: deque = deque(maxlen=10000)  # (t, Pr(i|x), V_i) of the arbiter's draws

    # ------------------------------------------------------------------ records

    def _rel(self, t: float) -> float:
        """Time ``t`` counted from the running episode's start (:meth:`StreamBuffer.cut`)."""
        return episode_time(t, self.episode['t0'], self.clock.dt)

    def proposal(self, p: Proposal) -> bool:
        """A module's proposal; False if it was a copy (already there)."""
        if self.whole:
            self.memory._add_decision(p.module, self._rel(p.t), p.b, p.value)
        elif not self.buffer.add_decision(p.module, p.t, p.b, p.value):
            return False
        if self.episode is not None and p.t >= self.episode['t0'] - TIME_TOL \
                and p.version != self.version:
            self.episode['stale'] += 1
        return True

    def action(self, t: float, u: np.ndarray, acting: str) -> None:
        """The command in force from ``t`` (``acting = ''``: a stop, nobody acts). KeyError
        for a module not of the condition."""
        if not acting:        # '' = a stop: nobody acts (the one at an episode's end comes
            self.stop_t = max(self.stop_t, t)     # after all of that episode's actions)
            return
        if acting not in self.names:
            raise KeyError(acting)
        if self.whole:
            self.memory.record_action(self._rel(t), u, acting)
            return
        self.buffer.add_action(t, u, acting)

    def selection(self, t: float, probs: Mapping[str, float],
                  values: Mapping[str, float]) -> None:
        """A draw of the arbiter (kept by stamp: it may come before the episode's start)."""
        self.draws.append((t, [probs.get(n, math.nan) for n in self.names],
                           [values.get(n, math.nan) for n in self.names]))

    def observation(self, module: str, t: float, b: np.ndarray) -> None:
        """Module ``module``'s features at ``t``, an instant at which it did not decide
        (:meth:`~clis_learner.core.memory.StreamBuffer.add_observation`)."""
        if self.whole:
            self.memory._add_observation(module, self._rel(t), b)
            return
        self.buffer.add_observation(module, t, b)

    def reward(self, t: float, r: float) -> None:
        """The reward of the step that ended at ``t``."""
        self.first_reward_t = min(self.first_reward_t, t)
        self.reward_t = max(self.reward_t, t)
        if self.whole:
            self.memory.record_reward(self._rel(t), r)
            return
        self.buffer.add_reward(t, r)

    def start(self, t: float, index: int, start: str, dt: float | None = None) -> Closed | None:
        """Episode ``index`` started at ``t`` (on ticks of ``dt``; None: as before); an ended
        episode still open is closed first."""
        closed = self.close() if self.closing is not None else None
        if dt is not None and dt != self.clock.dt:
            self.clock = DecisionClock([m.period for m in self.modules], dt)
        self.episode = {'index': index, 't0': t, 'start': start, 'stale': 0}
        if self.whole:
            self.memory.clear()
            self.memory.t_start = float(t) if self.clock.dt <= 0.0 else 0.0
        return closed

    def end(self, t: float, index: int, event: str, deadline: float = math.inf,
            grace: float = 0.0, sim_return: float = math.nan) -> dict[str, Any] | None:
        """Episode ``index`` ended at ``t`` with ``event`` (one of the module nodes'
        ``END_EVENTS``) and the return ``sim_return`` the simulator counted (NaN: unknown). It
        closes once :meth:`due` (wall times ``grace`` / ``deadline`` of the caller's clock). A
        row with ``learned: 0`` if the episode's start was not seen (nothing to learn), else
        None."""
        if self.episode is not None and self.episode['index'] == index:
            self.closing = {'t_end': t, 'reached': event == 'reached', 'event': event,
                            'return': float(sim_return), 'deadline': deadline, 'grace': grace}
            return None
        return {'episode': index, 'learned': 0, 'event': event}

    def due(self, now: float, on_grid: bool = True) -> tuple[bool, list[str]]:
        """``(close now, what is missing)``: every record of the ended episode is in
        (:meth:`missing`) and its grace time has passed, or its deadline has (then the list
        says what did not arrive). ``on_grid``: decisions fall on ``t_0 + l tau_i`` (sim
        time)."""
        c = self.closing
        if c is None:
            return False, []
        missing = self.missing(c['t_end'], on_grid)
        if (not missing and now >= c['grace']) or now >= c['deadline']:
            return True, missing
        return False, []

    def missing(self, t_end: float, on_grid: bool = True) -> list[str]:
        """What of the episode ending at ``t_end`` has not arrived yet: its last reward, the
        arbiter's stop at its end (sent after all of its actions), and each module's last
        decision ``t_0 + l tau_i < t_end`` (they travel on separate topics, and a run without
        lockstep pauses only at the decision instants)."""
        t0 = self.episode['t0']
        missing = [] if self.reward_t >= t_end - TIME_TOL else ['the last reward']
        if self.stop_t < t_end - TIME_TOL:
            missing.append("the arbiter's stop")
        for i, m in enumerate(self.modules if on_grid else ()):  # real time: off the grid
            # decisions at t_0 + l tau_i before t_end
            last = self.clock.last_before(i, t_end, t0)
            if self.buffer.last_decision(m.name) < last - TIME_TOL:
                missing.append(f'the decision of {m.name} at {last:.3f} s')
            # its observation at the last instant of another module before t_end (the module
            # nodes send one at every such instant)
            obs = self.clock.last_observed(i, t_end, t0) if len(self.modules) > 1 else None
            if obs is not None and self.buffer.last_observation(m.name) < obs - TIME_TOL:
                missing.append(f'the observation of {m.name} at {obs:.3f} s')
        return missing

    # ------------------------------------------------------------------ learning

    def close(self, learn: bool = True) -> Closed:
        """Cut the ended episode out of the buffer and learn from it (if seen from its
        start, and ``learn``: the runner's evaluation episodes are not learned)."""
        ep, c = self.episode, self.closing
        if ep is None or c is None:
            raise RuntimeError('no ended episode to close')
        if self.whole:                  # its records are in its memory already
            mem = self.memory
            mem.end(self._rel(c['t_end']), c['reached'])
        else:
            mem = self.buffer.cut(ep['t0'], c['t_end'], c['reached'], self.memory,
                                  dt=self.clock.dt)
        self.episode = self.closing = None
        probs, values = self._first_draw(ep['t0'], c['t_end'])
        # every reward of the episode arrived iff they sum to the simulator's return
        ret = float(mem.rewards()[1].sum())
        complete = not abs(ret - c['return']) > 1e-6           # NaN: the sim did not say
        # learn only from episodes recorded from their start
        learnable = self.whole or self.first_reward_t <= ep['t0'] + self.min_period + TIME_TOL
        learnable = learnable and learn
        held = self.learner.held_steps
        diag = self.learner.learn(mem) if learnable else {}
        if learnable:
            self.version += 1
        # off-policy steps whose behaviour density was scored at the behaviour's held state
        # (with learner.behaviour_state = resampled: an observation that did not arrive)
        held = self.learner.held_steps - held
        core = episode_row(mem, self.names, probs, values, diag, ep['start'])
        # the divergence guard observes (no number changes): the n-th learned episode
        new = self.guard.check(self.version, diag, mem.rewards()[1]) if learnable else []
        core['diverged'] = '+'.join(d.module for d in new)
        core['diverged_why'] = '; '.join(d.reason for d in new)
        row = {'label': self.condition, 'condition': self.condition, 'seed': self.seed,
               'phase': 'train', 'episode': ep['index'], **core,
               'event': c['event'], 'learned': int(learnable), 'version': self.version,
               'stale_decisions': ep['stale'], 'complete': int(complete), 't_end': c['t_end'],
               'held_steps': held}
        return Closed(row, learnable, c['t_end'], ep['index'], c['return'], core, tuple(new))

    def _first_draw(self, t0: float, t_end: float) -> tuple[list | None, list | None]:
        """``Pr(i | x)`` and values of the episode's first draw (None if none arrived)."""
        first = next(((p, v) for t, p, v in self.draws if t0 - TIME_TOL <= t <= t_end + TIME_TOL),
                     (None, None))
        while self.draws and self.draws[0][0] <= t_end + TIME_TOL:
            self.draws.popleft()
        return first
