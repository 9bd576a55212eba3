"""Decision instants in integer ticks: the one test of "is ``t`` a decision instant
``t_0 + l tau_i``" that every scheduler of the project uses.

The simulator advances in ticks of ``dt`` (``episode.dt``, 50 ms): the time of an episode is
``t = t_0 + k dt`` for an integer tick ``k``. Module i, of period ``tau_i``, decides at every
tick ``k`` with ``k mod n_i = 0``, ``n_i = round(tau_i / dt)`` (at least 1), reading the sensors
of that tick (docs/design.md §6). The headless runner counts ticks itself; the graph's nodes see
stamps ``t`` of a sim clock that runs on across episodes, and :meth:`DecisionClock.tick` turns
them back into the tick of the running episode (a stamp off the tick grid by more than
:data:`TOL` is no tick). Users: the runner (:mod:`clis_app.experiments.runner`), the module node
(its decision grid), the arbiter's lockstep barrier (:mod:`clis_modules.core.lockstep`), the
simulator's lockstep gate (:mod:`cr_sim.core.gate`), the learner's episode stream
(:mod:`clis_learner.core.intake`) and the replayed random streams
(:mod:`clis_modules.core.draws`).
"""

from __future__ import annotations

from collections.abc import Sequence
import math

__all__ = ['TOL', 'ticks_per', 'DecisionClock']

#: Two stamps closer than this [s] are the same instant.
TOL = 1e-6


def ticks_per(period: float, dt: float) -> int:
    """``n = round(period / dt)``, at least 1: the ticks between two decisions of a module of
    ``period`` [s]."""
    return max(1, int(round(period / dt)))


class DecisionClock:
    """The decision instants of modules of ``periods`` [s] on a tick of ``dt`` [s].

    Attributes
    ----------
    every : list of int
        ``n_i`` of each module (:func:`ticks_per`).
    cycle : int
        Their least common multiple: the due modules repeat with it.
    schedule : list of list of int
        ``schedule[k % cycle]``: indices of the modules due at tick ``k`` (in module order).
    gaps : list of int
        ``gaps[k % cycle]``: ticks from tick ``k`` to the next tick at which a module is due.
    """

    def __init__(self, periods: Sequence[float], dt: float) -> None:
        self.dt = float(dt)
        self.every = [ticks_per(p, dt) for p in periods]
        self.cycle = math.lcm(*self.every)
        self.schedule = [[i for i, n in enumerate(self.every) if k % n == 0]
                         for k in range(self.cycle)]
        # tick 0 has every module: the gaps are finite
        self.gaps = [next(j for j in range(1, self.cycle + 1)
                          if self.schedule[(k + j) % self.cycle]) for k in range(self.cycle)]

    def tick(self, t: float, t0: float) -> int | None:
        """The tick ``k`` of the episode started at ``t0`` that stamp ``t`` is (``t`` =
        ``t0 + k dt`` within :data:`TOL`), or None (before the start, or off the grid)."""
        x = (t - t0) / self.dt
        k = int(round(x))
        if k < 0 or abs(x - k) * self.dt > TOL:
            return None
        return k

    def due_at(self, k: int) -> list[int]:
        """Indices of the modules due at tick ``k``."""
        return self.schedule[k % self.cycle]

    def is_due(self, i: int, k: int | None) -> bool:
        """Whether module ``i`` decides at tick ``k`` (None: no tick)."""
        return k is not None and k % self.every[i] == 0

    def due(self, t: float, t0: float) -> list[bool]:
        """Per module, whether it decides at stamp ``t`` of the episode started at ``t0``."""
        k = self.tick(t, t0)
        return [self.is_due(i, k) for i in range(len(self.every))]

    def is_instant(self, t: float, t0: float) -> bool:
        """Whether stamp ``t`` is a decision instant of some module."""
        k = self.tick(t, t0)
        return k is not None and bool(self.schedule[k % self.cycle])

    def last_tick(self, i: int, t: float, t0: float) -> int:
        """The last decision tick of module ``i`` at or before stamp ``t`` (-1 before
        ``t0``)."""
        k = math.floor((t - t0) / self.dt + TOL / self.dt)
        if k < 0:
            return -1
        return k - k % self.every[i]

    def last_instant(self, i: int, t: float, t0: float) -> float:
        """:meth:`last_tick` as a stamp ``t0 + k dt``."""
        return t0 + self.last_tick(i, t, t0) * self.dt

    def last_before(self, i: int, t: float, t0: float) -> float:
        """The last decision instant of module ``i`` strictly before stamp ``t`` (by more
        than :data:`TOL`)."""
        return self.last_instant(i, t - 2 * TOL, t0)

    def last_observed(self, i: int, t: float, t0: float) -> float | None:
        """The last instant strictly before stamp ``t`` at which another module decides and
        module ``i`` does not (None: none since ``t0``)."""
        k = math.floor((t - 2 * TOL - t0) / self.dt + TOL / self.dt)
        while k > 0:
            due = self.schedule[k % self.cycle]
            if due and i not in due:
                return t0 + k * self.dt
            k -= 1
        return None
