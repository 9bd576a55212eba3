"""Grid Markov localization on landmark bearings: the state of the place module (paper III-D).

The belief ``b_pl`` is a probability over a grid of poses ``(x, y, theta)``: square cells of
side ``cell_size`` over the floor (a square, or any rectangle), times ``n_headings`` heading
bins.
Paper: 15 cm and 30 deg over 3 m x 3 m, "450 states"; that grid has 20 x 20 x 12 = 4800 cells
(450 matches neither 20 x 20 = 400 nor any whole number of 30 deg bins), so we keep the stated
resolutions and get 4800 cells; both resolutions are parameters.

Array layout: ``belief_grid[k, i, j]`` is the probability of heading bin ``k`` (centre
``theta_k = k 2 pi / n_headings``), x cell ``i`` and y cell ``j`` (centres ``xs[i]``,
``ys[j]``); the flat belief (the place module's feature vector) is its C-order ravel.

Initial belief: uniform over the free cells (paper: the robot does not know its start).
Cells whose centre lies inside an obstacle box (optional) always hold 0.

Motion update (paper: ``b(x') <- sum_x Pr(x' | x, u) b(x)``), from odometry ``(dx, dy, dtheta)``
expressed in the robot frame at the start of the interval:

1. every heading layer ``k`` is shifted by the displacement rotated into the world,
   ``R(theta_k) (dx, dy)``, with bilinear weights (mass conserving; mass leaving the floor is
   dropped: those poses contradict the odometry);
2. the heading axis is rolled by ``dtheta`` (periodic, linear weights between bins);
3. Gaussian noise: a blur of standard deviation ``trans_noise * |d| + trans_noise_min`` in x and
   y (reflecting at the walls) and ``rot_noise * |dtheta| + rot_noise_min`` in heading
   (periodic) -- :func:`scipy.ndimage.gaussian_filter`'s arithmetic, compiled (:func:`_blur`,
   bit-identical: tested). The ``*_min`` terms also stand for the
   spread of the true pose inside a cell; they are added per call, so call ``predict`` once per
   place-module period (not once per simulator tick).

Sensor update (paper: ``b(x) <- eta Pr(s | x) b(x)``): the bearings ``s`` of the landmarks that
are seen, each with a von Mises likelihood around the bearing expected from the cell centre,
``Pr(s | x) = prod_m exp(kappa cos(s_m - mu_m(x)))`` with ``kappa = 1 / sigma_bearing^2`` (the
von Mises approximation of a wrapped Gaussian of std ``sigma_bearing``). The true pose is
anywhere inside its cell, so a cell's likelihood is the mean over ``sub_cells^2 x sub_headings``
sub-poses spread inside it (with only the cell centre, the 30 deg bins force a wide
``sigma_bearing`` and the position becomes ambiguous along ridges near the corners: measured,
65 % of MAP cells within 1 cell of the truth against 94 % with 2 x 2 x 3 sub-poses). The
bearing expected at a sub-pose ``(p, theta)`` is ``mu_m = phi_m(p) - theta``, ``phi_m(p)`` the
direction of landmark m from position p, so with ``A_m = s_m - phi_m(p)``::

    sum_m kappa cos(s_m - mu_m) = kappa (C(p) cos theta - S(p) sin theta),
    C(p) = sum_m cos A_m,  S(p) = sum_m sin A_m     (sums over the seen landmarks)

``cos phi_m`` and ``sin phi_m`` of every sub-position are precomputed; an update forms C and S
per sub-position (2 x 2 M products) and the log-likelihood of every sub-pose from them
(:func:`_log_likelihood`), relative to the best, clipped 50 below it, then exp. A landmark
that is not seen (NaN) adds no information (occlusion is not modelled).

Computation: each update is one compiled call (:func:`_update_into`), each motion update too
(:func:`_predict_into`); they do the operations of the reference kernels above them
(:func:`_shift_pose`, :func:`_blur`, :func:`_log_likelihood`, :func:`_row_max`,
:func:`_unclipped`, :func:`_sub_pose_sums`) and of numpy's sums (:func:`_pairwise_sum`) in the
same order, without their intermediate arrays, and skip only sub-poses that are clipped
anyway (bounded by ``hypot(C, S)``); ``exp`` is numpy's own loop
(:mod:`cr_sim.core.ufunc_loops`): bit-identical beliefs (tested). The result is normalised,
then ``floor`` of a uniform belief is mixed in so that no pose is ever ruled out for good; a
belief that contradicts the reading (evidence below 1e-15 of the best cell's likelihood: the
kidnapped robot, or ``floor = 0``) restarts from the reading alone.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from cr_sim.core.kernels import njit
from cr_sim.core.params import dataclass, param
from cr_sim.core.robot import integrate_arc, wheels_to_twist
from cr_sim.core.ufunc_loops import LOOPS, exp_into
from cr_sim.core.ufunc_loops import pairwise_sum as _pairwise_sum
import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from clis_modules.core.plugin import Floor

__all__ = ['LocalizationParams', 'MarkovLocalizer']

#: Log-likelihoods below the best by more than this are clipped (e^-50 ~ 2e-22: nothing).
_LOG_LIK_MIN = -50.0
#: ``exp(_LOG_LIK_MIN)`` as numpy's exp computes it.
_EXP_LOG_LIK_MIN = float(np.exp(np.array([_LOG_LIK_MIN]))[0])
#: Evidence ``sum_x Pr(s | x) b(x)`` (the best cell's likelihood scaled to 1) below which the
#: belief is taken to contradict the reading, and the update restarts from the reading alone.
_EVIDENCE_MIN = 1e-15


@dataclass(frozen=True)
class LocalizationParams:
    """Grid Markov localization (``clis.yaml`` section ``place.localization``)."""

    cell_size: float = param(0.01, 1.5, doc='side of a square grid cell [m] (paper: 0.15)')
    n_headings: int = param(1, 360, doc='number of heading bins (paper: 30 deg -> 12)')
    bearing_sigma_deg: float = param(
        0.1, 180.0, doc='std of the landmark-bearing likelihood [deg]')
    trans_noise: float = param(0.0, 10.0, doc='position noise std per metre travelled [m/m]')
    trans_noise_min: float = param(0.0, 1.0, doc='position noise std added per predict [m]')
    rot_noise: float = param(0.0, 10.0, doc='heading noise std per radian turned [rad/rad]')
    rot_noise_min_deg: float = param(
        0.0, 180.0, doc='heading noise std added per predict [deg]')
    floor: float = param(0.0, 0.5, doc='weight of a uniform belief mixed in per sensor update')
    sub_cells: int = param(1, 8, doc='sub-positions per cell side for the sensor likelihood')
    sub_headings: int = param(1, 16, doc='sub-headings per heading bin for the likelihood')


class MarkovLocalizer:
    """Belief over the pose grid with motion and sensor updates (module docstring).

    Parameters
    ----------
    params : LocalizationParams
    landmarks_xy : array_like, shape (M, 2)
        Landmark positions [m], in the order of the bearings given to :meth:`update`.
    floor : Floor
        The floor [m] (:class:`clis_modules.core.plugin.Floor`).
    boxes : array_like, shape (K, 4), optional
        Obstacles as ``(xmin, ymin, xmax, ymax)`` [m]: cells whose centre is inside are never
        occupied.

    Attributes
    ----------
    shape : tuple of int
        ``(n_headings, nx, ny)``.
    xs, ys : np.ndarray, shape (nx,), (ny,)
        Cell centres [m] (``nx = round(width / cell_size)``; the actual cell side is
        ``cell = width / nx``; ``ny = round(height / cell)`` cells of that side, centred on
        the floor).
    origin : tuple of float
        South-west corner of the grid [m].
    thetas : np.ndarray, shape (n_headings,)
        Heading-bin centres [rad], ``k 2 pi / n_headings``.
    """

    def __init__(self, params: LocalizationParams, landmarks_xy: ArrayLike, floor: Floor,
                 boxes: ArrayLike | None = None) -> None:
        self.params = params
        self.landmarks_xy = np.asarray(landmarks_xy, dtype=np.float64).reshape(-1, 2)
        self.half_size = floor.half             # None: not a square centred at the origin
        x0, y0, x1, y1 = (float(v) for v in (floor.xmin, floor.ymin, floor.xmax, floor.ymax))
        n = max(1, int(round((x1 - x0) / params.cell_size)))
        self.cell = (x1 - x0) / n
        ny = max(1, int(round((y1 - y0) / self.cell)))
        off = 0.5 * ((y1 - y0) - ny * self.cell)
        if abs(off) < 1e-9:
            off = 0.0
        self.origin = (x0, y0 + off)
        self.xs = x0 + self.cell * (np.arange(n) + 0.5)
        self.ys = self.xs.copy() if (y0, ny) == (x0, n) else \
            self.origin[1] + self.cell * (np.arange(ny) + 0.5)
        self.n_headings = params.n_headings
        self.bin = 2.0 * math.pi / self.n_headings
        self.thetas = self.bin * np.arange(self.n_headings)
        self.shape = (self.n_headings, n, ny)
        self.size = int(np.prod(self.shape))
        self.kappa = 1.0 / math.radians(params.bearing_sigma_deg) ** 2

        gx, gy = np.meshgrid(self.xs, self.ys, indexing='ij')           # (nx, ny)
        free = np.ones((n, ny), dtype=bool)
        if boxes is not None:
            for x0, y0, x1, y1 in np.asarray(boxes, dtype=np.float64).reshape(-1, 4):
                free &= ~((gx >= x0) & (gx <= x1) & (gy >= y0) & (gy <= y1))
        if not free.any():
            raise ValueError('every grid cell lies inside an obstacle')
        self._free = np.broadcast_to(free, self.shape).astype(np.float64)
        self._uniform = self._free / self._free.sum()
        self._floor_uniform = params.floor * self._uniform
        # C order for the kernels (the same values; broadcast_to(...).astype keeps strides
        # with the heading fastest)
        self._free, self._uniform, self._floor_uniform = (
            np.ascontiguousarray(a) for a in (self._free, self._uniform, self._floor_uniform))

        # phi_m(p) = atan2(l_y - y, l_x - x): direction of landmark m from each sub-position p
        # (sub_cells^2 points inside each cell), and the sub-headings theta (sub_headings
        # inside each bin); the expected bearing is mu_m = phi_m(p) - theta
        m = len(self.landmarks_xy)
        off_xy = self.cell * ((np.arange(params.sub_cells) + 0.5) / params.sub_cells - 0.5)
        off_th = self.bin * ((np.arange(params.sub_headings) + 0.5) / params.sub_headings - 0.5)
        phi = np.array([[np.arctan2(self.landmarks_xy[:, 1, None, None] - (gy[None] + oy),
                                    self.landmarks_xy[:, 0, None, None] - (gx[None] + ox))
                         for oy in off_xy] for ox in off_xy])           # (sx, sy, M, nx, ny)
        phi = phi.reshape(-1, m, n, ny)                                  # (Q, M, nx, ny)
        self._cos_phi = np.ascontiguousarray(np.cos(phi))
        self._sin_phi = np.ascontiguousarray(np.sin(phi))
        th_sub = self.thetas[:, None] + off_th[None, :]                 # (K, T)
        self._cos_th = np.ascontiguousarray(np.cos(th_sub))
        self._sin_th = np.ascontiguousarray(np.sin(th_sub))
        self._cos_tk = np.ascontiguousarray(self._cos_th.T)
        self._sin_tk = np.ascontiguousarray(self._sin_th.T)
        self._n_sub = phi.shape[0] * len(off_th)
        self._cos_k, self._sin_k = np.cos(self.thetas), np.sin(self.thetas)
        self._p = self._uniform.copy()
        # scratch of predict and update (one call at a time per localizer: each scheduler of
        # the project decides a module from one thread)
        self._buf = (np.empty(self.shape), np.empty(self.shape))
        self._wargs = np.empty(16)                    # blur weights' exponents
        self._cc = np.empty((phi.shape[0], n, ny))    # C(p), S(p) per sub-position
        self._ss = np.empty((phi.shape[0], n, ny))
        self._bound = np.empty((phi.shape[0] + 1, n, ny))
        self._computed = np.empty((n, ny), dtype=np.bool_)
        self._cell_max = np.empty(self.shape)
        self._cells = np.empty(self.size, dtype=np.int64)
        self._vals = np.empty(self.size * self._n_sub)
        self._lik = np.empty(self.size)
        pad = max(n, ny) + 2                          # the largest shift (clipped) plus one
        self._padded = np.zeros((self.n_headings, n + 2 * pad, ny + 2 * pad))

    # ------------------------------------------------------------------ state

    def reset(self) -> None:
        """Uniform belief over the free cells (the start pose is unknown, paper III-D)."""
        self._p = self._uniform.copy()

    @property
    def belief_grid(self) -> np.ndarray:
        """The belief, shape ``(n_headings, nx, ny)`` (read-only view)."""
        v = self._p.view()
        v.flags.writeable = False
        return v

    @property
    def belief(self) -> np.ndarray:
        """The flat belief, shape (N,), the place module's features (read-only view)."""
        return self.belief_grid.reshape(-1)

    def set_belief(self, p: ArrayLike) -> None:
        """Replace the belief (shape (N,) or :attr:`shape`; normalised here)."""
        p = np.asarray(p, dtype=np.float64).reshape(self.shape) * self._free
        self._p = self._normalised(p)

    def map_pose(self) -> tuple[float, float, float]:
        """Centre ``(x, y, theta)`` of the most probable cell [m, m, rad]."""
        k, i, j = np.unravel_index(int(np.argmax(self._p)), self.shape)
        return float(self.xs[i]), float(self.ys[j]), float(self.thetas[k])

    def cell_of(self, x: float, y: float, theta: float) -> tuple[int, int, int]:
        """Grid index ``(k, i, j)`` of a pose (clipped to the grid)."""
        _, n, ny = self.shape
        i = min(max(int(math.floor((x - self.origin[0]) / self.cell)), 0), n - 1)
        j = min(max(int(math.floor((y - self.origin[1]) / self.cell)), 0), ny - 1)
        k = int(round(theta / self.bin)) % self.n_headings
        return k, i, j

    # ------------------------------------------------------------------ motion update

    def predict(self, dx: float, dy: float, dtheta: float) -> None:
        """Motion update ``b(x') <- sum_x Pr(x' | x, u) b(x)`` (paper III-D).

        Parameters
        ----------
        dx, dy : float
            Displacement [m] over the interval, in the robot frame at its start (x forward,
            y to the left).
        dtheta : float
            Heading change [rad], counter-clockwise positive.
        """
        prm = self.params
        s_xy = (prm.trans_noise * math.hypot(dx, dy) + prm.trans_noise_min) / self.cell
        s_th = (prm.rot_noise * abs(dtheta) + math.radians(prm.rot_noise_min_deg)) / self.bin
        # = scipy.ndimage.gaussian_filter(p, (s_th, s_xy, s_xy), truncate=3.0,
        #                                 mode=('wrap', 'reflect', 'reflect')), unless both
        # are 0; weights as _gaussian_weights computes them (numpy's exp: one call)
        n_th = n_xy = 0
        if s_xy > 0.0 or s_th > 0.0:
            n_th = 2 * int(3.0 * s_th + 0.5) + 1 if s_th > 1e-15 else 0
            n_xy = 2 * int(3.0 * s_xy + 0.5) + 1 if s_xy > 1e-15 else 0
            if n_th + n_xy > self._wargs.shape[0]:
                self._wargs = np.empty(n_th + n_xy)
        args = self._wargs
        _weight_exponents(s_th, n_th, s_xy, n_xy, args)
        p = np.empty(self.shape)
        # steps 1-3, the free cells, the normalisation: one compiled call
        if _predict_into(self._p, self._cos_k, self._sin_k, dx, dy, dtheta, self.cell,
                         self.bin, np.exp(args[:n_th + n_xy]), n_th, n_xy, self._free,
                         self._padded, self._buf[0], self._buf[1], p):
            self._p = p
        else:
            self._p = self._uniform.copy()

    def peek(self, odometry: tuple[float, float, float] | None,
             landmark_bearings: ArrayLike) -> np.ndarray:
        """The belief that :meth:`predict` (``odometry = (dx, dy, dtheta)``, skipped if None)
        then :meth:`update` would give, as a new flat array (N,); the belief itself is left
        as it is (the motion and sensor updates replace it by a new array, never write it)."""
        saved = self._p
        try:
            if odometry is not None:
                self.predict(*odometry)
            self.update(landmark_bearings)
            return self._p.reshape(-1).copy()
        finally:
            self._p = saved

    def predict_wheels(self, wheels: ArrayLike, dt: float, wheel_base: float) -> None:
        """Motion update from the executed wheel velocities of consecutive simulator steps.

        Composes the exact arcs (:func:`cr_sim.core.robot.integrate_arc`) of every step into
        one ``(dx, dy, dtheta)`` in the frame of the first step, then calls :meth:`predict`.

        Parameters
        ----------
        wheels : array_like, shape (K, 2)
            Executed ``(v_left, v_right)`` of each step [m/s], oldest first.
        dt : float
            Step duration [s].
        wheel_base : float
            Distance between the wheels [m].
        """
        x = y = th = 0.0
        for v_left, v_right in np.asarray(wheels, dtype=np.float64).reshape(-1, 2):
            v, omega = wheels_to_twist(v_left, v_right, wheel_base)
            x, y, th = integrate_arc(x, y, th, v, omega, dt)
        self.predict(x, y, th)

    def _shift(self, p: np.ndarray, dx: float, dy: float, dtheta: float) -> np.ndarray:
        """Steps 1-2 of the motion update: every heading layer k shifted by
        ``R(theta_k) (dx, dy)`` (bilinear, zero fill), then the heading axis rolled by
        ``dtheta`` (periodic, linear weights between bins) (:func:`_shift_kernel`)."""
        return _shift_pose(p, self._cos_k, self._sin_k, dx, dy, dtheta, self.cell, self.bin)

    # ------------------------------------------------------------------ sensor update

    def update(self, landmark_bearings: ArrayLike) -> None:
        """Sensor update ``b(x) <- eta Pr(s | x) b(x)`` (paper III-D) on landmark bearings.

        Parameters
        ----------
        landmark_bearings : array_like, shape (M,)
            Bearing of each landmark relative to the heading [rad]; NaN = not seen (no
            information). Nothing seen: the belief is left unchanged.
        """
        # a fresh writable C array whatever the caller passes (a simulator observation is
        # read-only): one compiled signature of _update_into for every caller
        z = np.array(landmark_bearings, dtype=np.float64).reshape(-1)
        if z.shape[0] != len(self.landmarks_xy):
            raise ValueError(f'expected {len(self.landmarks_xy)} landmark bearings, '
                             f'got {z.shape[0]}')
        # ln Pr(s | x') = sum_m kappa cos(s_m - mu_m(x')) + const  (von Mises per landmark),
        # at every sub-pose x' of every cell, relative to the best one, clipped at
        # _LOG_LIK_MIN (no denormals), then Pr(s | cell) and b(x) <- eta Pr(s | x) b(x) with
        # the floor: one compiled call (_update_into); nothing seen: no change
        p = np.empty(self.shape)
        if _update_into(z, self.kappa, self._cos_phi, self._sin_phi, self._cos_tk, self._sin_tk,
                        self._cos_th, self._sin_th, _LOG_LIK_MIN, _EXP_LOG_LIK_MIN, self._cc,
                        self._ss, self._bound, self._computed, self._cell_max, self._cells,
                        self._vals, LOOPS, self._p, self._uniform, self._floor_uniform,
                        self.params.floor, _EVIDENCE_MIN, self._lik, p):
            self._p = p

    def _normalised(self, p: np.ndarray) -> np.ndarray:
        """``p / sum(p)``, in place (``p`` is a new array of the caller's)."""
        total = p.sum()
        if not (total > 0.0 and math.isfinite(total)):
            return self._uniform.copy()
        p /= total
        return p


