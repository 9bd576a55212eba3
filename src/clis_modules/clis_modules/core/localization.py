"""Grid Markov localization on landmark bearings: the state of the place module (paper III-D).

The model (the grid, its array layout, the initial belief, the motion update
``b(x') <- sum_x Pr(x' | x, u) b(x)`` and the sensor update ``b(x) <- eta Pr(s | x) b(x)`` on
the landmark bearings) is :mod:`clis_modules.core.localization_reference`'s docstring, and its
functions are the two updates as the paper writes them, in numpy and scipy.

:class:`MarkovLocalizer` holds the grid and the belief, and runs each update as one compiled
call of :mod:`clis_modules.core.localization_fused` (the same arithmetic in the same order,
bit-identical beliefs: tested), with its grid in a
:class:`~clis_modules.core.localization_fused.Grid` and its scratch arrays in a
:class:`~clis_modules.core.localization_fused.Scratch`; what the reference reads of the grid
are its public read-only names (:attr:`MarkovLocalizer.free`, :attr:`MarkovLocalizer.cos_phi`,
...).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from clis_base.params import dataclass, param
from cr_sim.core.robot import integrate_arc, wheels_to_twist
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.localization_fused import Grid, Scratch, predict_into, update_into

if TYPE_CHECKING:
    from clis_modules.core.plugin import Floor

__all__ = ['LocalizationParams', 'MarkovLocalizer']


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
    """Belief over the pose grid with motion and sensor updates (the model:
    :mod:`clis_modules.core.localization_reference`).

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
    cell, bin : float
        Cell side [m], heading bin ``2 pi / n_headings`` [rad].
    kappa : float
        ``1 / sigma_bearing^2`` of the von Mises likelihood of a bearing.
    free, uniform, cos_phi, sin_phi, cos_th, sin_th : np.ndarray
        The grid as the updates read it (read-only views; their properties).
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
        free_k = np.broadcast_to(free, self.shape).astype(np.float64)
        uniform = free_k / free_k.sum()
        floor_uniform = params.floor * uniform
        # C order for the kernels (the same values; broadcast_to(...).astype keeps strides
        # with the heading fastest)
        self._free, self._uniform, floor_uniform = (
            np.ascontiguousarray(a) for a in (free_k, uniform, floor_uniform))

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
        cos_phi = np.ascontiguousarray(np.cos(phi))
        sin_phi = np.ascontiguousarray(np.sin(phi))
        th_sub = self.thetas[:, None] + off_th[None, :]                 # (K, T)
        cos_th = np.ascontiguousarray(np.cos(th_sub))
        sin_th = np.ascontiguousarray(np.sin(th_sub))
        self._p = self._uniform.copy()
        # the compiled updates' view of the grid, and their scratch arrays
        self._grid = Grid(self.shape, self.cell, self.bin, self.kappa, params.floor,
                          np.cos(self.thetas), np.sin(self.thetas), cos_phi, sin_phi, cos_th,
                          sin_th, np.ascontiguousarray(cos_th.T),
                          np.ascontiguousarray(sin_th.T), self._free, self._uniform,
                          floor_uniform)
        self._scratch = Scratch.for_grid(self._grid)

    # ------------------------------------------------------------------ state

    def reset(self) -> None:
        """Uniform belief over the free cells (the start pose is unknown, paper III-D)."""
        self._p = self._uniform.copy()

    @property
    def belief_grid(self) -> np.ndarray:
        """The belief, shape ``(n_headings, nx, ny)`` (read-only view)."""
        return _read_only(self._p)

    @property
    def belief(self) -> np.ndarray:
        """The flat belief, shape (N,), the place module's features (read-only view)."""
        return self.belief_grid.reshape(-1)

    # ------------------------------------------------------------------ the grid (read-only)

    @property
    def free(self) -> np.ndarray:
        """1.0 on the free cells, 0.0 on those inside an obstacle, shape
        ``(n_headings, nx, ny)`` (read-only view)."""
        return _read_only(self._free)

    @property
    def uniform(self) -> np.ndarray:
        """The uniform belief over the free cells, shape ``(n_headings, nx, ny)`` (read-only
        view): the initial belief."""
        return _read_only(self._uniform)

    @property
    def cos_phi(self) -> np.ndarray:
        """``cos phi_m(p)``, ``phi_m(p)`` the direction of landmark m from sub-position q of
        each cell, shape ``(Q, M, nx, ny)`` with ``Q = sub_cells^2`` (read-only view)."""
        return _read_only(self._grid.cos_phi)

    @property
    def sin_phi(self) -> np.ndarray:
        """``sin phi_m(p)``, as :attr:`cos_phi`."""
        return _read_only(self._grid.sin_phi)

    @property
    def cos_th(self) -> np.ndarray:
        """Cosine of sub-heading t of each heading bin k, shape ``(n_headings, T)`` with
        ``T = sub_headings`` (read-only view)."""
        return _read_only(self._grid.cos_th)

    @property
    def sin_th(self) -> np.ndarray:
        """Sine of sub-heading t of each heading bin k, as :attr:`cos_th`."""
        return _read_only(self._grid.sin_th)

    # ------------------------------------------------------------------ the belief

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

        Notes
        -----
        The noise floors ``trans_noise_min``, ``rot_noise_min_deg`` are added per call: one
        call per place-module period, not one per simulator tick.
        """
        prm = self.params
        # the noise of (a) motion: std proportional to the distance and the turn, plus a floor
        s_xy = (prm.trans_noise * math.hypot(dx, dy) + prm.trans_noise_min) / self.cell
        s_th = (prm.rot_noise * abs(dtheta) + math.radians(prm.rot_noise_min_deg)) / self.bin
        p = np.empty(self.shape)
        if predict_into(self._grid, self._scratch, self._p, dx, dy, dtheta, s_th, s_xy, p):
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
            # each update that changes the belief makes a new array: copy only the belief
            return (self._p.copy() if self._p is saved else self._p).reshape(-1)
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
        # read-only): one compiled signature of update_into for every caller
        z = np.array(landmark_bearings, dtype=np.float64).reshape(-1)
        if z.shape[0] != len(self.landmarks_xy):
            raise ValueError(f'expected {len(self.landmarks_xy)} landmark bearings, '
                             f'got {z.shape[0]}')
        # ln Pr(s | x') = sum_m kappa cos(s_m - mu_m(x')) + const  (von Mises per landmark),
        # at every sub-pose x' of every cell, relative to the best one, clipped LOG_LIK_MIN
        # below it (no denormals), then Pr(s | cell) and b(x) <- eta Pr(s | x) b(x) with the
        # floor: one compiled call (update_into); nothing seen: no change
        p = np.empty(self.shape)
        if update_into(self._grid, self._scratch, self._p, z, p):
            self._p = p

    def _normalised(self, p: np.ndarray) -> np.ndarray:
        """``p / sum(p)``, in place (``p`` is a new array of the caller's)."""
        total = p.sum()
        if not (total > 0.0 and math.isfinite(total)):
            return self._uniform.copy()
        p /= total
        return p


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a``."""
    v = a.view()
    v.flags.writeable = False
    return v
