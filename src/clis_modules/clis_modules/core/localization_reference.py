"""Grid Markov localization on landmark bearings, the place module's state (paper III-D): the
model, and its two updates as the paper writes them, in numpy and scipy. This is the reference
of the compiled path (:mod:`clis_modules.core.localization_fused`), which gives the same
beliefs bit for bit (tested).

Grid. The belief ``b_pl`` is a probability over a grid of poses ``(x, y, theta)``: square
cells of side ``cell_size`` over the floor (a square, or any rectangle), times ``n_headings``
heading bins. Paper: 15 cm and 30 deg over 3 m x 3 m, "450 states"; that grid has
20 x 20 x 12 = 4800 cells (450 matches neither 20 x 20 = 400 nor any whole number of 30 deg
bins), so we keep the stated resolutions and get 4800 cells; both resolutions are parameters.

Array layout: ``belief_grid[k, i, j]`` is the probability of heading bin ``k`` (centre
``theta_k = k 2 pi / n_headings``), x cell ``i`` and y cell ``j`` (centres ``xs[i]``,
``ys[j]``); the flat belief (the place module's feature vector) is its C-order ravel.

Initial belief: uniform over the free cells (paper III-D: the robot does not know its start).
Cells whose centre lies inside an obstacle box (optional) always hold 0.

Motion update (paper III-D: ``b(x') <- sum_x Pr(x' | x, u) b(x)``, :func:`predict`), from
odometry ``u = (dx, dy, dtheta)`` expressed in the robot frame at the start of the interval:

1. every heading layer ``k`` is shifted by the displacement rotated into the world,
   ``R(theta_k) (dx, dy)``, with bilinear weights (mass conserving; mass leaving the floor is
   dropped: those poses contradict the odometry);
2. the heading axis is rolled by ``dtheta`` (periodic, linear weights between bins);
3. Gaussian noise: a blur of standard deviation ``trans_noise * |d| + trans_noise_min`` in x and
   y (reflecting at the walls) and ``rot_noise * |dtheta| + rot_noise_min`` in heading
   (periodic), :func:`scipy.ndimage.gaussian_filter`. The ``*_min`` terms also stand for the
   spread of the true pose inside a cell; they are added per call, so the motion update runs
   once per place-module period (not once per simulator tick).

Sensor update (paper III-D: ``b(x) <- eta Pr(s | x) b(x)``, :func:`update`): the bearings ``s``
of the landmarks that are seen, each with a von Mises likelihood around the bearing expected
from the cell centre, ``Pr(s | x) = prod_m exp(kappa cos(s_m - mu_m(x)))`` with
``kappa = 1 / sigma_bearing^2`` (the von Mises approximation of a wrapped Gaussian of std
``sigma_bearing``). The true pose is anywhere inside its cell, so a cell's likelihood is the
mean over ``sub_cells^2 x sub_headings`` sub-poses spread inside it (with only the cell centre,
the 30 deg bins force a wide ``sigma_bearing`` and the position becomes ambiguous along ridges
near the corners: measured, 65 % of MAP cells within 1 cell of the truth against 94 % with
2 x 2 x 3 sub-poses). The bearing expected at a sub-pose ``(p, theta)`` is
``mu_m = phi_m(p) - theta``, ``phi_m(p)`` the direction of landmark m from position p, so with
``A_m = s_m - phi_m(p)``::

    sum_m kappa cos(s_m - mu_m) = kappa (C(p) cos theta - S(p) sin theta),
    C(p) = sum_m cos A_m,  S(p) = sum_m sin A_m     (sums over the seen landmarks)

``cos phi_m`` and ``sin phi_m`` of every sub-position are computed once per grid; an update
forms C and S per sub-position and the log-likelihood of every sub-pose from them
(:func:`log_likelihood`), relative to the best, clipped :data:`LOG_LIK_MIN` below it, then exp.
A landmark that is not seen (NaN) adds no information (occlusion is not modelled). The result is
normalised, then ``floor`` of a uniform belief is mixed in so that no pose is ever ruled out for
good; a belief that contradicts the reading (evidence below :data:`EVIDENCE_MIN` of the best
cell's likelihood: the kidnapped robot, or ``floor = 0``) restarts from the reading alone.

Each function takes the localizer for the grid's geometry (:class:`PoseGrid`: the public names
of :class:`~clis_modules.core.localization.MarkovLocalizer` it reads) and a belief
``p`` (K, nx, ny), and returns a new belief; neither changes the localizer.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

__all__ = ['LOG_LIK_MIN', 'EXP_LOG_LIK_MIN', 'EVIDENCE_MIN', 'PoseGrid', 'shift', 'predict',
           'log_likelihood', 'update']

#: Log-likelihoods below the best by more than this are clipped (e^-50 ~ 2e-22: nothing).
LOG_LIK_MIN = -50.0
#: ``exp(LOG_LIK_MIN)`` as numpy's exp computes it.
EXP_LOG_LIK_MIN = float(np.exp(np.array([LOG_LIK_MIN]))[0])
#: Evidence ``sum_x Pr(s | x) b(x)`` (the best cell's likelihood scaled to 1) below which the
#: belief is taken to contradict the reading, and the update restarts from the reading alone.
EVIDENCE_MIN = 1e-15


class PoseGrid(Protocol):
    """What the updates read of a localizer (the public names of
    :class:`~clis_modules.core.localization.MarkovLocalizer`).

    Attributes
    ----------
    params : LocalizationParams
        ``trans_noise``, ``trans_noise_min``, ``rot_noise``, ``rot_noise_min_deg``, ``floor``.
    thetas : np.ndarray, shape (K,)
        Heading-bin centres [rad].
    cell, bin : float
        Cell side [m], heading bin [rad].
    kappa : float
        ``1 / sigma_bearing^2`` of the von Mises likelihood.
    free, uniform : np.ndarray, shape (K, nx, ny)
        1 on the free cells, 0 inside the obstacles; the uniform belief over the free cells.
    cos_phi, sin_phi : np.ndarray, shape (Q, M, nx, ny)
        Of the direction ``phi_m(p)`` of landmark m from sub-position q of each cell.
    cos_th, sin_th : np.ndarray, shape (K, T)
        Of sub-heading t of each heading bin.
    """

    params: Any
    thetas: np.ndarray
    cell: float
    bin: float
    kappa: float

    @property
    def free(self) -> np.ndarray: ...

    @property
    def uniform(self) -> np.ndarray: ...

    @property
    def cos_phi(self) -> np.ndarray: ...

    @property
    def sin_phi(self) -> np.ndarray: ...

    @property
    def cos_th(self) -> np.ndarray: ...

    @property
    def sin_th(self) -> np.ndarray: ...


def shift(loc: PoseGrid, p: np.ndarray, dx: float, dy: float, dtheta: float) -> np.ndarray:
    """Steps 1-2 of the motion update: every heading layer ``k`` of ``p`` (K, nx, ny) moved by
    the displacement ``R(theta_k) (dx, dy)`` in cells (bilinear weights; mass leaving the grid
    is dropped), then the heading axis rolled by ``dtheta`` (linear weights between bins)."""
    n_k, nx, ny = p.shape
    c, s = np.cos(loc.thetas), np.sin(loc.thetas)
    # the displacement of layer k in cells, R(theta_k) (dx, dy), clipped to the grid's size
    # plus one
    sx = np.clip((c * dx - s * dy) / loc.cell, -nx - 1.0, nx + 1.0)
    sy = np.clip((s * dx + c * dy) / loc.cell, -ny - 1.0, ny + 1.0)
    ix, iy = np.floor(sx).astype(int), np.floor(sy).astype(int)
    fx, fy = (sx - ix)[:, None, None], (sy - iy)[:, None, None]
    # mass at cell c moves to c + i + f: q[c] = (1 - f) p[c - i] + f p[c - i - 1], per axis
    pad = max(nx, ny) + 2
    padded = np.zeros((n_k, nx + 2 * pad, ny + 2 * pad))
    padded[:, pad:pad + nx, pad:pad + ny] = p
    k = np.arange(n_k)[:, None, None]
    rows = (pad + np.arange(nx)[None, :] - ix[:, None])[:, :, None]      # (K, nx, 1)
    cols = (pad + np.arange(ny)[None, :] - iy[:, None])[:, None, :]      # (K, 1, ny)
    a0 = (1.0 - fx) * padded[k, rows, cols] + fx * padded[k, rows - 1, cols]
    a1 = (1.0 - fx) * padded[k, rows, cols - 1] + fx * padded[k, rows - 1, cols - 1]
    q = (1.0 - fy) * a0 + fy * a1
    # the heading roll: out[k] = (1 - f) q[k - i] + f q[k - i - 1] (indices mod K)
    st = dtheta / loc.bin
    it = int(math.floor(st))
    ft = st - math.floor(st)
    if ft == 0.0:
        return np.roll(q, it, axis=0)
    return (1.0 - ft) * np.roll(q, it, axis=0) + ft * np.roll(q, it + 1, axis=0)


def predict(loc: PoseGrid, p: np.ndarray, dx: float, dy: float, dtheta: float) -> np.ndarray:
    """Motion update ``b(x') <- sum_x Pr(x' | x, u) b(x)`` (paper III-D) of ``p`` (K, nx, ny)
    by the odometry ``u = (dx, dy, dtheta)`` [m, m, rad] (robot frame at the interval's
    start)."""
    prm = loc.params
    q = shift(loc, p, dx, dy, dtheta)
    # Pr(x' | x, u): Gaussian noise of std proportional to the distance and the turn plus a
    # floor, in cells and bins; headings periodic, walls mirroring
    s_xy = (prm.trans_noise * math.hypot(dx, dy) + prm.trans_noise_min) / loc.cell
    s_th = (prm.rot_noise * abs(dtheta) + math.radians(prm.rot_noise_min_deg)) / loc.bin
    if s_xy > 0.0 or s_th > 0.0:
        q = ndimage.gaussian_filter(q, sigma=(s_th, s_xy, s_xy), truncate=3.0,
                                    mode=('wrap', 'reflect', 'reflect'))
    q = q * loc.free                                      # no pose inside an obstacle
    total = q.sum()
    if not (total > 0.0 and math.isfinite(total)):
        return loc.uniform.copy()
    # b(x') <- sum_x Pr(x' | x, u) b(x), normalised over the free cells (paper III-D)
    return q / total


def log_likelihood(loc: PoseGrid, z: np.ndarray) -> np.ndarray:
    """``ln Pr(s | x') = sum_m kappa cos(s_m - mu_m(x'))`` (von Mises per seen landmark) at
    every sub-pose ``x' = (p, theta)``: ``kappa (C(p) cos theta - S(p) sin theta)`` with
    ``C = sum_m cos(s_m - phi_m(p))``, ``S = sum_m sin(s_m - phi_m(p))``; shape
    (Q T, K, nx, ny), sub-positions q then sub-headings t."""
    seen = np.isfinite(z)
    cos_phi, sin_phi = loc.cos_phi, loc.sin_phi
    c_sum = np.zeros(cos_phi[:, 0].shape)                            # (Q, nx, ny)
    s_sum = np.zeros(cos_phi[:, 0].shape)
    for m in np.flatnonzero(seen):
        cz, sz = math.cos(z[m]), math.sin(z[m])
        cp, sp = cos_phi[:, m], sin_phi[:, m]
        # cos(s - phi) = cos s cos phi + sin s sin phi; sin(s - phi) likewise
        c_sum += cz * cp + sz * sp
        s_sum += sz * cp - cz * sp
    c_sum *= loc.kappa
    s_sum *= loc.kappa
    n_q = c_sum.shape[0]
    cos_th, sin_th = loc.cos_th, loc.sin_th
    n_k, n_t = cos_th.shape
    # kappa cos(A + theta) = C cos theta - S sin theta, at every sub-heading of every bin
    ll = (c_sum[:, None, None] * cos_th.T[None, :, :, None, None]
          - s_sum[:, None, None] * sin_th.T[None, :, :, None, None])  # (Q, T, K, nx, ny)
    return ll.reshape(n_q * n_t, n_k, *c_sum.shape[1:])


def update(loc: PoseGrid, p: np.ndarray, landmark_bearings: ArrayLike) -> np.ndarray:
    """Sensor update ``b(x) <- eta Pr(s | x) b(x)`` (paper III-D) of ``p`` (K, nx, ny) on the
    landmark bearings (M,) (NaN = not seen; nothing seen: ``p`` itself)."""
    z = np.asarray(landmark_bearings, dtype=np.float64).reshape(-1)
    if not np.isfinite(z).any():
        return p
    # Pr(s | cell): the mean over the sub-poses spread inside it of Pr(s | x'), relative to
    # the best sub-pose, each clipped LOG_LIK_MIN below it (no denormals)
    ll = log_likelihood(loc, z)
    rows = ll.reshape(ll.shape[0], -1)                               # (Q T, N)
    v = np.maximum(rows - rows.max(), LOG_LIK_MIN)
    e = np.full(v.shape, EXP_LOG_LIK_MIN)
    e[v > LOG_LIK_MIN] = np.exp(v[v > LOG_LIK_MIN])
    lik = e.sum(axis=0).reshape(p.shape)
    # b(x) <- eta Pr(s | x) b(x) (paper III-D); a belief that rules the reading out restarts
    # from it
    q = lik * p
    total = q.sum()
    if not (total > EVIDENCE_MIN and math.isfinite(total)):
        q = lik * loc.uniform
        total = q.sum()
    # and the floor of a uniform belief, so that no pose is ruled out for good
    floor = loc.params.floor
    q *= (1.0 - floor) / total
    if floor > 0.0:
        q += floor * loc.uniform
    return q