# ------------------------------------------------------------------ compiled kernels

def _gaussian_weights(sigma: float, truncate: float) -> np.ndarray:
    """Normalised Gaussian weights of std ``sigma`` [cells] over ``+-int(truncate sigma + 1/2)``
    (``scipy.ndimage``'s kernel, its arithmetic), shape (2 r + 1,); empty when ``sigma`` is
    (nearly) 0: that axis is not blurred."""
    if not sigma > 1e-15:
        return np.zeros(0)
    radius = int(truncate * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (sigma * sigma) * x ** 2)
    return phi / phi.sum()


@njit
def _extend(idx: int, n: int, wrap: bool) -> int:
    """Index in ``[0, n)`` of position ``idx`` of a line extended periodically (``wrap``) or
    mirrored (``reflect``: d c b a | a b c d | d c b a)."""
    if wrap:
        return idx % n
    idx %= 2 * n
    return 2 * n - 1 - idx if idx >= n else idx


@njit
def _blur(p: np.ndarray, w0: np.ndarray, w1: np.ndarray, w2: np.ndarray) -> np.ndarray:
    """Separable Gaussian blur of ``p`` (K, nx, ny), C-contiguous: axis 0 periodic (``wrap``),
    axes 1 and 2 mirrored at the walls (``reflect``), one axis after the other, each with its
    symmetric weights ``w`` (2 r + 1,) (empty: the axis is skipped). A new array
    (:func:`_blur_passes`).

    ``scipy.ndimage.gaussian_filter``'s arithmetic (its correlate1d of a symmetric kernel:
    ``out = x[0] w[r] + sum_{j = -r .. -1} (x[j] + x[-j]) w[r + j]``, in that order), so the
    results are the same bit for bit; the loops run over whole contiguous rows.
    """
    return _blur_passes(p.copy(), np.empty_like(p), w0, w1, w2)


