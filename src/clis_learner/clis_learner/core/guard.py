"""The divergence guard: says when a module's learning has blown up, and changes no number.

TD(lambda) with the importance ratios of (7)(8) can diverge: under the literal ``paper``
preset the product ``c_i`` of (8) grows over the off-policy stretches of an episode and the
value weights ``w_i`` with it, until ``V_i`` is far beyond any return (docs/results.md,
"Divergence"). A module whose value has diverged then wins every selection by (3), and the run
goes on learning nothing. The guard watches each learned episode's diagnostics
(:class:`~clis_learner.core.learner.Learner`) and reports a module, once, at the first episode
where

* its update was not finite (``diverged``: the learner then does not apply it), or the
  importance product overflowed (``c_max`` not finite); or
* the largest ``|V_i(x_l)|`` over the episode's states (``v_abs_max``, before the update)
  exceeds ``FACTOR * r_max / (1 - gamma_i)``. No discounted sum of rewards of at most
  ``r_max`` per decision reaches ``r_max / (1 - gamma_i)``; ``FACTOR`` (10) leaves room for a
  value still settling. ``r_max`` is the largest ``|r|`` of the rewards the guard has been
  shown, at least :data:`REWARD_FLOOR` (the goal reward of the task, paper III-E).

It reads only what the learner computed: the headless runner, the learner node and ``clis
learn`` report the same module at the same episode (the n-th learned one), in the episode
rows' columns ``diverged`` (the modules, joined by ``+``) and ``diverged_why``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['FACTOR', 'REWARD_FLOOR', 'DOCS', 'Divergence', 'DivergenceGuard']

#: How far beyond the largest possible return a value must be to count as diverged.
FACTOR = 10.0
#: The smallest ``r_max`` the bound uses (the goal reward of the task).
REWARD_FLOOR = 1.0
#: Where the docs explain it.
DOCS = 'docs/results.md#divergence'


@dataclass(frozen=True)
class Divergence:
    """Module ``module`` diverged at learned episode ``episode``: ``reason`` says how."""

    module: str
    episode: int
    reason: str

    @staticmethod
    def from_row(row: Mapping[str, object], episode: int) -> list[Divergence]:
        """The divergences an episode row reports (its columns ``diverged``, the modules
        joined by ``+``, and ``diverged_why``, their reasons joined by ``; ``)."""
        names = [n for n in str(row.get('diverged') or '').split('+') if n]
        why = str(row.get('diverged_why') or '').split('; ')
        return [Divergence(n, int(episode), why[k] if k < len(why) else '')
                for k, n in enumerate(names)]

    def message(self) -> str:
        """One line for a progress display or a log."""
        return (f'module {self.module} diverged at episode {self.episode}: {self.reason}; its '
                f'values no longer mean anything, and the arbiter follows them ({DOCS})')


class DivergenceGuard:
    """Reports each module's divergence once (module docstring).

    Parameters
    ----------
    names : sequence of str
        The modules, in the learner's order.
    gammas : array_like, shape (N,)
        Their discounts ``gamma_i`` (11).
    """

    def __init__(self, names: Sequence[str], gammas: ArrayLike) -> None:
        self.names = list(names)
        self.gammas = np.asarray(gammas, dtype=np.float64).reshape(-1)
        self.r_max = REWARD_FLOOR
        #: The first divergence of each module reported so far.
        self.reported: dict[str, Divergence] = {}

    def bound(self, module: str) -> float:
        """``FACTOR * r_max / (1 - gamma_i)`` of ``module`` (inf for ``gamma_i = 1``)."""
        g = float(self.gammas[self.names.index(module)])
        return FACTOR * self.r_max / (1.0 - g) if g < 1.0 else math.inf

    def check(self, episode: int, diag: Mapping[str, Mapping[str, float]],
              rewards: ArrayLike = ()) -> list[Divergence]:
        """The modules that diverged at ``episode`` and were not reported before.

        Parameters
        ----------
        episode : int
            The learned episode's number.
        diag : mapping
            :meth:`Learner.learn`'s diagnostics of the episode, per module.
        rewards : array_like, shape (R,)
            The episode's rewards (they raise ``r_max``).
        """
        r = np.abs(np.asarray(rewards, dtype=np.float64))
        r = r[np.isfinite(r)]
        if r.size:
            self.r_max = max(self.r_max, float(r.max()))
        out = []
        for name in self.names:
            d = diag.get(name)
            if d is None or name in self.reported or not d.get('n_steps', 0):
                continue
            reason = self._reason(name, d)
            if reason:
                self.reported[name] = Divergence(name, int(episode), reason)
                out.append(self.reported[name])
        return out

    def _reason(self, name: str, d: Mapping[str, float]) -> str:
        if d.get('diverged', 0.0):
            return 'its update was not finite (not applied)'
        if not math.isfinite(d.get('c_max', 0.0)):
            return 'the importance product of (8) overflowed'
        v = d.get('v_abs_max', 0.0)
        bound = self.bound(name)
        if not math.isfinite(v) or v > bound:
            return (f'|V| = {v:.3g} at a state of the episode, beyond {bound:.3g} '
                    f'= {FACTOR:g} r_max / (1 - gamma) with r_max = {self.r_max:g}')
        return ''
