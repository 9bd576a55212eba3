"""Compiled per-tick kernels of the simulator: one step of motion with contact, one sensor scan.

The model is where it is documented (:mod:`cr_sim.core.robot`, :mod:`cr_sim.core.geometry`,
the module docstring of :mod:`cr_sim.core.sim`); these kernels only run the same arithmetic
without the Python interpreter's cost per operation: the scalar functions of those modules are
compiled as they are (:data:`HAVE_NUMBA`: with numba, else they run as plain Python), and the
ray casts are the scalar loops of :func:`cr_sim.core.geometry.slab_planes`. Every floating-point
operation is the one of the reference code, in the same order, and the transcendental functions
are those of the reference (``math.sin``/``math.cos`` are the C library's in numpy, Python and
numba alike; ``atan2`` and ``exp``, whose numpy versions are SIMD code that differs from the C
library in the last bit, stay numpy calls outside the kernels), so the simulator's results are
bit-identical to the reference code's (tested: ``test/test_sim_kernels.py``).

Compiled functions are cached on disk (``__pycache__``); the first import in a fresh checkout
compiles them (a few seconds).
"""

from __future__ import annotations

import math

import numpy as np

from cr_sim.core.geometry import TWO_PI, disc_gap, wrap_angle
from cr_sim.core.robot import clamp_wheel, integrate_arc

__all__ = ['HAVE_NUMBA', 'njit', 'move', 'hold', 'scan', 'scan_many', 'odometry_step',
           'odometry']

try:  # pragma: no cover - exercised by whichever branch is installed
    import numba

    HAVE_NUMBA = True

    def njit(fn):
        """Compile ``fn`` in nopython mode (cached on disk, no fast-math: IEEE semantics)."""
        return numba.njit(cache=True, nogil=True)(fn)
except ImportError:  # pragma: no cover
    HAVE_NUMBA = False

    def njit(fn):
        """numba is not installed: run ``fn`` as plain Python (same results, slower)."""
        return fn


_disc_gap = njit(disc_gap)
_arc = njit(integrate_arc)
_wrap = njit(wrap_angle)
_clamp = njit(clamp_wheel)


@njit
def odometry_step(x: float, y: float, th: float, v_left: float, v_right: float,
                  wheel_base: float, dt: float) -> tuple[float, float, float]:
    """Pose ``(x, y, th)`` after the wheels ``(v_left, v_right)`` [m/s] for ``dt`` [s]:
    :func:`~cr_sim.core.robot.wheels_to_twist` then :func:`~cr_sim.core.robot.integrate_arc`
    (theta not wrapped)."""
    return _arc(x, y, th, 0.5 * (v_left + v_right), (v_right - v_left) / wheel_base, dt)


@njit
def odometry(x: float, y: float, th: float, wheels: np.ndarray, wheel_base: float,
             dt: float) -> tuple[float, float, float]:
    """:func:`odometry_step` over the rows ``(v_left, v_right)`` of ``wheels`` (K, 2), oldest
    first: the same operations as K calls of it."""
    for s in range(wheels.shape[0]):
        x, y, th = odometry_step(x, y, th, wheels[s, 0], wheels[s, 1], wheel_base, dt)
    return x, y, th


