"""Importance-sampling corrections: the per-step ratio rho of (6), pluggable.

Paper (6): ``rho_i = pi_i(x, u) / pi_i'(x, u)`` corrects an episode of the behaviour policy
``pi_i'`` for the target ``pi_i``; its product over the episode may diverge, so (7) truncates::

    rho~_i = (pi_i + epsilon) / (pi_i' + epsilon),   epsilon = 0.2      (7)

A correction is any object with a ``name`` and ``ratio(pi_target, pi_behaviour) -> rho``
(arrays of densities in, array of ratios out). Add a variant by writing such a class and
registering a factory in :data:`CORRECTIONS`; ``learner.correction`` in ``clis.yaml`` picks one
by name (its ``choices`` come from this registry).

Whatever the correction, with ``learner.behaviour = acting`` the learner sets ``rho = 1``
exactly on the steps where the target is the behaviour module (the ratio of a density to
itself), without evaluating any density.

Behaviour density (``learner.behaviour``, beyond the paper): ``acting`` is the paper's
``pi_i'``, the density of the module that acted. ``mixture`` is the density of the selection
mixture, ``sum_j Pr(j | x) pi_j(x_j, u)`` with ``Pr`` of the arbiter's rule (3): the balance
heuristic of multiple importance sampling (Veach & Guibas 1995), which CRAIL (Uchibe 2018,
CLIS's successor) uses as its behaviour policy. Every step of every episode is then a sample of
the same mixture, the ratio of a target is bounded by ``1 / Pr(i | x)`` (up to ``epsilon``) and
it is the same whichever module happened to act (:func:`mixture_density`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['Correction', 'TruncatedRatio', 'ClippedRatio', 'NoCorrection', 'CORRECTIONS',
           'make_correction', 'BEHAVIOURS', 'BEHAVIOUR_STATES', 'mixture_density']

#: ``learner.behaviour``: the density of the acting module (paper), or of the selection mixture.
BEHAVIOURS = ('acting', 'mixture')
#: ``learner.behaviour_state``: where the acting module's density is scored at a target's
#: instant ``l tau_i``: its features at that instant (paper (6)) or at its latest decision.
BEHAVIOUR_STATES = ('resampled', 'held')


class Correction(Protocol):
    """Per-step importance ratio of a target policy to the behaviour policy."""

    name: str

    def ratio(self, pi_target: ArrayLike, pi_behaviour: ArrayLike) -> np.ndarray:
        """Ratios ``rho`` (L,) from target and behaviour densities (L,) of the same actions."""
        ...


class TruncatedRatio:
    """The paper's truncated ratio (7), ``(pi_i + epsilon) / (pi_i' + epsilon)``.

    Parameters
    ----------
    epsilon : float
        >= 0; with 0 this is the plain ratio (6).
    """

    name = 'paper'

    def __init__(self, epsilon: float) -> None:
        if not epsilon >= 0.0:
            raise ValueError(f'epsilon must be >= 0, got {epsilon}')
        self.epsilon = float(epsilon)

    def ratio(self, pi_target: ArrayLike, pi_behaviour: ArrayLike) -> np.ndarray:
        """``rho~ = (pi_i + epsilon) / (pi_i' + epsilon)`` elementwise (7)."""
        eps = self.epsilon
        # (7) rho~_i = (pi_i + eps) / (pi_i' + eps)
        return (np.asarray(pi_target, dtype=np.float64) + eps) / (
            np.asarray(pi_behaviour, dtype=np.float64) + eps)


class ClippedRatio(TruncatedRatio):
    """Beyond the paper: the truncated ratio (7) clipped at 1, ``min(1, rho~)``.

    As in Retrace / V-trace (Munos et al. 2016; Espeholt et al. 2018): the product ``c`` and
    the trace ``lambda gamma rho e`` of (8) can then only shrink, so TD(lambda) with IS cannot
    diverge. The estimate is biased toward the behaviour policy's values, and an episode still
    teaches a module only as far as its actions agree with the module's policy.
    """

    name = 'clipped'

    def ratio(self, pi_target: ArrayLike, pi_behaviour: ArrayLike) -> np.ndarray:
        """``min(1, (pi_i + epsilon) / (pi_i' + epsilon))`` elementwise."""
        return np.minimum(super().ratio(pi_target, pi_behaviour), 1.0)


class NoCorrection:
    """``rho = 1``: every episode treated as on-policy (an ablation, not the paper)."""

    name = 'none'

    def __init__(self, epsilon: float = 0.0) -> None:
        del epsilon

    def ratio(self, pi_target: ArrayLike, pi_behaviour: ArrayLike) -> np.ndarray:
        """Ones, shape of ``pi_target``."""
        return np.ones(np.shape(pi_target))


#: Registry: name -> factory taking ``epsilon`` (``common.epsilon``).
CORRECTIONS: dict[str, Callable[[float], Correction]] = {
    'paper': TruncatedRatio,
    'clipped': ClippedRatio,
    'none': NoCorrection,
}


def make_correction(name: str, epsilon: float) -> Correction:
    """The correction registered as ``name``, built with ``epsilon``."""
    try:
        factory = CORRECTIONS[name]
    except KeyError:
        raise ValueError(f'unknown correction {name!r}: choose from '
                         f'{", ".join(CORRECTIONS)}') from None
    return factory(epsilon)


def mixture_density(pi: ArrayLike, probs: ArrayLike) -> np.ndarray:
    """Density of the selection mixture at each step (balance heuristic, Veach & Guibas 1995).

    ``pi_mix(x, u) = sum_j Pr(j | x) pi_j(x_j, u)``: the behaviour when the acting module is
    drawn by (3) with probabilities ``Pr(j | x)`` and then acts by its policy (10) (CRAIL,
    Uchibe 2018). A target ``i`` among the ``j`` gets ``pi_i / pi_mix <= 1 / Pr(i | x)``.

    Parameters
    ----------
    pi : array_like, shape (L, N)
        ``pi_j(x_j, u_l)`` of every module j at every step l (its state at its latest decision).
    probs : array_like, shape (L, N) or (N,)
        ``Pr(j | x)`` of the selection at each step (rows sum to 1), or one row for the episode.

    Returns
    -------
    np.ndarray, shape (L,)
    """
    pi = np.asarray(pi, dtype=np.float64)
    probs = np.broadcast_to(np.asarray(probs, dtype=np.float64), pi.shape)
    # balance heuristic: pi_mix = sum_j Pr(j|x) pi_j(x, u)
    return np.sum(probs * pi, axis=1)
