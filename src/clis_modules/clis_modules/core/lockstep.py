"""Which decisions an instant waits for, when the arbiter answers every instant (lockstep).

Under sim time with ``node.lockstep`` the simulator holds its clock at each instant ``t`` until
a command stamped ``t`` (or later) arrives (:mod:`cr_sim.core.gate`). The arbiter answers
instant ``t`` once every module whose decision is due at ``t`` has proposed on the readings of
``t``: then the :class:`~clis_modules.core.arbiter.Selector` gets those proposals together, as
in the headless runner, and the command in force is sent stamped ``t``.

Due at ``t``: module i decides at ``t_0 + l tau_i`` (its timer is aligned to the episode start,
as in the headless runner), in integer ticks of the simulator
(:class:`~clis_base.instants.DecisionClock`). A module that does not deliver within
``timeout`` wall seconds (it died, or is restarting) is *missing*: no instant waits for it
until it proposes again. Pure: wall times are passed in.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

from clis_base.instants import TOL, DecisionClock
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.proposal import Proposal

__all__ = ['TickBarrier']

#: Two stamps closer than this [s] are the same instant.
_TOL = TOL
#: The simulator's tick [s] until :meth:`TickBarrier.begin_episode` says another.
DEFAULT_DT = 0.05


class TickBarrier:
    """The instants waiting for their decisions (module docstring).

    Parameters
    ----------
    names : sequence of str
        Module names, in index order.
    periods : array_like, shape (N,)
        Decision periods ``tau_i`` [s].
    timeout : float
        Wall seconds an instant waits for a due decision before the module counts as missing.
    dt : float
        The simulator's tick [s].
    """

    def __init__(self, names: Sequence[str], periods: ArrayLike, timeout: float,
                 dt: float = DEFAULT_DT) -> None:
        self.names = tuple(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.periods = np.asarray(periods, dtype=np.float64)
        self.clock = DecisionClock(self.periods.tolist(), dt)
        self.timeout = float(timeout)
        self.running = False
        self.t0 = -math.inf
        self.missing: set[int] = set()
        self.last = np.full(len(self.names), -math.inf)   # newest proposal stamp per module
        self.inbox: list[Proposal] = []
        self.open: list[tuple[float, float]] = []         # (instant, wall deadline)
        self.reached = -math.inf                          # the newest instant opened

    def begin_episode(self, t0: float, dt: float | None = None) -> None:
        """An episode starts at ``t0`` (on ticks of ``dt``; None: as before): instants before
        it are answered by nobody."""
        if dt is not None and dt != self.clock.dt:
            self.clock = DecisionClock(self.periods.tolist(), dt)
        self.running, self.t0 = True, float(t0)
        self.open = [(t, d) for t, d in self.open if t >= t0 - _TOL]
        self.inbox = [p for p in self.inbox if p.t >= t0 - _TOL]

    def end_episode(self) -> None:
        self.running = False

    def on_tick(self, t: float, now: float) -> None:
        """The clock reached instant ``t`` (wall time ``now``); an instant already opened
        (and maybe answered) is not opened again."""
        if t > self.reached + _TOL:
            self.reached = float(t)
            self.open.append((float(t), now + self.timeout))

    def is_instant(self, t: float) -> bool:
        """Whether ``t`` is a decision instant ``t_0 + l tau_i`` of the running episode for
        some module (missing or not): the instants a simulator in lockstep holds its clock at
        (between two, the command cannot change and nobody waits for it)."""
        if not self.running:
            return False
        return self.clock.is_instant(t, self.t0)

    def on_proposal(self, p: Proposal) -> bool:
        """Take a proposal; False (ignored) for a copy or an older one of the same module
        (modules send their last proposal again while the clock stands still)."""
        i = self.index[p.module]
        if p.t <= self.last[i] + _TOL:
            return False
        self.last[i] = p.t
        self.missing.discard(i)
        self.inbox.append(p)
        return True

    def lost(self, name: str) -> None:
        """Module ``name`` is known dead: missing now, without waiting for a timeout."""
        self.missing.add(self.index[name])

    def alive(self, name: str) -> None:
        """Module ``name`` is known alive again (its liveliness came back, or a restarted
        module's proposals are matched): its due decisions are waited for again."""
        self.missing.discard(self.index[name])

    def due(self, t: float) -> np.ndarray:
        """Modules whose decision is due at ``t`` and not missing, shape (N,), bool."""
        # decisions at t_0 + l tau_i
        due = np.array(self.clock.due(t, self.t0), dtype=bool)
        for i in self.missing:
            due[i] = False
        return due

    def ready(self, now: float) -> list[tuple[float, list[Proposal]]]:
        """The instants that can be answered at wall time ``now``, oldest first, each with
        the proposals stamped up to it (those of its due decisions, and any late ones)."""
        out: list[tuple[float, list[Proposal]]] = []
        while self.running and self.open:
            t, deadline = self.open[0]
            due = self.due(t)
            # a proposal at t, or a later one (the module decided past t: no use waiting)
            have = {self.index[p.module] for p in self.inbox if p.t >= t - _TOL}
            waiting = [i for i in np.flatnonzero(due) if i not in have
                       and self.last[i] < t - _TOL]
            if waiting and now < deadline:
                break
            self.missing.update(int(i) for i in waiting)
            ps = [p for p in self.inbox if p.t <= t + _TOL]
            self.inbox = [p for p in self.inbox if p.t > t + _TOL]
            self.open.pop(0)
            out.append((t, ps))
        return out

    @property
    def waiting_for(self) -> list[str]:
        """Names of the modules the oldest open instant waits for (diagnostics)."""
        if not self.open:
            return []
        t = self.open[0][0]
        have = {p.module for p in self.inbox if p.t >= t - _TOL}
        return [n for i, (n, d) in enumerate(zip(self.names, self.due(t)))
                if d and n not in have and self.last[i] < t - _TOL]
