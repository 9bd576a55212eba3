"""The localization's step kernels, for the tests: each one step of the reference updates
(:mod:`clis_modules.core.localization_reference`), compiled with the project's ``njit``, the
arithmetic the fused kernels of :mod:`clis_modules.core.localization_fused` run without their
intermediate arrays. ``test/test_sim_kernels.py`` checks each against numpy and scipy, and the
fused updates against their composition, bit for bit.

:func:`shift_pose` (steps 1-2 of the motion update), :func:`gaussian_weights` and :func:`blur`
(step 3, ``scipy.ndimage.gaussian_filter``'s arithmetic), :func:`log_likelihood` (the von Mises
sum at every sub-pose), :func:`row_max`, :func:`unclipped`, :func:`sub_pose_sums` (the
likelihood of every cell).
"""

from __future__ import annotations

from clis_modules.core.localization_fused import _blur_passes, _shift_into
from cr_sim.core.kernels import njit
import numpy as np

__all__ = ['gaussian_weights', 'blur', 'shift_pose', 'log_likelihood', 'row_max', 'unclipped',
           'sub_pose_sums']


def gaussian_weights(sigma: float, truncate: float) -> np.ndarray:
    """Normalised Gaussian weights of std ``sigma`` [cells] over ``+-int(truncate sigma + 1/2)``
    (``scipy.ndimage``'s kernel, its arithmetic), shape (2 r + 1,); empty when ``sigma`` is
    (nearly) 0: that axis is not blurred."""
    if not sigma > 1e-15:
        return np.zeros(0)
    radius = int(truncate * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1)
    # phi(x) = exp(-x^2 / (2 sigma^2)), normalised
    phi = np.exp(-0.5 / (sigma * sigma) * x ** 2)
    return phi / phi.sum()


@njit
def blur(p: np.ndarray, w0: np.ndarray, w1: np.ndarray, w2: np.ndarray) -> np.ndarray:
    """Separable Gaussian blur of ``p`` (K, nx, ny), C-contiguous: axis 0 periodic (``wrap``),
    axes 1 and 2 mirrored at the walls (``reflect``), one axis after the other, each with its
    symmetric weights ``w`` (2 r + 1,) (empty: the axis is skipped). A new array
    (:func:`~clis_modules.core.localization_fused._blur_passes`).

    ``scipy.ndimage.gaussian_filter``'s arithmetic (its correlate1d of a symmetric kernel:
    ``out = x[0] w[r] + sum_{j = -r .. -1} (x[j] + x[-j]) w[r + j]``, in that order), so the
    results are the same bit for bit; the loops run over whole contiguous rows.
    """
    return _blur_passes(p.copy(), np.empty_like(p), w0, w1, w2)


@njit
def shift_pose(p: np.ndarray, cos_k: np.ndarray, sin_k: np.ndarray, dx: float, dy: float,
               dtheta: float, cell: float, bin_: float) -> np.ndarray:
    """Steps 1-2 of the motion update (:func:`~clis_modules.core.localization_reference.shift`)
    of ``p`` (K, nx, ny) into a new array
    (:func:`~clis_modules.core.localization_fused._shift_into`); ``cos_k``, ``sin_k`` (K,) of
    the heading-bin centres."""
    n_k, nx, ny = p.shape
    pad = max(nx, ny) + 2
    out = np.empty_like(p)
    _shift_into(p, cos_k, sin_k, dx, dy, dtheta, cell, bin_,
                np.zeros((n_k, nx + 2 * pad, ny + 2 * pad)), np.empty_like(p), out)
    return out


@njit
def log_likelihood(cos_z: np.ndarray, sin_z: np.ndarray, seen: np.ndarray, kappa: float,
                   cos_phi: np.ndarray, sin_phi: np.ndarray, cos_th: np.ndarray,
                   sin_th: np.ndarray) -> np.ndarray:
    """``kappa sum_m cos(s_m - mu_m)`` at every sub-pose
    (:func:`~clis_modules.core.localization_reference.log_likelihood`).

    Parameters
    ----------
    cos_z, sin_z : np.ndarray, shape (M,)
        Of the observed bearings; ``seen`` (M,) which are used.
    cos_phi, sin_phi : np.ndarray, shape (Q, M, nx, ny)
        Of the landmark directions from each sub-position q of each cell.
    cos_th, sin_th : np.ndarray, shape (K, T)
        Of each sub-heading t of each heading bin k.

    Returns
    -------
    np.ndarray, shape (Q T, K, nx, ny)
        Sub-pose major (q, then t).
    """
    n_q, n_m, nx, ny = cos_phi.shape
    n_k, n_t = cos_th.shape
    # C = kappa sum_m cos(s_m - phi_m), S = kappa sum_m sin(s_m - phi_m), per sub-position
    cc = np.zeros((n_q, nx, ny))
    ss = np.zeros((n_q, nx, ny))
    for q in range(n_q):
        for m in range(n_m):
            if seen[m]:
                for i in range(nx):
                    for j in range(ny):
                        cp, sp = cos_phi[q, m, i, j], sin_phi[q, m, i, j]
                        cc[q, i, j] += cos_z[m] * cp + sin_z[m] * sp
                        ss[q, i, j] += sin_z[m] * cp - cos_z[m] * sp
    cc *= kappa
    ss *= kappa
    out = np.empty((n_q * n_t, n_k, nx, ny))
    for q in range(n_q):
        for t in range(n_t):
            for k in range(n_k):
                ct, st = cos_th[k, t], sin_th[k, t]
                for i in range(nx):
                    for j in range(ny):
                        # kappa cos(A + theta) = C cos theta - S sin theta
                        out[q * n_t + t, k, i, j] = cc[q, i, j] * ct - ss[q, i, j] * st
    return out


@njit
def row_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=0)`` of ``a`` (S, N) without NaN: the best sub-pose of each cell."""
    out = a[0].copy()
    for s in range(1, a.shape[0]):
        for i in range(a.shape[1]):
            out[i] = max(out[i], a[s, i])
    return out


@njit
def unclipped(a: np.ndarray, cell_max: np.ndarray, best: float, low: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """The cells (columns of ``a`` (S, N)) with an entry ``v = a - best > low``
    (``cell_max`` (N,) their maxima), and those entries ``v``, cell by cell, rows in order."""
    n_sub, n = a.shape
    cells = np.empty(n, dtype=np.int64)
    vals = np.empty(n * n_sub)
    n_cells = m = 0
    for i in range(n):
        if max(cell_max[i] - best, low) > low:
            cells[n_cells] = i
            n_cells += 1
            for s in range(n_sub):
                v = max(a[s, i] - best, low)
                if v > low:
                    vals[m] = v
                    m += 1
    return cells[:n_cells], vals[:m]


@njit
def sub_pose_sums(a: np.ndarray, cells: np.ndarray, best: float, low: float, exp_low: float,
                  exps: np.ndarray) -> np.ndarray:
    """Per column of ``a`` (S, N), ``sum_s exp(max(a[s] - best, low))`` added row after row
    (as ``a.sum(axis=0)`` adds rows), with ``exp_low`` for the clipped entries and ``exps``
    for the others, in :func:`unclipped`'s order (``cells``: the columns that have any)."""
    n_sub, n = a.shape
    const = exp_low                         # a column with every entry clipped
    for _ in range(1, n_sub):
        const += exp_low
    out = np.full(n, const)
    m = 0
    for i in cells:
        acc = 0.0
        for s in range(n_sub):
            e = exp_low
            if max(a[s, i] - best, low) > low:
                e = exps[m]
                m += 1
            acc = e if s == 0 else acc + e
        out[i] = acc
    return out