@njit
def _blur_passes(src: np.ndarray, dst: np.ndarray, w0: np.ndarray, w1: np.ndarray,
                 w2: np.ndarray) -> np.ndarray:
    """The passes of :func:`_blur` from ``src`` (overwritten), ``dst`` scratch of its shape:
    returns the one of the two that holds the result."""
    n_k, nx, ny = src.shape
    if w0.size:
        r = w0.size // 2
        for k in range(n_k):
            for i in range(nx):
                for c in range(ny):
                    dst[k, i, c] = src[k, i, c] * w0[r]
            for j in range(-r, 0):
                lo, hi = _extend(k + j, n_k, True), _extend(k - j, n_k, True)
                wj = w0[r + j]
                for i in range(nx):
                    for c in range(ny):
                        dst[k, i, c] += (src[lo, i, c] + src[hi, i, c]) * wj
        src, dst = dst, src
    if w1.size:
        r = w1.size // 2
        for k in range(n_k):
            for i in range(nx):
                for c in range(ny):
                    dst[k, i, c] = src[k, i, c] * w1[r]
                for j in range(-r, 0):
                    lo, hi = _extend(i + j, nx, False), _extend(i - j, nx, False)
                    wj = w1[r + j]
                    for c in range(ny):
                        dst[k, i, c] += (src[k, lo, c] + src[k, hi, c]) * wj
        src, dst = dst, src
    if w2.size:
        r = w2.size // 2
        ext = np.empty(ny + 2 * r, dtype=np.int64)
        for c in range(ny + 2 * r):
            ext[c] = _extend(c - r, ny, False)
        line = np.empty(ny + 2 * r)
        for k in range(n_k):
            for i in range(nx):
                for c in range(ny + 2 * r):
                    line[c] = src[k, i, ext[c]]
                for c in range(ny):
                    dst[k, i, c] = line[c + r] * w2[r]
                for j in range(-r, 0):
                    wj = w2[r + j]
                    for c in range(ny):
                        dst[k, i, c] += (line[c + r + j] + line[c + r - j]) * wj
        src, dst = dst, src
    return src


