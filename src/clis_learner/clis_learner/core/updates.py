"""The update rules of CLIS: TD(lambda) with importance sampling (8), policy gradient with
importance sampling (9), and the semi-MDP discount (11).

Indexing (our reading of the paper's ``rho~_i(t + tau_i)``): module i's episode is the sequence
of its decision states ``x_0 .. x_{L-1}`` at times ``t_0 < .. < t_{L-1}``; step ``l`` is the
transition ``x_l -> x_{l+1}`` under the (resampled) action ``u_l = u(t_l)`` with the reward
``r_l`` summed over ``[t_l, t_{l+1})``. ``rho_l`` is the ratio of the action ``u_l`` that
generated step l (evaluated when the step completes, at ``t + tau_i``), so the product
``c_l = rho_0 ... rho_l`` weights the reward ``r_l`` by exactly the actions that preceded it.
The step after ``x_{L-1}`` ends the episode (goal or timeout): ``V(x_L) = 0`` (the time limit
is not part of any module's state, so a timeout is treated as terminal).
"""

from __future__ import annotations

from clis_modules.core.value import gamma_i
import numpy as np
from numpy.typing import ArrayLike

__all__ = ['C_MAX', 'gamma_i', 'importance_products', 'td_lambda_is', 'pg_weights',
           'policy_gradient_is']

#: Upper clip of the importance product ``c`` (never reached in practice; keeps it finite).
C_MAX = 1e100


def importance_products(rho: ArrayLike) -> np.ndarray:
    """``c_l = prod_{k <= l} rho_k`` (the ``c_i <- rho~_i c_i`` of (8) and (9), ``c`` = 1 before
    the first step), clipped to ``[0, C_MAX]``.

    Parameters
    ----------
    rho : array_like, shape (L,)

    Returns
    -------
    np.ndarray, shape (L,)
    """
    # (8)(9) c_i <- rho~_i c_i, from c_i = 1 at the episode start
    with np.errstate(over='ignore'):
        return np.minimum(np.cumprod(np.asarray(rho, dtype=np.float64)), C_MAX)


def td_lambda_is(w: ArrayLike, B: ArrayLike, r: ArrayLike, rho: ArrayLike,  # noqa: N803
                 gamma_i: float, lambda_: float, alpha: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TD(lambda) with importance sampling over one episode, eq. (8), online.

    For ``l = 0 .. L-1`` (module docstring for the indexing)::

        c     <- rho_l c
        delta <- r_l + gamma_i c V(x_{l+1}) - V(x_l)          V(x_L) = 0 (episode end)
        e     <- lambda gamma_i rho_l e + c b(x_l)            e = 0 at the start
        w     <- w + alpha delta e

    with ``V(x) = w^T b(x)`` at the current ``w`` (online: each step sees the previous update).

    Parameters
    ----------
    w : array_like, shape (n,)
        Value weights before the episode (not modified).
    B : array_like, shape (L, n)
        Features ``b(x_l)``.
    r : array_like, shape (L,)
        Rewards ``r_l`` of each step.
    rho : array_like, shape (L,)
        Ratios ``rho~_l`` (7).
    gamma_i, lambda_, alpha : float
        Discount per step (11), trace decay, step size.

    Returns
    -------
    w : np.ndarray, shape (n,)
        Weights after the episode.
    delta : np.ndarray, shape (L,)
        TD errors.
    c : np.ndarray, shape (L,)
        Importance products after each step.
    """
    w = np.array(w, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)  # noqa: N806
    rho = np.asarray(rho, dtype=np.float64)
    c = importance_products(rho)
    n_steps = B.shape[0]
    e = np.zeros_like(w)
    delta = np.empty(n_steps)
    decay = (lambda_ * gamma_i * rho).tolist()
    r_list, c_list = np.asarray(r, dtype=np.float64).tolist(), c.tolist()
    for l in range(n_steps):  # noqa: E741 - the paper's step index
        b = B[l]
        v = float(w @ b)
        v_next = float(w @ B[l + 1]) if l + 1 < n_steps else 0.0
        # (8) delta_i <- r + gamma_i c_i V_i(x') - V_i(x)
        d = r_list[l] + gamma_i * c_list[l] * v_next - v
        # (8) e_i <- lambda_i gamma_i rho~_i e_i + c_i b_i(x)
        e *= decay[l]
        e += c_list[l] * b
        # (8) w_i <- w_i + alpha_i delta_i e_i
        w += (alpha * d) * e
        delta[l] = d
    return w, delta, c


def pg_weights(r: ArrayLike, c: ArrayLike, gamma_i: float) -> np.ndarray:
    """Weight of each step's score in the policy gradient of one episode, eq. (9).

    (9) adds ``alpha gamma_i^l r_l c_l e_l`` at every step, with the trace
    ``e_l = sum_{k <= l} d ln pi(x_k, u_k) / dW``. The scores are evaluated at the policy of the
    episode (it is not updated while the episode is replayed), so the sum of the updates is
    ``alpha sum_k G_k d ln pi(x_k, u_k) / dW`` with the reverse cumulative sum::

        G_k = sum_{l >= k} gamma_i^l r_l c_l

    Parameters
    ----------
    r, c : array_like, shape (L,)
        Rewards and importance products of each step.
    gamma_i : float

    Returns
    -------
    np.ndarray, shape (L,)
    """
    r = np.asarray(r, dtype=np.float64)
    # (9) per-step factor gamma_i^t r(t + tau_i) c_i, t = step index on module i's grid
    x = gamma_i ** np.arange(len(r)) * r * np.asarray(c, dtype=np.float64)
    return np.cumsum(x[::-1])[::-1]


def policy_gradient_is(scores: ArrayLike, r: ArrayLike, rho: ArrayLike, gamma_i: float,
                       alpha: float) -> np.ndarray:
    """Total change of the policy parameters over one episode by (9).

    ::

        c <- rho_l c;   e <- e + d ln pi(x_l, u_l) / dW;   W <- W + alpha gamma_i^l r_l c e

    Parameters
    ----------
    scores : array_like, shape (L, P)
        ``d ln pi(x_l, u_l) / d theta`` of each step (flattened parameters).
    r, rho : array_like, shape (L,)
    gamma_i, alpha : float

    Returns
    -------
    np.ndarray, shape (P,)
        ``alpha sum_k G_k scores_k`` (:func:`pg_weights`).
    """
    g = pg_weights(r, importance_products(rho), gamma_i)
    return alpha * (g @ np.asarray(scores, dtype=np.float64))
