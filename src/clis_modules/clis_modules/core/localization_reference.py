"""The place module's grid Markov localization as the paper writes it (Sec. III-D), in numpy
and scipy: the reference of the compiled path (:mod:`clis_modules.core.localization_fused`),
which gives the same beliefs bit for bit (tested).

The belief ``b(x)`` lives on the grid of :class:`~clis_modules.core.localization.MarkovLocalizer`
(heading bins ``k``, cells ``(i, j)``; its module docstring has the model). Each function takes
that localizer for the grid's geometry and returns a new belief; neither changes it.

    predict:  b(x') <- sum_x Pr(x' | x, u) b(x)          motion update, u = odometry
    update:   b(x)  <- eta Pr(s | x) b(x)                 sensor update, s = landmark bearings
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

from clis_modules.core.localization_fused import EVIDENCE_MIN, EXP_LOG_LIK_MIN, LOG_LIK_MIN

__all__ = ['shift', 'predict', 'update']


def shift(loc: Any, p: np.ndarray, dx: float, dy: float, dtheta: float) -> np.ndarray:
    """Steps 1-2 of the motion update: every heading layer ``k`` of ``p`` (K, nx, ny) moved by
    the displacement ``R(theta_k) (dx, dy)`` in cells (bilinear weights; mass leaving the grid
    is dropped), then the heading axis rolled by ``dtheta`` (linear weights between bins)."""
    n_k, nx, ny = p.shape
    c, s = np.cos(loc.thetas), np.sin(loc.thetas)
    # the displacement of layer k in cells, clipped to the grid's size plus one
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


def predict(loc: Any, p: np.ndarray, dx: float, dy: float, dtheta: float) -> np.ndarray:
    """Motion update ``b(x') <- sum_x Pr(x' | x, u) b(x)`` of ``p`` (K, nx, ny) by the odometry
    ``u = (dx, dy, dtheta)`` [m, m, rad] (robot frame at the interval's start)."""
    prm = loc.params
    q = shift(loc, p, dx, dy, dtheta)
    # Pr(x' | x, u): Gaussian noise of std proportional to the distance and the turn plus a
    # floor, in cells and bins; headings periodic, walls mirroring
    s_xy = (prm.trans_noise * math.hypot(dx, dy) + prm.trans_noise_min) / loc.cell
    s_th = (prm.rot_noise * abs(dtheta) + math.radians(prm.rot_noise_min_deg)) / loc.bin
    if s_xy > 0.0 or s_th > 0.0:
        q = ndimage.gaussian_filter(q, sigma=(s_th, s_xy, s_xy), truncate=3.0,
                                    mode=('wrap', 'reflect', 'reflect'))
    q = q * loc._free                                     # no pose inside an obstacle
    total = q.sum()
    if not (total > 0.0 and math.isfinite(total)):
        return loc._uniform.copy()
    return q / total


def log_likelihood(loc: Any, z: np.ndarray) -> np.ndarray:
    """``ln Pr(s | x') = sum_m kappa cos(s_m - mu_m(x'))`` (von Mises per seen landmark) at
    every sub-pose ``x' = (p, theta)``: ``kappa (C(p) cos theta - S(p) sin theta)`` with
    ``C = sum_m cos(s_m - phi_m(p))``, ``S = sum_m sin(s_m - phi_m(p))``; shape
    (Q T, K, nx, ny), sub-positions q then sub-headings t."""
    seen = np.isfinite(z)
    c_sum = np.zeros(loc._cos_phi[:, 0].shape)                       # (Q, nx, ny)
    s_sum = np.zeros(loc._cos_phi[:, 0].shape)
    for m in np.flatnonzero(seen):
        cz, sz = math.cos(z[m]), math.sin(z[m])
        cp, sp = loc._cos_phi[:, m], loc._sin_phi[:, m]
        # cos(s - phi) = cos s cos phi + sin s sin phi; sin(s - phi) likewise
        c_sum += cz * cp + sz * sp
        s_sum += sz * cp - cz * sp
    c_sum *= loc.kappa
    s_sum *= loc.kappa
    n_q = c_sum.shape[0]
    n_k, n_t = loc._cos_th.shape
    ll = (c_sum[:, None, None] * loc._cos_th.T[None, :, :, None, None]
          - s_sum[:, None, None] * loc._sin_th.T[None, :, :, None, None])  # (Q, T, K, nx, ny)
    return ll.reshape(n_q * n_t, n_k, *c_sum.shape[1:])


def update(loc: Any, p: np.ndarray, landmark_bearings: ArrayLike) -> np.ndarray:
    """Sensor update ``b(x) <- eta Pr(s | x) b(x)`` of ``p`` (K, nx, ny) on the landmark
    bearings (M,) (NaN = not seen; nothing seen: ``p`` itself)."""
    z = np.asarray(landmark_bearings, dtype=np.float64).reshape(-1)
    if not np.isfinite(z).any():
        return p
    # Pr(s | cell): the mean over the sub-poses spread inside it of Pr(s | x'), relative to
    # the best sub-pose, each clipped LOG_LIK_MIN below it (no denormals)
    rows = log_likelihood(loc, z).reshape(loc._n_sub, -1)
    v = np.maximum(rows - rows.max(), LOG_LIK_MIN)
    e = np.full(v.shape, EXP_LOG_LIK_MIN)
    e[v > LOG_LIK_MIN] = np.exp(v[v > LOG_LIK_MIN])
    lik = e.sum(axis=0).reshape(p.shape)
    # b(x) <- eta Pr(s | x) b(x); a belief that rules the reading out restarts from it
    q = lik * p
    total = q.sum()
    if not (total > EVIDENCE_MIN and math.isfinite(total)):
        q = lik * loc._uniform
        total = q.sum()
    # and the floor of a uniform belief, so that no pose is ruled out for good
    floor = loc.params.floor
    q *= (1.0 - floor) / total
    if floor > 0.0:
        q += loc._floor_uniform
    return q
