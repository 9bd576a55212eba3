"""Rate conversion between the behaviour module's and each module's decision grid (paper II-E).

"The actual tuple of (x, u, r) is obtained every tau_i' steps while the state for M_i is
obtained every tau_i steps. Therefore, we have to resample the data points. We use cubic spline
interpolation to estimate them."

* :func:`resample_actions` -- the executed actions (change points every ``tau_i'``) at module
  i's decision times ``l tau_i``: ``'spline'`` (the paper: :class:`scipy.interpolate.CubicSpline`,
  not-a-knot, through the change points) or ``'zoh'`` (zero-order hold: the command in force,
  which is what the robot actually executed -- it is piecewise constant between decisions).
  A query that coincides with a knot returns that knot exactly (so equal grids, the Sync
  condition, give the identity on either method); queries after the last knot hold the last
  command (it stays in force until the end; a spline would extrapolate); queries before the
  first knot take the first command.
* :func:`sum_rewards` -- the reward of each interval ``(t_l, t_{l+1}]`` of module i's grid,
  the last one ``(t_L, end]``: ``r(t + tau_i)`` of (8) and (9), with each reward stamped at the
  end of the step that earned it (:mod:`~clis_learner.core.memory`). Rewards at or before
  ``t_0`` go to the first interval, so the total is always preserved.
* :func:`latest_index` -- index of the latest grid time ``<= t`` (the behaviour's decision in
  force, whose features give ``pi_i'`` in (7)).

Times are compared with the tolerance :data:`~clis_learner.core.memory.TIME_TOL`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

from clis_learner.core.memory import TIME_TOL

__all__ = ['RESAMPLE_METHODS', 'ActionTrack', 'latest_index', 'resample_actions', 'sum_rewards']

#: Resampling methods of :func:`resample_actions`.
RESAMPLE_METHODS = ('spline', 'zoh')


def latest_index(t_grid: ArrayLike, t: ArrayLike) -> np.ndarray:
    """Index of the latest ``t_grid`` entry ``<= t`` (within the tolerance), clipped to >= 0.

    Parameters
    ----------
    t_grid : array_like, shape (K,)
        Increasing times, K >= 1.
    t : array_like, shape (L,)

    Returns
    -------
    np.ndarray of int, shape (L,)
    """
    idx = np.searchsorted(np.asarray(t_grid), np.asarray(t) + TIME_TOL, side='right') - 1
    return np.maximum(idx, 0)


def resample_actions(t_knots: ArrayLike, u_knots: ArrayLike, t_query: ArrayLike,
                     method: str) -> np.ndarray:
    """Actions at the query times (module docstring).

    Parameters
    ----------
    t_knots : array_like, shape (K,)
        Times of the action change points, increasing, K >= 1.
    u_knots : array_like, shape (K, d)
        Actions from each change point on.
    t_query : array_like, shape (L,)
        Module i's decision times.
    method : {'spline', 'zoh'}

    Returns
    -------
    np.ndarray, shape (L, d)
    """
    return ActionTrack(t_knots, u_knots, method).at(t_query)


class ActionTrack:
    """The executed actions of one episode, resampled onto any grid (:func:`resample_actions`):
    the spline through the change points is fitted once (on first use) for all the grids
    (every module's) of the episode; each query point is evaluated on its own, so the values
    are those of :func:`resample_actions` bit for bit.

    Parameters
    ----------
    t_knots, u_knots, method
        As for :func:`resample_actions`.
    """

    def __init__(self, t_knots: ArrayLike, u_knots: ArrayLike, method: str) -> None:
        self.tk = np.asarray(t_knots, dtype=np.float64)
        self.uk = np.asarray(u_knots, dtype=np.float64).reshape(len(self.tk), -1)
        if method not in RESAMPLE_METHODS:
            raise ValueError(f'unknown resampling method {method!r}: {RESAMPLE_METHODS}')
        if len(self.tk) == 0:
            raise ValueError('no action to resample')
        self.method = method
        self._spline: CubicSpline | None = None

    def at(self, t_query: ArrayLike) -> np.ndarray:
        """Actions at the query times ``t_query`` (L,) -> shape (L, d)."""
        tk, uk = self.tk, self.uk
        tq = np.asarray(t_query, dtype=np.float64)
        idx = latest_index(tk, tq)
        out = uk[idx].copy()                                   # zero-order hold
        if self.method == 'spline' and len(tk) >= 2:
            on_knot = np.abs(tq - tk[idx]) <= TIME_TOL
            inside = (tq > tk[0]) & (tq < tk[-1]) & ~on_knot
            if inside.any():
                if self._spline is None:
                    self._spline = CubicSpline(tk, uk, axis=0)
                out[inside] = self._spline(tq[inside])
        return out


def sum_rewards(t_rewards: ArrayLike, rewards: ArrayLike, t_grid: ArrayLike) -> np.ndarray:
    """Reward of each interval ``(t_l, t_{l+1}]`` of the grid (module docstring).

    Parameters
    ----------
    t_rewards : array_like, shape (R,)
        Reward times (end of the step that earned each).
    rewards : array_like, shape (R,)
    t_grid : array_like, shape (L,)
        Module i's decision times, increasing, L >= 1.

    Returns
    -------
    np.ndarray, shape (L,)
        Interval sums; ``sum`` equals ``sum(rewards)``.
    """
    t_grid = np.asarray(t_grid, dtype=np.float64)
    # latest grid time strictly before the reward's stamp (within the tolerance)
    idx = np.maximum(np.searchsorted(
        t_grid, np.asarray(t_rewards, dtype=np.float64) - TIME_TOL, side='left') - 1, 0)
    return np.bincount(idx, weights=np.asarray(rewards, dtype=np.float64),
                       minlength=len(t_grid)).astype(np.float64)
