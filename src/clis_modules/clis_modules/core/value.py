"""Linear state value of a module, eqs. (1)-(2) and Sec. II-C.

``V_i(x) = w_i^T b_i(x)`` approximates the expected discounted return (1) of module i's policy;
its weights are learned by TD(lambda) with importance sampling, eq. (8)
(:mod:`clis_learner.core.updates`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['gamma_i', 'LinearValue']


def gamma_i(gamma: float, tau_i: float, base_tick: float) -> float:
    """Discount per decision of a module with period ``tau_i``, eq. (11).

    The paper prints ``gamma_i = gamma^{tau_i'}``; we read the exponent as the number of base
    ticks ``Delta`` in the period (docs/design.md §2): a second is discounted alike by every
    module, so all of them estimate (1) for the same objective.

    Parameters
    ----------
    gamma : float
        Common discount per base tick (paper: 0.995).
    tau_i : float
        Decision period of the module [s].
    base_tick : float
        ``Delta`` [s] (our choice: the 50 ms simulator tick).
    """
    # (11) gamma_i = gamma^(tau_i / Delta)
    return float(gamma) ** (float(tau_i) / float(base_tick))


class LinearValue:
    """``V(x) = w^T b(x)`` (Sec. II-C, approximating (1)).

    Parameters
    ----------
    n : int
        Number of features.
    v_init : float
        Initial weight of every feature. With normalised features (sum 1) the initial value is
        ``v_init`` in every state; the innate module starts high (paper III-B).
    """

    def __init__(self, n: int, v_init: float) -> None:
        self.w = np.full(int(n), float(v_init))

    def __call__(self, b: ArrayLike) -> float:
        """``V = w^T b`` for features ``b`` of shape (n,)."""
        # V_i(x) = w_i^T b_i(x)
        return float(self.w @ np.asarray(b, dtype=np.float64))

    def batch(self, B: ArrayLike) -> np.ndarray:  # noqa: N803 - features matrix
        """Values of many states: ``B`` shape (L, n) -> shape (L,)."""
        return np.asarray(B, dtype=np.float64) @ self.w
