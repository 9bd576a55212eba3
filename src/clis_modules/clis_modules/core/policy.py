"""The Gaussian policy of eq. (10), its log-likelihood and its analytic gradient.

Paper eq. (10)::

    pi_i(x, u) = eta_i exp(-||u - W_i b_i(x)||^2 / (2 sigma_i^2)),  eta_i = (2 pi sigma_i^2)^(-d/2)

over the action ``u = (v_left, v_right)`` in m/s (d = 2). Here the mean is scaled to the
module's speed limit, ``mu = v_max W b`` (docs/design.md §3): ``W`` is dimensionless (a share of
``v_max`` per unit feature), so one ``W`` means the same behaviour whatever the module's period.
This is (10) with ``W_i = v_max W``; the density is always over u in m/s, the common measure
that makes the ratio of two modules' densities in (7) meaningful. It is the density of the
*proposed* action, before the runner's clamp to the speed limit.

Gradients of ``ln pi`` (for (9)), with ``r = u - mu``::

    d ln pi / d W     = v_max r b^T / sigma^2                  shape (2, n)
    d ln pi / d sigma = -d / sigma + ||r||^2 / sigma^3

An optional second width ``sigma_blind`` applies where the *not visible* feature (the last one)
is on: the hand-made innate policy is a wide random search when the destination is not seen.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['ACTION_DIM', 'log_density', 'GaussianPolicy']

#: Dimension d of the action u = (v_left, v_right).
ACTION_DIM = 2


def log_density(u: ArrayLike, mean: ArrayLike, sigma: ArrayLike) -> np.ndarray:
    """Log of the isotropic Gaussian density (10).

    Parameters
    ----------
    u, mean : array_like, shape (..., d)
        Actions and means [m/s].
    sigma : array_like, shape (...) or scalar
        Standard deviations [m/s], > 0.

    Returns
    -------
    np.ndarray, shape (...)
        ``ln pi = -d/2 ln(2 pi sigma^2) - ||u - mean||^2 / (2 sigma^2)``.
    """
    u = np.asarray(u, dtype=np.float64)
    r = u - np.asarray(mean, dtype=np.float64)
    s2 = np.asarray(sigma, dtype=np.float64) ** 2
    d = u.shape[-1]
    # (10) ln pi = ln eta - ||u - W b||^2 / (2 sigma^2),  eta = (2 pi sigma^2)^(-d/2)
    return -0.5 * d * np.log(2.0 * math.pi * s2) - 0.5 * np.sum(r * r, axis=-1) / s2


class GaussianPolicy:
    """``u ~ N(v_max W b, sigma(b)^2 I_2)``: eq. (10) with the mean scaled to ``v_max``.

    Parameters
    ----------
    W : array_like, shape (2, n)
        Mean weights (copied).
    sigma : float
        Standard deviation of each wheel [m/s].
    v_max : float
        Speed limit of the module [m/s]: the mean is ``v_max W b``.
    sigma_blind : float, optional
        Standard deviation used where ``b[-1] >= 0.5`` (destination not visible); ``None``
        (default) uses ``sigma`` everywhere. Such rows carry no gradient with respect to sigma.
    """

    def __init__(self, W: ArrayLike, sigma: float, v_max: float,  # noqa: N803 - paper's W
                 sigma_blind: float | None = None) -> None:
        self.W = np.array(W, dtype=np.float64)
        if self.W.ndim != 2 or self.W.shape[0] != ACTION_DIM:
            raise ValueError(f'W must have shape (2, n), got {self.W.shape}')
        if not sigma > 0.0 or (sigma_blind is not None and not sigma_blind > 0.0):
            raise ValueError('sigma must be > 0')
        self.sigma = float(sigma)
        self.v_max = float(v_max)
        self.sigma_blind = None if sigma_blind is None else float(sigma_blind)

    @property
    def n(self) -> int:
        """Number of features n."""
        return self.W.shape[1]

    # ---------------------------------------------------------------------- one state

    def mean(self, b: ArrayLike) -> np.ndarray:
        """Mean action ``v_max W b`` [m/s], shape (2,), for features ``b`` of shape (n,)."""
        return self.v_max * (self.W @ np.asarray(b, dtype=np.float64))

    def sigma_at(self, b: ArrayLike) -> float:
        """Standard deviation [m/s] in the state with features ``b``."""
        if self.sigma_blind is not None and b[-1] >= 0.5:
            return self.sigma_blind
        return self.sigma

    def sample(self, b: ArrayLike, rng: np.random.Generator) -> np.ndarray:
        """Draw ``u ~ pi(b, .)``, shape (2,) [m/s] (two standard normals from ``rng``)."""
        return self.mean(b) + self.sigma_at(b) * rng.standard_normal(ACTION_DIM)

    def log_density(self, b: ArrayLike, u: ArrayLike) -> float:
        """``ln pi(b, u)`` of (10) for one state and action."""
        return float(log_density(u, self.mean(b), self.sigma_at(b)))

    def density(self, b: ArrayLike, u: ArrayLike) -> float:
        """``pi(b, u)`` of (10), in (m/s)^-2."""
        return math.exp(self.log_density(b, u))

    def score_W(self, b: ArrayLike, u: ArrayLike) -> np.ndarray:  # noqa: N802 - paper's W
        """``d ln pi(b, u) / d W = v_max (u - mu) b^T / sigma^2``, shape (2, n)."""
        b = np.asarray(b, dtype=np.float64)
        r = np.asarray(u, dtype=np.float64) - self.mean(b)
        return (self.v_max / self.sigma_at(b) ** 2) * np.outer(r, b)

    def score_sigma(self, b: ArrayLike, u: ArrayLike) -> float:
        """``d ln pi(b, u) / d sigma = -d / sigma + ||u - mu||^2 / sigma^3`` (0 if blind)."""
        if self.sigma_blind is not None and b[-1] >= 0.5:
            return 0.0
        r = np.asarray(u, dtype=np.float64) - self.mean(b)
        s = self.sigma
        return float(-ACTION_DIM / s + (r @ r) / s ** 3)

    # ---------------------------------------------------------------------- batches

    def mean_batch(self, B: ArrayLike) -> np.ndarray:  # noqa: N803 - features matrix
        """Means of many states: ``B`` shape (L, n) -> shape (L, 2) [m/s]."""
        return self.v_max * (np.asarray(B, dtype=np.float64) @ self.W.T)

    def sigma_batch(self, B: np.ndarray) -> np.ndarray:  # noqa: N803
        """Standard deviation of each state, shape (L,)."""
        s = np.full(B.shape[0], self.sigma)
        if self.sigma_blind is not None:
            s[B[:, -1] >= 0.5] = self.sigma_blind
        return s

    def log_density_batch(self, B: ArrayLike, U: ArrayLike) -> np.ndarray:  # noqa: N803
        """``ln pi`` of (10) for many (state, action) pairs: (L, n), (L, 2) -> (L,)."""
        B = np.asarray(B, dtype=np.float64)  # noqa: N806
        return log_density(U, self.mean_batch(B), self.sigma_batch(B))

    def density_batch(self, B: ArrayLike, U: ArrayLike) -> np.ndarray:  # noqa: N803
        """``pi`` of (10) for many (state, action) pairs -> shape (L,), in (m/s)^-2."""
        return np.exp(self.log_density_batch(B, U))

    def weighted_scores(self, B: ArrayLike, U: ArrayLike,  # noqa: N803
                        g: ArrayLike) -> tuple[np.ndarray, float]:
        """``sum_l g_l d ln pi(b_l, u_l) / d(W, sigma)`` without forming each score.

        Parameters
        ----------
        B : array_like, shape (L, n)
        U : array_like, shape (L, 2)
        g : array_like, shape (L,)
            Weight of each step.

        Returns
        -------
        dW : np.ndarray, shape (2, n)
            ``v_max sum_l g_l (u_l - mu_l) b_l^T / sigma_l^2``.
        dsigma : float
            ``sum_l g_l (-d / sigma + ||u_l - mu_l||^2 / sigma^3)`` over the rows that use
            ``sigma`` (not ``sigma_blind``).
        """
        B = np.asarray(B, dtype=np.float64)  # noqa: N806
        g = np.asarray(g, dtype=np.float64)
        r = np.asarray(U, dtype=np.float64) - self.mean_batch(B)     # (L, 2)
        s = self.sigma_batch(B)
        d_w = self.v_max * ((g / s ** 2)[:, None] * r).T @ B          # (2, n)
        own = np.ones(len(s), bool) if self.sigma_blind is None else B[:, -1] < 0.5
        rr = np.sum(r * r, axis=1)
        d_sigma = float(np.sum(g[own] * (-ACTION_DIM / self.sigma + rr[own] / self.sigma ** 3)))
        return d_w, d_sigma
