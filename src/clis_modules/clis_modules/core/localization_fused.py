"""The compiled path of the grid Markov localization (:mod:`clis_modules.core.localization`):
its motion and sensor updates, each as one compiled call, the arithmetic of the reference
(:mod:`clis_modules.core.localization_reference`, which has the model and its constants) in the
same order, bit for bit (tested).

:func:`predict_into` and :func:`update_into` are the entry points; what they need of the grid
is a :class:`Grid` and their scratch arrays a :class:`Scratch`, both made once per localizer
(:class:`~clis_modules.core.localization.MarkovLocalizer` builds its :class:`Grid`, then
:meth:`Scratch.for_grid`).

Step kernels: :func:`_shift_into` (steps 1-2 of the motion update, the reference's ``shift``)
and :func:`_blur_passes` (step 3, ``scipy.ndimage.gaussian_filter``'s arithmetic). Fused kernels
(:func:`_predict_kernel`, :func:`_update_kernel`): the operations of the reference's steps and
of numpy's sums (:func:`clis_base.ufunc_loops.pairwise_sum`) in the same order, without their
intermediate arrays; the sensor update skips only sub-poses that are clipped anyway (bounded by
``hypot(C, S)``), and its ``exp`` is numpy's own loop (:func:`clis_base.ufunc_loops.exp_into`).
The tests check each step against numpy and scipy, and the fused kernels against the steps
composed (``test/localization_kernels.py``, ``test/test_sim_kernels.py``).

One module over 500 lines: it is the compiled path as one piece, read beside the reference
step by step; both updates work on the one layout of :class:`Grid` and :class:`Scratch` that
the entry points hand to the kernels, and no other module of the package calls a kernel.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from clis_base.ufunc_loops import LOOPS, exp_into
from clis_base.ufunc_loops import pairwise_sum as _pairwise_sum
from cr_sim.core.kernels import njit
import numpy as np

from clis_modules.core.localization_reference import EVIDENCE_MIN, EXP_LOG_LIK_MIN, LOG_LIK_MIN

__all__ = ['Grid', 'Scratch', 'predict_into', 'update_into']


@dataclass(frozen=True)
class Grid:
    """What the updates read of the grid (made once, never written).

    Attributes
    ----------
    shape : tuple of int
        ``(K, nx, ny)``: heading bins, x cells, y cells.
    cell, bin : float
        Cell side [m], heading bin [rad].
    kappa : float
        ``1 / sigma_bearing^2`` of the von Mises likelihood.
    floor : float
        Weight of the uniform belief mixed in per sensor update.
    cos_k, sin_k : np.ndarray, shape (K,)
        Of the heading-bin centres.
    cos_phi, sin_phi : np.ndarray, shape (Q, M, nx, ny)
        Of the direction of landmark m from sub-position q of each cell.
    cos_th, sin_th : np.ndarray, shape (K, T)
        Of sub-heading t of each heading bin; ``cos_tk``, ``sin_tk`` (T, K) transposed.
    free, uniform, floor_uniform : np.ndarray, shape (K, nx, ny)
        1 on the free cells; the uniform belief over them; ``floor`` times it.
    """

    shape: tuple[int, int, int]
    cell: float
    bin: float
    kappa: float
    floor: float
    cos_k: np.ndarray
    sin_k: np.ndarray
    cos_phi: np.ndarray
    sin_phi: np.ndarray
    cos_th: np.ndarray
    sin_th: np.ndarray
    cos_tk: np.ndarray
    sin_tk: np.ndarray
    free: np.ndarray
    uniform: np.ndarray
    floor_uniform: np.ndarray


@dataclass(frozen=True)
class Scratch:
    """The scratch arrays of :func:`predict_into` and :func:`update_into` (one call at a time
    per localizer: each scheduler of the project decides a module from one thread).

    Attributes
    ----------
    buf0, buf1 : np.ndarray, shape (K, nx, ny)
        The motion update's intermediate beliefs.
    padded : np.ndarray, shape (K, nx + 2 P, ny + 2 P)
        Zero but for its middle (``P = max(nx, ny) + 2``, above the largest shift).
    cc, ss : np.ndarray, shape (Q, nx, ny)
        ``C(p)``, ``S(p)`` per sub-position.
    bound : np.ndarray, shape (Q + 1, nx, ny)
        ``hypot(C, S)`` per sub-position, then their maximum.
    computed : np.ndarray, shape (nx, ny), bool
        The positions whose cell maxima were computed.
    cell_max : np.ndarray, shape (K, nx, ny)
        The best sub-pose log-likelihood of each cell.
    cells : np.ndarray, shape (N,), int64
        The cells with an unclipped sub-pose.
    vals, exps : np.ndarray, shape (N Q T,)
        Their sub-pose values (clipped at the floor), and the exps of those.
    lik : np.ndarray, shape (N,)
        Their likelihoods.
    """

    buf0: np.ndarray
    buf1: np.ndarray
    padded: np.ndarray
    cc: np.ndarray
    ss: np.ndarray
    bound: np.ndarray
    computed: np.ndarray
    cell_max: np.ndarray
    cells: np.ndarray
    vals: np.ndarray
    exps: np.ndarray
    lik: np.ndarray

    @classmethod
    def for_grid(cls, grid: Grid) -> Scratch:
        n_k, nx, ny = grid.shape
        n_q = grid.cos_phi.shape[0]
        size = n_k * nx * ny
        pad = max(nx, ny) + 2                     # the largest shift (clipped) plus one
        return cls(np.empty(grid.shape), np.empty(grid.shape),
                   np.zeros((n_k, nx + 2 * pad, ny + 2 * pad)), np.empty((n_q, nx, ny)),
                   np.empty((n_q, nx, ny)), np.empty((n_q + 1, nx, ny)),
                   np.empty((nx, ny), dtype=np.bool_), np.empty(grid.shape),
                   np.empty(size, dtype=np.int64), np.empty(size * n_q * grid.cos_th.shape[1]),
                   np.empty(size * n_q * grid.cos_th.shape[1]), np.empty(size))


def predict_into(grid: Grid, scratch: Scratch, p: np.ndarray, dx: float, dy: float,
                 dtheta: float, s_th: float, s_xy: float, out: np.ndarray) -> bool:
    """The motion update of ``p`` (K, nx, ny) into ``out``: shift by the odometry
    ``(dx, dy, dtheta)``, Gaussian blur of ``s_th`` bins and ``s_xy`` cells (0: that axis is
    not blurred), the free cells, normalised. False (``out`` unfinished) when nothing is left:
    the caller restarts from the uniform belief."""
    # = scipy.ndimage.gaussian_filter(p, (s_th, s_xy, s_xy), truncate=3.0,
    #                                 mode=('wrap', 'reflect', 'reflect')), unless both
    # are 0; weights as scipy.ndimage's _gaussian_kernel1d computes them (numpy's exp: one
    # call)
    n_th = n_xy = 0
    if s_xy > 0.0 or s_th > 0.0:
        n_th = 2 * int(3.0 * s_th + 0.5) + 1 if s_th > 1e-15 else 0
        n_xy = 2 * int(3.0 * s_xy + 0.5) + 1 if s_xy > 1e-15 else 0
    args = np.empty(n_th + n_xy)
    _weight_exponents(s_th, n_th, s_xy, n_xy, args)
    # steps 1-3, the free cells, the normalisation: one compiled call
    return _predict_kernel(p, grid.cos_k, grid.sin_k, dx, dy, dtheta, grid.cell, grid.bin,
                           np.exp(args), n_th, n_xy, grid.free, scratch.padded,
                           scratch.buf0, scratch.buf1, out)


def update_into(grid: Grid, scratch: Scratch, p: np.ndarray, z: np.ndarray,
                out: np.ndarray) -> bool:
    """The sensor update of ``p`` (K, nx, ny) on the landmark bearings ``z`` (M,) (a C array
    of float64; NaN = not seen) into ``out``. False (``out`` untouched) when no bearing is
    finite: the belief stays as it is."""
    s = scratch
    return _update_kernel(z, grid.kappa, grid.cos_phi, grid.sin_phi, grid.cos_tk, grid.sin_tk,
                          grid.cos_th, grid.sin_th, LOG_LIK_MIN, EXP_LOG_LIK_MIN, s.cc, s.ss,
                          s.bound, s.computed, s.cell_max, s.cells, s.vals, s.exps, LOOPS, p,
                          grid.uniform, grid.floor_uniform, grid.floor, EVIDENCE_MIN, s.lik,
                          out)


# ------------------------------------------------------------------ step kernels (motion)
@njit
def _extend(idx: int, n: int, wrap: bool) -> int:
    """Index in ``[0, n)`` of position ``idx`` of a line extended periodically (``wrap``) or
    mirrored (``reflect``: d c b a | a b c d | d c b a)."""
    if wrap:
        return idx % n
    idx %= 2 * n
    return 2 * n - 1 - idx if idx >= n else idx


@njit
def _add_pair(d: np.ndarray, a: np.ndarray, b: np.ndarray, w: float) -> None:
    """``d += (a + b) w`` element by element (arrays of one length). Indices from 0 up: a
    loop indexed ``f - lo`` may be negative for numba (an index wrapped from the end), and
    that check keeps the loop from being vectorized; the arithmetic is the same."""
    for i in range(d.shape[0]):
        d[i] += (a[i] + b[i]) * w


@njit
def _scaled(d: np.ndarray, a: np.ndarray, w: float) -> None:
    """``d = a w`` element by element."""
    for i in range(d.shape[0]):
        d[i] = a[i] * w


@njit
def _blur_passes(src: np.ndarray, dst: np.ndarray, w0: np.ndarray, w1: np.ndarray,
                 w2: np.ndarray) -> np.ndarray:
    """Separable Gaussian blur of ``src`` (K, nx, ny), C-contiguous (overwritten), ``dst``
    scratch of its shape: returns the one of the two that holds the result. Axis 0 periodic
    (``wrap``), axes 1 and 2 mirrored at the walls (``reflect``), one axis after the other,
    each with its symmetric weights ``w`` (2 r + 1,) (empty: the axis is skipped).

    ``scipy.ndimage.gaussian_filter``'s arithmetic (its correlate1d of a symmetric kernel:
    ``out = x[0] w[r] + sum_{j = -r .. -1} (x[j] + x[-j]) w[r + j]``, in that order), so the
    results are the same bit for bit.

    Each pass runs over long contiguous stretches of the flat arrays: every cell gets
    ``x[0] w[r]``, then ``(x[j] + x[-j]) w[r + j]`` added for ``j = -r .. -1`` in that order,
    its neighbours read directly where they are on the grid; the cells within ``r`` of a
    wall (mirrored neighbours) are then computed again from the start through
    :func:`_extend`."""
    n_k, nx, ny = src.shape
    plane = nx * ny
    if w0.size:
        # heading: periodic, whole (x, y) planes
        r = w0.size // 2
        s_flat, d_flat = src.reshape(-1), dst.reshape(-1)
        for k in range(n_k):
            d = d_flat[k * plane:(k + 1) * plane]
            _scaled(d, s_flat[k * plane:(k + 1) * plane], w0[r])
            for j in range(-r, 0):
                lo, hi = _extend(k + j, n_k, True), _extend(k - j, n_k, True)
                _add_pair(d, s_flat[lo * plane:(lo + 1) * plane],
                          s_flat[hi * plane:(hi + 1) * plane], w0[r + j])
        src, dst = dst, src
    if w1.size:
        # x: mirrored; the whole array as one line (neighbours f -+ r ny), then the rows
        # within r of a wall, whose neighbours on that line are in other planes, again
        r = w1.size // 2
        s_flat, d_flat = src.reshape(-1), dst.reshape(-1)
        n = s_flat.shape[0]
        _scaled(d_flat, s_flat, w1[r])
        for j in range(-r, 0):
            if n + 2 * j * ny > 0:
                _add_pair(d_flat[-j * ny:n + j * ny], s_flat[:n + 2 * j * ny],
                          s_flat[-2 * j * ny:], w1[r + j])
        for k in range(n_k):
            o = k * plane
            for i in range(nx):
                if r <= i < nx - r:
                    continue
                d = d_flat[o + i * ny:o + (i + 1) * ny]
                _scaled(d, s_flat[o + i * ny:o + (i + 1) * ny], w1[r])
                for j in range(-r, 0):
                    lo, hi = _extend(i + j, nx, False), _extend(i - j, nx, False)
                    _add_pair(d, s_flat[o + lo * ny:o + (lo + 1) * ny],
                              s_flat[o + hi * ny:o + (hi + 1) * ny], w1[r + j])
        src, dst = dst, src
    if w2.size:
        # y: mirrored; the whole array as one line (f - r .. f + r), then the columns near a
        # wall, whose neighbours on that line belong to other rows, again
        r = w2.size // 2
        s_flat, d_flat = src.reshape(-1), dst.reshape(-1)
        n = s_flat.shape[0]
        _scaled(d_flat, s_flat, w2[r])
        for j in range(-r, 0):
            if n + 2 * j > 0:
                _add_pair(d_flat[-j:n + j], s_flat[:n + 2 * j], s_flat[-2 * j:], w2[r + j])
        edge = np.empty(ny, dtype=np.int64)
        n_edge = 0
        for c in range(ny):
            if c < r or c >= ny - r:
                edge[n_edge] = c
                n_edge += 1
        e_lo = np.empty((r, n_edge), dtype=np.int64)
        e_hi = np.empty((r, n_edge), dtype=np.int64)
        for jj in range(r):                                # j = jj - r
            for e in range(n_edge):
                e_lo[jj, e] = _extend(edge[e] + jj - r, ny, False)
                e_hi[jj, e] = _extend(edge[e] - jj + r, ny, False)
        for row in range(0, n, ny):
            for e in range(n_edge):
                c = edge[e]
                acc = s_flat[row + c] * w2[r]
                for jj in range(r):
                    acc += (s_flat[row + e_lo[jj, e]] + s_flat[row + e_hi[jj, e]]) * w2[jj]
                d_flat[row + c] = acc
        src, dst = dst, src
    return src


@njit
def _shift_into(p: np.ndarray, cos_k: np.ndarray, sin_k: np.ndarray, dx: float, dy: float,
                dtheta: float, cell: float, bin_: float, padded: np.ndarray, q: np.ndarray,
                out: np.ndarray) -> None:
    """Steps 1-2 of the motion update into ``out``: layer k's shift ``R(theta_k) (dx, dy)``
    in cells (clipped to the grid's size plus one), split into whole cells ``i`` and a
    fraction ``f`` in [0, 1): mass at cell c moves to c + i + f,
    ``q[c] = (1 - f) p[c - i] + f p[c - i - 1]`` per axis (x first, then y; zero outside
    the grid), then the heading roll ``dtheta`` in bins ``it + ft``:
    ``out[k] = (1 - ft) q[k - it] + ft q[k - it - 1]`` (indices mod K; ``q[k - it]`` when
    ``ft = 0``). ``padded`` (K, nx + 2 P, ny + 2 P) is zero but for its middle, ``P`` above
    the largest shift (``max(nx, ny) + 2``): the shift reads a 0.0 for a cell off the grid;
    ``q`` scratch of ``p``'s shape."""
    n_k, nx, ny = p.shape
    ix = np.empty(n_k, dtype=np.int64)
    iy = np.empty(n_k, dtype=np.int64)
    fx = np.empty(n_k)
    fy = np.empty(n_k)
    for k in range(n_k):
        sx = min(max((cos_k[k] * dx - sin_k[k] * dy) / cell, -nx - 1.0), nx + 1.0)
        sy = min(max((sin_k[k] * dx + cos_k[k] * dy) / cell, -ny - 1.0), ny + 1.0)
        ax, ay = math.floor(sx), math.floor(sy)
        ix[k], fx[k] = int(ax), sx - ax
        iy[k], fy[k] = int(ay), sy - ay
    st = dtheta / bin_
    it = int(math.floor(st))
    ft = st - math.floor(st)
    pad = (padded.shape[1] - nx) // 2
    # (the loops index rows taken as slices from 0 up: an index such as o - 1 + c may be
    # negative for numba, whose check for it keeps a loop from being vectorized)
    for k in range(n_k):
        for i in range(nx):
            row = padded[k, pad + i, pad:pad + ny]
            src = p[k, i]
            for j in range(ny):
                row[j] = src[j]
    # a[c] = (1 - f_x) row0[c] + f_x row1[c] once per column c of the padded rows: the x shift
    # of column o + j is a0 of cell j and a1 of cell j + 1
    a = np.empty(ny + 1)
    for k in range(n_k):
        gx, gy, fxk, fyk = 1.0 - fx[k], 1.0 - fy[k], fx[k], fy[k]
        o = pad - iy[k]
        for i in range(nx):
            r0 = pad + i - ix[k]
            row0 = padded[k, r0, o - 1:o + ny]
            row1 = padded[k, r0 - 1, o - 1:o + ny]
            for c in range(ny + 1):
                a[c] = gx * row0[c] + fxk * row1[c]
            q_row = q[k, i]
            for j in range(ny):
                # a0 = a[j + 1] (column o + j), a1 = a[j] (column o + j - 1)
                q_row[j] = gy * a[j + 1] + fyk * a[j]
    plane = nx * ny
    q_flat, out_flat = q.reshape(-1), out.reshape(-1)
    if ft == 0.0:
        for k in range(n_k):
            out[k] = q[(k - it) % n_k]
    else:
        gt = 1.0 - ft
        for k in range(n_k):
            k0, k1 = (k - it) % n_k, (k - it - 1) % n_k
            dst = out_flat[k * plane:(k + 1) * plane]
            q0 = q_flat[k0 * plane:(k0 + 1) * plane]
            q1 = q_flat[k1 * plane:(k1 + 1) * plane]
            for f in range(plane):
                dst[f] = gt * q0[f] + ft * q1[f]


# ------------------------------------------------------------------ fused kernels (predict,
# update): the operations of the step kernels (those above, test/localization_kernels.py's)
# and of the numpy glue that composes them, in the same order, without the intermediate
# arrays (tested against that composition, bit for bit)

@njit
def _weight_exponents(s_th: float, n_th: int, s_xy: float, n_xy: int, out: np.ndarray) -> None:
    """The exponents ``-0.5 / sigma^2 x^2`` of scipy.ndimage's Gaussian kernel for
    ``x = -r .. r`` (``n = 2 r + 1`` of them; none for ``n = 0``): heading then position,
    into ``out[:n_th + n_xy]``."""
    for n, s, off in ((n_th, s_th, 0), (n_xy, s_xy, n_th)):
        if n:
            r = n // 2
            c = -0.5 / (s * s)
            for e in range(n):
                x = e - r
                out[off + e] = c * float(x * x)


@njit
def _normalised_weights(e: np.ndarray, lo: int, n: int) -> np.ndarray:
    """``phi / phi.sum()`` of ``phi = e[lo:lo + n]`` (scipy.ndimage's Gaussian kernel)."""
    w = np.empty(n)
    total = _pairwise_sum(e, lo, n)
    for i in range(n):
        w[i] = e[lo + i] / total
    return w


@njit
def _predict_kernel(p: np.ndarray, cos_k: np.ndarray, sin_k: np.ndarray, dx: float,
                    dy: float, dtheta: float, cell: float, bin_: float, e: np.ndarray,
                    n_th: int, n_xy: int, free: np.ndarray, padded: np.ndarray,
                    buf0: np.ndarray, buf1: np.ndarray, out: np.ndarray) -> bool:
    """The motion update of :meth:`MarkovLocalizer.predict` into ``out`` (K, nx, ny): the
    shift and roll (:func:`_shift_into`), the blur (:func:`_blur_passes`) with the weights
    normalised from their exps ``e`` (heading ``e[:n_th]``, position ``e[n_th:]``; 0: no
    blur of that axis), the free cells, then ``p / sum(p)``; ``buf0``,
    ``buf1`` scratch of ``p``'s shape, ``padded`` (K, nx + 2 P, ny + 2 P) zero but for its
    middle, ``P`` above the largest shift (``max(nx, ny) + 2``). Returns False (``out``
    unfinished) when the sum is not positive and finite."""
    # steps 1-2 (_shift_into) into buf1, step 3 (_blur_passes) from there
    _shift_into(p, cos_k, sin_k, dx, dy, dtheta, cell, bin_, padded, buf0, buf1)
    w_xy = _normalised_weights(e, n_th, n_xy)
    src = _blur_passes(buf1, buf0, _normalised_weights(e, 0, n_th), w_xy, w_xy)
    # p *= free; b(x') <- sum_x Pr(x' | x, u) b(x) normalised (paper III-D)
    flat_src = src.reshape(-1)
    flat_free = free.reshape(-1)
    flat = out.reshape(-1)
    n = flat.shape[0]
    for i in range(n):
        flat[i] = flat_src[i] * flat_free[i]
    total = _pairwise_sum(flat, 0, n)
    if not (total > 0.0 and math.isfinite(total)):
        return False
    for i in range(n):
        flat[i] /= total
    return True


@njit
def _cell_maxima(z: np.ndarray, kappa: float, cos_phi: np.ndarray, sin_phi: np.ndarray,
                 cos_tk: np.ndarray, sin_tk: np.ndarray, low: float, cc: np.ndarray,
                 ss: np.ndarray, bound: np.ndarray, computed: np.ndarray,
                 cell_max: np.ndarray) -> float:
    """The best sub-pose log-likelihood of the cells that may be within ``-low`` of the best
    one (the reference's ``log_likelihood``, then each cell's maximum over its sub-poses,
    without the array of every sub-pose).

    Writes ``C = kappa sum_m cos(s_m - phi_m)``, ``S`` likewise with sin, per sub-position
    (``cc``, ``ss`` (Q, nx, ny)), and ``cell_max[k, i, j]`` = the largest
    ``C cos theta - S sin theta`` over the sub-poses of cell (k, i, j), for the positions
    (i, j) marked in ``computed``: those whose bound ``max_q hypot(C, S)`` (a sub-pose value
    ``hypot(C, S) cos(theta + atan2(S, C))`` is at most that; ``bound`` (Q + 1, nx, ny):
    per sub-position, then their maximum) does not rule every cell out; the others are
    below the best by more than ``-low`` (clipped), whatever their heading. Within a
    position, the sub-positions whose bound rules them out are skipped: that changes no
    maximum above the clipping level (exact), only maxima of cells that are clipped anyway.
    ``cos_tk``, ``sin_tk`` (T, K): of the sub-headings, transposed.

    Returns
    -------
    float
        The best value over every sub-pose (exact: the position holding it is computed), or
        NaN when no bearing in ``z`` (M,) is finite (nothing seen).
    """
    n_q, n_m, nx, ny = cos_phi.shape
    n_t, n_k = cos_tk.shape
    cc[:] = 0.0
    ss[:] = 0.0
    any_seen = False
    for m in range(n_m):
        if not math.isfinite(z[m]):
            continue
        any_seen = True
        cz, sz = math.cos(z[m]), math.sin(z[m])       # numpy's cos, sin: the same bits
        for q in range(n_q):
            for i in range(nx):
                for j in range(ny):
                    cp, sp = cos_phi[q, m, i, j], sin_phi[q, m, i, j]
                    cc[q, i, j] += cz * cp + sz * sp
                    ss[q, i, j] += sz * cp - cz * sp
    if not any_seen:
        return np.nan
    cc *= kappa
    ss *= kappa
    # the bounds sub-position by sub-position over contiguous planes, then their maximum
    plane = nx * ny
    cc_f, ss_f, bound_f = cc.reshape(-1), ss.reshape(-1), bound.reshape(-1)
    top = bound_f[n_q * plane:]
    top[:] = 0.0
    for q in range(n_q):
        c_q = cc_f[q * plane:(q + 1) * plane]
        s_q = ss_f[q * plane:(q + 1) * plane]
        b_q = bound_f[q * plane:(q + 1) * plane]
        for f in range(plane):
            # a margin far above the rounding of C cos - S sin (~1e-13 here)
            r = math.sqrt(c_q[f] ** 2 + s_q[f] ** 2) * (1.0 + 1e-9) + 1e-9
            b_q[f] = r
            top[f] = max(top[f], r)
    first = 0
    for f in range(1, plane):
        if top[f] > top[first]:
            first = f
    first_i, first_j = first // ny, first % ny
    computed[:] = False
    v = np.empty(n_k)
    # the most promising position first, then the others in order
    best = _position_maxima(first_i, first_j, -np.inf, low, cc, ss, cos_tk, sin_tk, bound,
                            computed, cell_max, v)
    for i in range(nx):
        for j in range(ny):
            if computed[i, j] or bound[n_q, i, j] < best + low - 1e-6:
                continue
            best = _position_maxima(i, j, best, low, cc, ss, cos_tk, sin_tk, bound, computed,
                                    cell_max, v)
    return best


@njit
def _position_maxima(i: int, j: int, best: float, low: float, cc: np.ndarray, ss: np.ndarray,
                     cos_tk: np.ndarray, sin_tk: np.ndarray, bound: np.ndarray,
                     computed: np.ndarray, cell_max: np.ndarray, v: np.ndarray) -> float:
    """:func:`_cell_maxima` at position (i, j): ``cell_max[:, i, j]``, marked ``computed``;
    returns ``best`` updated (``v`` (K,) scratch)."""
    n_q = cc.shape[0]
    n_t, n_k = cos_tk.shape
    computed[i, j] = True
    v[:] = -np.inf
    for q in range(n_q):
        if bound[q, i, j] < best + low - 1e-6:
            # this sub-position is clipped at every heading: whether a cell is clipped,
            # and the maximum of one that is not, come from the other sub-positions
            continue
        c, s = cc[q, i, j], ss[q, i, j]
        for t in range(n_t):
            for k in range(n_k):
                # kappa cos(A + theta) = C cos theta - S sin theta (log_likelihood)
                v[k] = max(v[k], c * cos_tk[t, k] - s * sin_tk[t, k])
    for k in range(n_k):
        cell_max[k, i, j] = v[k]
        best = max(best, v[k])
    return best


@njit
def _unclipped_sub_poses(cc: np.ndarray, ss: np.ndarray, cos_th: np.ndarray,
                         sin_th: np.ndarray, computed: np.ndarray, cell_max: np.ndarray,
                         best: float, low: float, cells: np.ndarray, vals: np.ndarray) -> int:
    """The unclipped sub-poses, from :func:`_cell_maxima`'s results: the flat indices of the
    cells (C order of (K, nx, ny)) with a sub-pose value ``v = a - best > low`` into ``cells``,
    and every sub-pose value ``v = max(a - best, low)`` of each of those cells into ``vals``,
    cell by cell (``n_sub = Q T`` each), sub-poses in order (q, then t), as the reference's
    ``rows - rows.max()`` clipped at ``low`` (``a``: :func:`_cell_maxima`'s
    ``C cos theta - S sin theta``).

    The cells are listed position by position (the computed ones), heading by heading within
    a position: each cell's likelihood is its own sum, so their order changes no value.

    Returns
    -------
    int
        How many cells.
    """
    n_q, nx, ny = cc.shape
    n_k, n_t = cos_th.shape
    n_sub = n_q * n_t
    n_cells = 0
    for i in range(nx):
        for j in range(ny):
            if not computed[i, j]:
                continue
            for k in range(n_k):
                if not max(cell_max[k, i, j] - best, low) > low:
                    continue
                cells[n_cells] = (k * nx + i) * ny + j
                m = n_cells * n_sub
                n_cells += 1
                for q in range(n_q):
                    c, s = cc[q, i, j], ss[q, i, j]
                    for t in range(n_t):
                        vals[m] = max(c * cos_th[k, t] - s * sin_th[k, t] - best, low)
                        m += 1
    return n_cells


@njit
def _posterior(n_sub: int, cells: np.ndarray, low: float, exp_low: float, vals: np.ndarray,
               exps: np.ndarray, prior: np.ndarray, uniform: np.ndarray,
               floor_uniform: np.ndarray, floor: float, evidence_min: float, lik: np.ndarray,
               out: np.ndarray) -> None:
    """The rest of :meth:`MarkovLocalizer.update` into ``out`` (K, nx, ny): the likelihood of
    every cell (of the ``cells``, the sum of their ``n_sub`` sub-pose terms in order, as the
    reference's ``e.sum(axis=0)``: ``exps`` (the exps of ``vals``) where ``vals > low`` and
    ``exp_low`` where clipped;
    ``lik`` (N,) scratch), ``p = lik prior``, restarted from ``lik uniform`` when its sum is
    not above ``evidence_min`` (or not finite), scaled by ``(1 - floor) / sum``, plus
    ``floor_uniform`` when ``floor > 0``."""
    const = exp_low                         # a cell with every sub-pose clipped
    for _ in range(1, n_sub):
        const += exp_low
    # lik of the cells with an unclipped sub-pose (the others: const), then lik prior
    for c_i in range(cells.shape[0]):
        m = c_i * n_sub
        acc = exps[m] if vals[m] > low else exp_low
        for s in range(1, n_sub):
            acc += exps[m + s] if vals[m + s] > low else exp_low
        lik[c_i] = acc
    flat = out.reshape(-1)
    n = flat.shape[0]
    for attempt in range(2):
        weights = prior.reshape(-1) if attempt == 0 else uniform.reshape(-1)
        # b(x) <- eta Pr(s | x) b(x) (paper III-D)
        for i in range(n):
            flat[i] = const * weights[i]
        for c_i in range(cells.shape[0]):
            flat[cells[c_i]] = lik[c_i] * weights[cells[c_i]]
        total = _pairwise_sum(flat, 0, n)
        if total > evidence_min and math.isfinite(total):
            break
        # else: the prior ruled out the reading: restart from it (lik uniform)
    scale = (1.0 - floor) / total
    if floor > 0.0:
        flat_floor = floor_uniform.reshape(-1)
        for i in range(n):
            flat[i] = flat[i] * scale + flat_floor[i]
    else:
        for i in range(n):
            flat[i] *= scale


@njit
def _update_kernel(z: np.ndarray, kappa: float, cos_phi: np.ndarray, sin_phi: np.ndarray,
                   cos_tk: np.ndarray, sin_tk: np.ndarray, cos_th: np.ndarray,
                   sin_th: np.ndarray, low: float, exp_low: float, cc: np.ndarray,
                   ss: np.ndarray, bound: np.ndarray, computed: np.ndarray,
                   cell_max: np.ndarray, cells: np.ndarray, vals: np.ndarray,
                   exps: np.ndarray, loops: np.ndarray, prior: np.ndarray,
                   uniform: np.ndarray, floor_uniform: np.ndarray, floor: float,
                   evidence_min: float, lik: np.ndarray, out: np.ndarray) -> bool:
    """The sensor update of :meth:`MarkovLocalizer.update` into ``out``: :func:`_cell_maxima`,
    :func:`_unclipped_sub_poses`, the exps of their values by numpy's own loop
    (:func:`clis_base.ufunc_loops.exp_into`; ``loops`` its ``LOOPS``), :func:`_posterior`;
    the other arrays are their scratch. Returns False (``out`` untouched) when no bearing
    is finite (nothing seen)."""
    best = _cell_maxima(z, kappa, cos_phi, sin_phi, cos_tk, sin_tk, low, cc, ss, bound,
                        computed, cell_max)
    if math.isnan(best):
        return False
    n_cells = _unclipped_sub_poses(cc, ss, cos_th, sin_th, computed, cell_max, best, low,
                                   cells, vals)
    n_sub = cc.shape[0] * cos_th.shape[1]
    exp_into(loops, vals, exps, n_cells * n_sub)
    _posterior(n_sub, cells[:n_cells], low, exp_low, vals, exps, prior, uniform,
               floor_uniform, floor, evidence_min, lik, out)
    return True