@njit
def move(x0: float, y0: float, th0: float, u_left: float, u_right: float, v_max: float,
         wheel_base: float, dt: float, radius: float, boxes: tuple, half: float, tol: float,
         n_bisect: int) -> tuple[float, float, float, float, float, bool, bool]:
    """One ``dt`` of motion from ``(x0, y0, th0)`` under the command ``(u_left, u_right)``.

    The command is clamped (:func:`~cr_sim.core.robot.clamp_wheel`); the contact model is the
    one of :mod:`cr_sim.core.sim`: if the end pose overlaps, the forward speed is scaled by the
    largest free factor found by ``n_bisect`` halvings, the yaw rate kept.

    Returns
    -------
    x, y, theta : float
        End pose, theta wrapped to (-pi, pi].
    v_left, v_right : float
        Executed wheel velocities [m/s].
    blocked : bool
        The step was cut short by a contact.
    touching : bool
        ``blocked`` or the end gap is below ``tol``.
    """
    vl = _clamp(u_left, v_max)
    vr = _clamp(u_right, v_max)
    v, w = 0.5 * (vl + vr), (vr - vl) / wheel_base          # robot.wheels_to_twist
    x, y, th = _arc(x0, y0, th0, v, w, dt)
    gap = _disc_gap(x, y, radius, boxes, half)
    blocked = gap < 0.0
    if blocked:
        # largest fraction s of the forward speed whose end pose is free
        lo, hi = 0.0, 1.0
        for _ in range(n_bisect):
            mid = 0.5 * (lo + hi)
            xm, ym, _tm = _arc(x0, y0, th0, mid * v, w, dt)
            if _disc_gap(xm, ym, radius, boxes, half) >= 0.0:
                lo = mid
            else:
                hi = mid
        v *= lo
        x, y, th = _arc(x0, y0, th0, v, w, dt)
        gap = _disc_gap(x, y, radius, boxes, half)
        h = 0.5 * w * wheel_base                              # robot.twist_to_wheels
        vl, vr = v - h, v + h
    return x, y, _wrap(th), vl, vr, blocked, blocked or gap < tol


@njit
def scan(x: float, y: float, th: float, ir_angles: np.ndarray, targets_x: np.ndarray,
         targets_y: np.ndarray, bearing: np.ndarray, planes: np.ndarray, n_tall: int,
         radius: float, ir_range: float, noise: np.ndarray, noisy: bool
         ) -> tuple[np.ndarray, np.ndarray]:
    """IR readings and camera bearings from pose ``(x, y, th)`` (model: :mod:`cr_sim.core.sim`).

    Parameters
    ----------
    ir_angles : np.ndarray, shape (n,)
        Beam angles from the heading [rad].
    targets_x, targets_y : np.ndarray, shape (T,)
        Destination then landmarks [m].
    bearing : np.ndarray, shape (T,)
        ``arctan2(ty - y, tx - x)`` of each target (numpy's, computed by the caller).
    planes : np.ndarray, shape (2, 2, B)
        Boxes from :func:`~cr_sim.core.geometry.box_planes` (tall obstacles first, walls last).
    n_tall : int
        Number of tall obstacles (the first boxes): they hide targets.
    noise : np.ndarray, shape (n + T,)
        Gaussian noise of each reading (used when ``noisy``).

    Returns
    -------
    ir : np.ndarray, shape (n,)
        Readings clipped to ``[0, ir_range]``.
    bearing : np.ndarray, shape (T,)
        ``bearing - th + noise`` wrapped to (-pi, pi] (as :func:`geometry.wrap_angles`);
        NaN where a tall obstacle crosses the segment to the target.
    """
    ir = np.empty(ir_angles.shape[0])
    out = np.empty(targets_x.shape[0])
    scan_into(x, y, th, ir_angles, targets_x, targets_y, bearing, planes, n_tall, radius,
              ir_range, noise, noisy, ir, out)
    return ir, out


@njit
def scan_many(x: np.ndarray, y: np.ndarray, th: np.ndarray, ir_angles: np.ndarray,
              targets_x: np.ndarray, targets_y: np.ndarray, bearing: np.ndarray,
              planes: np.ndarray, n_tall: int, radius: float, ir_range: float,
              noise: np.ndarray, noisy: bool, ir: np.ndarray, out: np.ndarray) -> None:
    """:func:`scan` of N robots at once (one arena): poses ``x, y, th`` (N,), ``bearing``
    (N, T), ``noise`` (N, n + T); results into ``ir`` (N, n) and ``out`` (N, T)."""
    for i in range(x.shape[0]):
        scan_into(x[i], y[i], th[i], ir_angles, targets_x, targets_y, bearing[i], planes,
                  n_tall, radius, ir_range, noise[i], noisy, ir[i], out[i])