@njit
def _shift_pose(p: np.ndarray, cos_k: np.ndarray, sin_k: np.ndarray, dx: float, dy: float,
                dtheta: float, cell: float, bin_: float) -> np.ndarray:
    """Steps 1-2 of the motion update (:meth:`MarkovLocalizer._shift`) into a new array
    (:func:`_shift_into`)."""
    n_k, nx, ny = p.shape
    pad = max(nx, ny) + 2
    out = np.empty_like(p)
    _shift_into(p, cos_k, sin_k, dx, dy, dtheta, cell, bin_,
                np.zeros((n_k, nx + 2 * pad, ny + 2 * pad)), np.empty_like(p), out)
    return out


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
    for k in range(n_k):
        for i in range(nx):
            for j in range(ny):
                padded[k, pad + i, pad + j] = p[k, i, j]
    for k in range(n_k):
        gx, gy, fxk, fyk = 1.0 - fx[k], 1.0 - fy[k], fx[k], fy[k]
        o = pad - iy[k]
        for i in range(nx):
            row0 = padded[k, pad + i - ix[k]]
            row1 = padded[k, pad + i - ix[k] - 1]
            for j in range(ny):
                a0 = gx * row0[o + j] + fxk * row1[o + j]
                a1 = gx * row0[o + j - 1] + fxk * row1[o + j - 1]
                q[k, i, j] = gy * a0 + fyk * a1
    if ft == 0.0:
        for k in range(n_k):
            out[k] = q[(k - it) % n_k]
    else:
        gt = 1.0 - ft
        for k in range(n_k):
            k0, k1 = (k - it) % n_k, (k - it - 1) % n_k
            for i in range(nx):
                for j in range(ny):
                    out[k, i, j] = gt * q[k0, i, j] + ft * q[k1, i, j]


