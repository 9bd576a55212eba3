"""Short-term memory of one episode (paper II-E: "a short term memory to save an episode").

What the learner needs to train every module from one episode, whichever module acted:

* decisions: for each module, its own features ``b_i`` at its own decision times (every
  ``tau_i``; all modules keep deciding whether they act or not);
* actions: the commands the robot executed, as a piecewise-constant sequence of change points
  ``(t, u, behaviour)``: at each decision of the acting (behaviour) module, its *proposed*
  action (before the runner's clamp; the densities of (7) are of the proposal) and its name;
* rewards with their times (simulator ticks);
* the end time and whether the destination was reached.

Time convention (all in seconds since the episode start, on the simulator's tick grid):
a reward is stamped with the time the simulator step that earned it **started**, i.e. the time
the command in force was issued (``res.t - dt`` for the step result ``res``), so that the reward
of interval ``[l tau_i, (l + 1) tau_i)`` of module i is the sum of the rewards stamped inside it.
Decisions at or after the end time are ignored. Times are compared with a tolerance of
:data:`TIME_TOL` (1 us), so ``15 * 0.05`` and ``0.75`` are the same instant.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['TIME_TOL', 'EpisodeMemory']

#: Two times closer than this [s] are the same instant.
TIME_TOL = 1e-6


class EpisodeMemory:
    """Records one episode for :class:`clis_learner.core.learner.Learner`.

    Parameters
    ----------
    module_names : sequence of str
        Names of the modules that may record decisions or act.
    """

    def __init__(self, module_names: Sequence[str]) -> None:
        self.module_names = tuple(module_names)
        self._index = {n: i for i, n in enumerate(self.module_names)}
        self.clear()

    def clear(self) -> None:
        """Forget everything (reuse the object for the next episode)."""
        self._dec_t: dict[str, list[float]] = {n: [] for n in self.module_names}
        self._dec_b: dict[str, list[np.ndarray]] = {n: [] for n in self.module_names}
        self._act_t: list[float] = []
        self._act_u: list[np.ndarray] = []
        self._act_who: list[int] = []
        self._rew_t: list[float] = []
        self._rew_r: list[float] = []
        self.t_end: float | None = None
        self.reached = False

    # ------------------------------------------------------------------ recording

    def _check_open(self) -> None:
        if self.t_end is not None:
            raise RuntimeError('the episode has ended: clear() the memory first')

    def record_decision(self, module: str, t: float, b: ArrayLike) -> None:
        """Module ``module`` decided at time ``t`` [s] with features ``b`` (copied), shape (n,).

        Times of one module must increase.
        """
        self._check_open()
        ts = self._dec_t[module]
        if ts and t <= ts[-1] + TIME_TOL:
            raise ValueError(f'{module}: decision time {t} does not follow {ts[-1]}')
        ts.append(float(t))
        self._dec_b[module].append(np.array(b, dtype=np.float64).reshape(-1))

    def record_action(self, t: float, u: ArrayLike, behaviour: str) -> None:
        """From time ``t`` [s] the robot executes ``u`` (the proposed ``(v_left, v_right)``
        [m/s] of module ``behaviour``). A second action at the same time replaces the first."""
        self._check_open()
        who = self._index[behaviour]
        u = np.array(u, dtype=np.float64).reshape(2)
        if self._act_t and t < self._act_t[-1] - TIME_TOL:
            raise ValueError(f'action time {t} precedes {self._act_t[-1]}')
        if self._act_t and abs(t - self._act_t[-1]) <= TIME_TOL:
            self._act_u[-1], self._act_who[-1] = u, who
            return
        self._act_t.append(float(t))
        self._act_u.append(u)
        self._act_who.append(who)

    def record_reward(self, t: float, r: float) -> None:
        """Reward ``r`` earned by the simulator step that started at time ``t`` [s]."""
        self._check_open()
        if r != 0.0:                      # zeros change no interval sum
            self._rew_t.append(float(t))
            self._rew_r.append(float(r))

    def end(self, t: float, reached: bool) -> None:
        """The episode ended at time ``t`` [s] (goal reached, or timeout)."""
        self._check_open()
        if not math.isfinite(t):
            raise ValueError(f'end time must be finite, got {t}')
        self.t_end = float(t)
        self.reached = bool(reached)

    # ------------------------------------------------------------------ reading

    @property
    def ended(self) -> bool:
        """Whether :meth:`end` was called."""
        return self.t_end is not None

    def decisions(self, module: str) -> tuple[np.ndarray, np.ndarray | None]:
        """Decision times (L,) and features (L, n) of ``module`` before the end.

        The features are ``None`` when the module never decided.
        """
        t = np.asarray(self._dec_t[module], dtype=np.float64)
        keep = t < self.t_end - TIME_TOL if self.t_end is not None else np.ones(len(t), bool)
        if not keep.any():
            return t[:0], None
        n_keep = int(np.count_nonzero(keep))     # times increase: a prefix is kept
        return t[:n_keep], np.stack(self._dec_b[module][:n_keep])

    def actions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Action change points: times (K,), proposed actions (K, 2), behaviour index (K,)."""
        if not self._act_t:
            return np.zeros(0), np.zeros((0, 2)), np.zeros(0, dtype=int)
        return (np.asarray(self._act_t), np.stack(self._act_u),
                np.asarray(self._act_who, dtype=int))

    def rewards(self) -> tuple[np.ndarray, np.ndarray]:
        """Reward times (R,) and values (R,)."""
        return np.asarray(self._rew_t, dtype=np.float64), np.asarray(self._rew_r)

    def index(self, module: str) -> int:
        """Index of ``module`` in :attr:`module_names` (as in :meth:`actions`)."""
        return self._index[module]