@njit
def scan_into(x: float, y: float, th: float, ir_angles: np.ndarray, targets_x: np.ndarray,
              targets_y: np.ndarray, bearing: np.ndarray, planes: np.ndarray, n_tall: int,
              radius: float, ir_range: float, noise: np.ndarray, noisy: bool, ir: np.ndarray,
              out: np.ndarray) -> None:
    """:func:`scan` into given arrays ``ir`` (n,) and ``out`` (T,)."""
    n = ir_angles.shape[0]
    n_t = targets_x.shape[0]
    n_b = planes.shape[2]
    for r in range(n + n_t):
        if r < n:
            a = ir_angles[r] + th
            dx, dy = math.cos(a), math.sin(a)
        else:
            dx, dy = targets_x[r - n] - x, targets_y[r - n] - y
        # geometry.slab_planes: inverse directions (+1e-300: no 0 * inf), then per box the
        # slab entry/exit per axis and the overlap of the two intervals
        inv_x = 1.0 / (dx + 1e-300)
        inv_y = 1.0 / (dy + 1e-300)
        first = np.inf          # first hit over all boxes (IR), or over the tall ones (camera)
        for b in range(n_b):
            if r >= n and b >= n_tall:
                break
            tx0 = inv_x * (planes[0, 0, b] - x)
            tx1 = inv_x * (planes[0, 1, b] - x)
            ty0 = inv_y * (planes[1, 0, b] - y)
            ty1 = inv_y * (planes[1, 1, b] - y)
            t_near = max(min(tx0, tx1), min(ty0, ty1))
            t_far = min(max(tx0, tx1), max(ty0, ty1))
            if t_near <= t_far and t_near >= 0.0 and t_near < first:
                first = t_near
        if r < n:
            # beams start on the body surface: reading = t_hit - radius (+ noise), clipped
            v = first - radius
            if noisy:
                v += noise[r]
            v = max(v, 0.0)
            ir[r] = min(v, ir_range)
        else:
            j = r - n
            if first <= 1.0:
                out[j] = np.nan      # the segment to the target enters a tall obstacle
                continue
            a = bearing[j] - th
            if noisy:
                a += noise[r]
            # geometry.wrap_angles: pi - (pi - a) mod 2 pi; Python's float % is numpy's
            # remainder (fmod, shifted by the divisor when the signs differ); a remainder of
            # 2 pi (rounding) is mapped to 0
            m = (math.pi - a) % TWO_PI
            if m >= TWO_PI:
                m = 0.0
            out[j] = math.pi - m


@njit
def hold(x: float, y: float, th: float, touching: bool, k: int, k_max: int, u_left: float,
         u_right: float, n: int, v_max: float, wheel_base: float, dt: float, radius: float,
         boxes: tuple, half: float, tol: float, n_bisect: int, dest_x: float, dest_y: float,
         goal_r2: float, wheels: np.ndarray
         ) -> tuple[float, float, float, bool, int, int, bool, bool]:
    """Up to ``n`` (>= 1) steps of :func:`move` under the same command, from step count ``k``,
    stopping after the first step that begins a contact, reaches the goal (the centre within
    ``sqrt(goal_r2)`` of ``(dest_x, dest_y)``) or reaches step ``k_max``: the steps of
    :meth:`cr_sim.core.sim.Simulator.step` without a return to Python between them.

    Returns
    -------
    x, y, theta : float
        End pose.
    touching : bool
        Of the last step.
    k : int
        Step count after the last step.
    steps : int
        Steps done; their executed ``(v_left, v_right)`` are written to ``wheels[:steps]``.
    collision, reached : bool
        Of the last step: a new contact began, the goal is reached.
    """
    steps = 0
    collision = reached = False
    while steps < n:
        before = touching
        x, y, th, vl, vr, _blocked, touching = move(x, y, th, u_left, u_right, v_max,
                                                    wheel_base, dt, radius, boxes, half, tol,
                                                    n_bisect)
        wheels[steps, 0] = vl
        wheels[steps, 1] = vr
        steps += 1
        k += 1
        collision = touching and not before
        dx, dy = x - dest_x, y - dest_y
        reached = dx * dx + dy * dy <= goal_r2
        if collision or reached or k >= k_max:
            break
    return x, y, th, touching, k, steps, collision, reached