@njit
def _log_likelihood(cos_z: np.ndarray, sin_z: np.ndarray, seen: np.ndarray, kappa: float,
                    cos_phi: np.ndarray, sin_phi: np.ndarray, cos_th: np.ndarray,
                    sin_th: np.ndarray) -> np.ndarray:
    """``kappa sum_m cos(s_m - mu_m)`` at every sub-pose (module docstring).

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
def _row_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=0)`` of ``a`` (S, N) without NaN: the best sub-pose of each cell."""
    out = a[0].copy()
    for s in range(1, a.shape[0]):
        for i in range(a.shape[1]):
            out[i] = max(out[i], a[s, i])
    return out


@njit
def _unclipped(a: np.ndarray, cell_max: np.ndarray, best: float, low: float
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
def _sub_pose_sums(a: np.ndarray, cells: np.ndarray, best: float, low: float, exp_low: float,
                   exps: np.ndarray) -> np.ndarray:
    """Per column of ``a`` (S, N), ``sum_s exp(max(a[s] - best, low))`` added row after row
    (as ``a.sum(axis=0)`` adds rows), with ``exp_low`` for the clipped entries and ``exps``
    for the others, in :func:`_unclipped`'s order (``cells``: the columns that have any)."""
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


# ------------------------------------------------------------------ fused kernels (predict,
# update): the operations of the kernels above and of the numpy glue that called them, in
# the same order, without the intermediate arrays (tested against them, bit for bit)

@njit
def _weight_exponents(s_th: float, n_th: int, s_xy: float, n_xy: int, out: np.ndarray) -> None:
    """The exponents ``-0.5 / sigma^2 x^2`` of :func:`_gaussian_weights` for
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
    """``phi / phi.sum()`` of ``phi = e[lo:lo + n]`` (:func:`_gaussian_weights`)."""
    w = np.empty(n)
    total = _pairwise_sum(e, lo, n)
    for i in range(n):
        w[i] = e[lo + i] / total
    return w


@njit
def _predict_into(p: np.ndarray, cos_k: np.ndarray, sin_k: np.ndarray, dx: float, dy: float,
                  dtheta: float, cell: float, bin_: float, e: np.ndarray, n_th: int,
                  n_xy: int, free: np.ndarray, padded: np.ndarray, buf0: np.ndarray,
                  buf1: np.ndarray, out: np.ndarray) -> bool:
    """The motion update of :meth:`MarkovLocalizer.predict` into ``out`` (K, nx, ny): the
    shift and roll (:func:`_shift_pose`), the blur (:func:`_blur`) with the weights
    normalised from their exps ``e`` (heading ``e[:n_th]``, position ``e[n_th:]``; 0: no
    blur of that axis), the free cells, then ``p / sum(p)`` (``_normalised``); ``buf0``,
    ``buf1`` scratch of ``p``'s shape, ``padded`` (K, nx + 2 P, ny + 2 P) zero but for its
    middle, ``P`` above the largest shift (``max(nx, ny) + 2``). Returns False (``out``
    unfinished) when the sum is not positive and finite."""
    # steps 1-2 (_shift_pose) into buf1, step 3 (_blur) from there
    _shift_into(p, cos_k, sin_k, dx, dy, dtheta, cell, bin_, padded, buf0, buf1)
    w_xy = _normalised_weights(e, n_th, n_xy)
    src = _blur_passes(buf1, buf0, _normalised_weights(e, 0, n_th), w_xy, w_xy)
    # p *= free; p / sum(p)
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
    one (:func:`_log_likelihood` then :func:`_row_max`, without the array of every sub-pose).

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
    first_i = first_j = 0
    for i in range(nx):
        for j in range(ny):
            b = 0.0
            for q in range(n_q):
                # a margin far above the rounding of C cos - S sin (~1e-13 here)
                r = math.sqrt(cc[q, i, j] ** 2 + ss[q, i, j] ** 2) * (1.0 + 1e-9) + 1e-9
                bound[q, i, j] = r
                b = max(b, r)
            bound[n_q, i, j] = b
            if b > bound[n_q, first_i, first_j]:
                first_i, first_j = i, j
    best = -np.inf
    computed[:] = False
    v = np.empty(n_k)
    for pos in range(-1, nx * ny):
        if pos < 0:
            i, j = first_i, first_j                   # the most promising position first
        else:
            i, j = pos // ny, pos % ny
            if computed[i, j] or bound[n_q, i, j] < best + low - 1e-6:
                continue
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
                    # kappa cos(A + theta) = C cos theta - S sin theta (_log_likelihood)
                    v[k] = max(v[k], c * cos_tk[t, k] - s * sin_tk[t, k])
        for k in range(n_k):
            cell_max[k, i, j] = v[k]
            best = max(best, v[k])
    return best


@njit
def _unclipped_sub_poses(cc: np.ndarray, ss: np.ndarray, cos_th: np.ndarray,
                         sin_th: np.ndarray, computed: np.ndarray, cell_max: np.ndarray,
                         best: float, low: float, cells: np.ndarray, vals: np.ndarray
                         ) -> tuple[int, int]:
    """:func:`_unclipped` from :func:`_cell_maxima`'s results: the flat indices of the cells
    (C order of (K, nx, ny)) with a sub-pose value ``v = a - best > low`` into ``cells``, and
    those ``v``, cell by cell, sub-poses in order (q, then t), into ``vals``.

    Returns
    -------
    int, int
        How many cells, how many values.
    """
    n_q, nx, ny = cc.shape
    n_k, n_t = cos_th.shape
    n_cells = m = 0
    for k in range(n_k):
        for i in range(nx):
            for j in range(ny):
                if not computed[i, j] or not max(cell_max[k, i, j] - best, low) > low:
                    continue
                cells[n_cells] = (k * nx + i) * ny + j
                n_cells += 1
                for q in range(n_q):
                    c, s = cc[q, i, j], ss[q, i, j]
                    for t in range(n_t):
                        v = max(c * cos_th[k, t] - s * sin_th[k, t] - best, low)
                        if v > low:
                            vals[m] = v
                            m += 1
    return n_cells, m


@njit
def _posterior(cc: np.ndarray, ss: np.ndarray, cos_th: np.ndarray, sin_th: np.ndarray,
               cells: np.ndarray, best: float, low: float, exp_low: float, exps: np.ndarray,
               prior: np.ndarray, uniform: np.ndarray, floor_uniform: np.ndarray, floor: float,
               evidence_min: float, lik: np.ndarray, out: np.ndarray) -> None:
    """The rest of :meth:`MarkovLocalizer.update` into ``out`` (K, nx, ny): the likelihood of
    every cell (:func:`_sub_pose_sums`; ``lik`` (N,) scratch), ``p = lik prior``, restarted
    from ``lik uniform`` when its sum is not above ``evidence_min`` (or not finite), scaled by
    ``(1 - floor) / sum``, plus ``floor_uniform`` when ``floor > 0``."""
    n_q, nx, ny = cc.shape
    n_k, n_t = cos_th.shape
    n_sub = n_q * n_t
    const = exp_low                         # a cell with every sub-pose clipped
    for _ in range(1, n_sub):
        const += exp_low
    # lik (the cells with an unclipped sub-pose: _sub_pose_sums), then lik prior
    m = 0
    for c_i in range(cells.shape[0]):
        c = cells[c_i]
        k, rest = c // (nx * ny), c % (nx * ny)
        i, j = rest // ny, rest % ny
        acc = 0.0
        for q in range(n_q):
            cq, sq = cc[q, i, j], ss[q, i, j]
            for t in range(n_t):
                e = exp_low
                if max(cq * cos_th[k, t] - sq * sin_th[k, t] - best, low) > low:
                    e = exps[m]
                    m += 1
                acc = e if q == 0 and t == 0 else acc + e
        lik[c_i] = acc
    flat = out.reshape(-1)
    n = flat.shape[0]
    for attempt in range(2):
        weights = prior.reshape(-1) if attempt == 0 else uniform.reshape(-1)
        # b(x) <- eta Pr(s | x) b(x)
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
def _update_into(z: np.ndarray, kappa: float, cos_phi: np.ndarray, sin_phi: np.ndarray,
                 cos_tk: np.ndarray, sin_tk: np.ndarray, cos_th: np.ndarray,
                 sin_th: np.ndarray, low: float, exp_low: float, cc: np.ndarray,
                 ss: np.ndarray, bound: np.ndarray, computed: np.ndarray,
                 cell_max: np.ndarray, cells: np.ndarray, vals: np.ndarray,
                 loops: np.ndarray, prior: np.ndarray, uniform: np.ndarray,
                 floor_uniform: np.ndarray, floor: float, evidence_min: float,
                 lik: np.ndarray, out: np.ndarray) -> bool:
    """The sensor update of :meth:`MarkovLocalizer.update` into ``out``: :func:`_cell_maxima`,
    :func:`_unclipped_sub_poses`, their exps by numpy's own loop
    (:func:`cr_sim.core.ufunc_loops.exp_into`; ``loops`` its ``LOOPS``), :func:`_posterior`;
    the other arrays are their scratch. Returns False (``out`` untouched) when no bearing
    is finite (nothing seen)."""
    best = _cell_maxima(z, kappa, cos_phi, sin_phi, cos_tk, sin_tk, low, cc, ss, bound,
                        computed, cell_max)
    if math.isnan(best):
        return False
    n_cells, n_vals = _unclipped_sub_poses(cc, ss, cos_th, sin_th, computed, cell_max, best,
                                           low, cells, vals)
    exp_into(loops, vals, vals, n_vals)
    _posterior(cc, ss, cos_th, sin_th, cells[:n_cells], best, low, exp_low, vals[:n_vals],
               prior, uniform, floor_uniform, floor, evidence_min, lik, out)
    return True
