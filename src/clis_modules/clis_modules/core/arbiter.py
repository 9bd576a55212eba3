"""Competitive module selection, eq. (3) (paper II-A).

``Pr(i | x) = exp(beta (1 - gamma_i) V_i(x)) / sum_j exp(beta (1 - gamma_j) V_j(x))``

``(1 - gamma_i) V_i`` is the value as a reward *rate* per decision of module i; with
``beta = 1`` and returns of at most 1 the exponents differ by at most ``1 - gamma_i`` (~0.02
to 0.11 with the default periods), so the selection is almost uniform (DESIGN Sec. 2, 9).

When to select is an ambiguity of the paper (DESIGN Sec. 2): ``episode`` (default) draws one
module at the episode start from the start-state values and keeps it -- what the importance
sampling of (4)-(6) assumes, one behaviour policy per episode; ``decision`` redraws at every
decision of any module, from each module's value at its latest features.
"""

from __future__ import annotations

from cr_sim.core.params import dataclass, param
import numpy as np
from numpy.typing import ArrayLike

__all__ = ['ArbiterParams', 'selection_probs', 'Arbiter']


@dataclass(frozen=True)
class ArbiterParams:
    """Module selection (``clis.yaml`` section ``arbiter``)."""

    selection: str = param(choices=('episode', 'decision'),
                           doc='select once per episode or at every decision')


def selection_probs(values: ArrayLike, gammas: ArrayLike, beta: float,
                    available: ArrayLike | None = None) -> np.ndarray:
    """Selection probabilities of eq. (3).

    Parameters
    ----------
    values : array_like, shape (N,)
        ``V_i(x)`` of each module at its current features.
    gammas : array_like, shape (N,)
        ``gamma_i`` of each module (11).
    beta : float
        Inverse temperature, >= 0.
    available : array_like of bool, shape (N,), optional
        Modules that currently propose an action; the others get probability 0.

    Returns
    -------
    np.ndarray, shape (N,)
        ``Pr(i | x)``, summing to 1 (computed with the max subtracted: no overflow).

    Raises
    ------
    ValueError
        If no module is available or an available module has a non-finite value.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    g = np.asarray(gammas, dtype=np.float64).reshape(-1)
    ok = np.ones(v.shape, bool) if available is None else np.asarray(available, bool).reshape(-1)
    if not (v.shape == g.shape == ok.shape):
        raise ValueError('values, gammas and available must have the same length')
    if not ok.any():
        raise ValueError('no module is available for selection')
    if not np.all(np.isfinite(v[ok])):
        raise ValueError(f'non-finite module value in {v}')
    z = np.full(v.shape, -np.inf)
    # (3) Pr(i|x) ∝ exp(beta (1 - gamma_i) V_i(x))
    z[ok] = beta * (1.0 - g[ok]) * v[ok]
    p = np.exp(z - z[ok].max())
    return p / p.sum()


class Arbiter:
    """Picks the acting module by (3), once per episode or at every decision.

    Parameters
    ----------
    params : ArbiterParams
    beta : float
        Inverse temperature of (3).
    rng : np.random.Generator
        The only source of randomness (one ``rng.random()`` per draw).

    Attributes
    ----------
    current : int or None
        Index of the acting module.
    probs : np.ndarray or None
        Probabilities of the last draw, shape (N,).
    """

    def __init__(self, params: ArbiterParams, beta: float, rng: np.random.Generator) -> None:
        self.mode = params.selection
        self.beta = float(beta)
        self.rng = rng
        self.current: int | None = None
        self.probs: np.ndarray | None = None

    def _draw(self, values: ArrayLike, gammas: ArrayLike, available: ArrayLike | None) -> int:
        self.probs = selection_probs(values, gammas, self.beta, available)
        cdf = np.cumsum(self.probs)
        i = min(int(np.searchsorted(cdf, self.rng.random() * cdf[-1], side='right')),
                len(cdf) - 1)
        if self.probs[i] == 0.0:             # rounding at the top edge: last available one
            i = int(np.flatnonzero(self.probs)[-1])
        self.current = i
        return i

    def begin_episode(self, values: ArrayLike, gammas: ArrayLike,
                      available: ArrayLike | None = None) -> int:
        """Draw the acting module at the episode start (both modes); returns its index."""
        return self._draw(values, gammas, available)

    def on_decision(self, values: ArrayLike, gammas: ArrayLike,
                    available: ArrayLike | None = None) -> int:
        """At a decision of any module: ``decision`` mode redraws; ``episode`` mode keeps the
        current module unless it is no longer available (then redraws among the others)."""
        if self.mode == 'decision' or self.current is None:
            return self._draw(values, gammas, available)
        if available is not None and not np.asarray(available, bool)[self.current]:
            return self._draw(values, gammas, available)
        return self.current
