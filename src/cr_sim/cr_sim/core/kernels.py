"""Compiled per-tick kernels of the simulator: one step of motion with contact, one sensor scan.

The model is where it is documented (:mod:`cr_sim.core.robot`, :mod:`cr_sim.core.geometry`,
the module docstring of :mod:`cr_sim.core.sim`); these kernels only run the same arithmetic
without the Python interpreter's cost per operation: the scalar functions of those modules are
compiled as they are (:data:`HAVE_NUMBA`: with numba, else they run as plain Python), and the
ray casts are the scalar loops of :func:`cr_sim.core.geometry.slab_planes`. Every floating-point
operation is the one of the reference code, in the same order, and the transcendental functions
are those of the reference (``math.sin``/``math.cos`` are the C library's in numpy, Python and
numba alike; ``atan2`` and ``exp``, whose numpy versions are SIMD code that differs from the C
library in the last bit, are numpy's own loops called from the kernel,
:mod:`clis_base.ufunc_loops`), so the simulator's results are bit-identical to the reference
code's (tested: ``test/test_sim_kernels.py``). :func:`sense` is an observation, :func:`hold`
the steps between two decisions, :func:`wander` the wander between episodes.

Compiled functions are cached on disk (``__pycache__``); the first import in a fresh checkout
compiles them (a few seconds).
"""

from __future__ import annotations

import math

from clis_base.ufunc_loops import HAVE_NUMBA, arctan2_into, njit, pairwise_sum
import numpy as np

from cr_sim.core.geometry import TWO_PI, disc_gap, wrap_angle
from cr_sim.core.robot import clamp_wheel, integrate_arc

__all__ = ['HAVE_NUMBA', 'njit', 'move', 'hold', 'scan', 'scan_into', 'scan_many', 'ir_into',
           'sense', 'odometry_step', 'odometry', 'wander']

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
    ir_into(x, y, th, ir_angles, planes, radius, ir_range, noise, noisy, ir)
    n = ir_angles.shape[0]
    for j in range(targets_x.shape[0]):
        if _first_hit(x, y, targets_x[j] - x, targets_y[j] - y, planes, n_tall) <= 1.0:
            out[j] = np.nan          # the segment to the target enters a tall obstacle
            continue
        a = bearing[j] - th
        if noisy:
            a += noise[n + j]
        # geometry.wrap_angles: pi - (pi - a) mod 2 pi; Python's float % is numpy's
        # remainder (fmod, shifted by the divisor when the signs differ); a remainder of
        # 2 pi (rounding) is mapped to 0
        m = (math.pi - a) % TWO_PI
        if m >= TWO_PI:
            m = 0.0
        out[j] = math.pi - m


@njit
def _first_hit(x: float, y: float, dx: float, dy: float, planes: np.ndarray, n_b: int) -> float:
    """The ray ``(x, y) + t (dx, dy)``, ``t >= 0``: the smallest ``t`` at which it enters one
    of the first ``n_b`` boxes of ``planes`` (inf: none) (:func:`geometry.slab_planes`)."""
    # inverse directions (+1e-300: no 0 * inf), then per box the slab entry/exit per axis
    # and the overlap of the two intervals
    inv_x = 1.0 / (dx + 1e-300)
    inv_y = 1.0 / (dy + 1e-300)
    first = np.inf
    for b in range(n_b):
        tx0 = inv_x * (planes[0, 0, b] - x)
        tx1 = inv_x * (planes[0, 1, b] - x)
        ty0 = inv_y * (planes[1, 0, b] - y)
        ty1 = inv_y * (planes[1, 1, b] - y)
        t_near = max(min(tx0, tx1), min(ty0, ty1))
        t_far = min(max(tx0, tx1), max(ty0, ty1))
        if t_near <= t_far and t_near >= 0.0 and t_near < first:
            first = t_near
    return first


@njit
def ir_into(x: float, y: float, th: float, ir_angles: np.ndarray, planes: np.ndarray,
            radius: float, ir_range: float, noise: np.ndarray, noisy: bool,
            ir: np.ndarray) -> None:
    """The IR readings of :func:`scan` into ``ir`` (n,): the first hit of each beam over all
    boxes, from the body surface (+ ``noise[r]`` when ``noisy``), clipped to
    ``[0, ir_range]``."""
    for r in range(ir_angles.shape[0]):
        a = ir_angles[r] + th
        v = _first_hit(x, y, math.cos(a), math.sin(a), planes, planes.shape[2]) - radius
        if noisy:
            v += noise[r]
        v = max(v, 0.0)
        ir[r] = min(v, ir_range)


@njit
def sense(x: float, y: float, th: float, ir_angles: np.ndarray, targets_x: np.ndarray,
          targets_y: np.ndarray, planes: np.ndarray, n_tall: int, radius: float,
          ir_range: float, noise: np.ndarray, noisy: bool, loops: np.ndarray, dx: np.ndarray,
          dy: np.ndarray, ir: np.ndarray, out: np.ndarray) -> float:
    """:func:`scan_into` with its input ``bearing = np.arctan2(ty - y, tx - x)`` made here by
    numpy's own loop (:mod:`clis_base.ufunc_loops`; ``loops`` its :data:`LOOPS`), ``dx``,
    ``dy`` (T,) scratch that ends as ``tx - x``, ``ty - y``.

    Returns
    -------
    float
        The smallest IR reading (``Observation.d_o``).
    """
    n_t = targets_x.shape[0]
    for j in range(n_t):
        dx[j] = targets_x[j] - x
        dy[j] = targets_y[j] - y
    arctan2_into(loops, dy, dx, out, n_t)          # bearing, overwritten by the scan
    scan_into(x, y, th, ir_angles, targets_x, targets_y, out, planes, n_tall, radius,
              ir_range, noise, noisy, ir, out)
    d_o = ir[0]
    for r in range(1, ir.shape[0]):
        d_o = min(d_o, ir[r])
    return d_o


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


@njit
def _masked_sum(a: np.ndarray, mask: np.ndarray) -> float:
    """``np.sum(a[mask])`` (numpy's order of additions: :func:`ufunc_loops.pairwise_sum`)."""
    sel = np.empty(a.shape[0])
    n = 0
    for i in range(a.shape[0]):
        if mask[i]:
            sel[n] = a[i]
            n += 1
    return pairwise_sum(sel, 0, n)


@njit
def wander(x: float, y: float, th: float, wl: float, wr: float, touching: bool, k: int,
           n: int, n_max: int, state: np.ndarray, wparams: np.ndarray, front: np.ndarray,
           left: np.ndarray, right: np.ndarray, ir_angles: np.ndarray, planes: np.ndarray,
           radius: float, ir_range: float, sigmas: np.ndarray, noisy: bool, rng,
           noise_rng, noise_block: np.ndarray, noise_pos: np.ndarray, v_max: float,
           wheel_base: float, dt: float, boxes: tuple, half: float,
           tol: float, n_bisect: int, dest_x: float, dest_y: float, goal_r2: float
           ) -> tuple[float, float, float, float, float, bool, int]:
    """The wander of :meth:`cr_sim.core.sim.Simulator.reset` (``start='wander'``) from step
    ``k``: a tick is an observation, :meth:`cr_sim.core.wander.WanderPolicy.act` on it and
    :func:`move`, while ``k < n``, or while the centre is in the goal and ``k < n_max``.

    The observation's IR readings as :func:`scan` computes them, with the noise of
    ``Simulator.observe``: the next row ``noise_pos[0]`` of ``noise_block`` (B, n_rays),
    refilled when used up with ``standard_normal((B, n_rays)) * sigmas`` from ``noise_rng``
    (in order: the same numbers); nothing when not ``noisy``. The camera bearings, which the
    policy does not read, are not computed. The policy's arithmetic and draws from ``rng``
    are :meth:`WanderPolicy.act`'s; its state ``(steer, turn, last_v)`` is read from and
    written to ``state``, its parameters ``wparams`` are ``(speed, turn_speed,
    avoid_distance, steer_sigma, steer_max)``, ``front``, ``left``, ``right`` its beam masks.

    Returns
    -------
    x, y, theta, v_left, v_right, touching, k
        After the last tick (the executed wheels of its :func:`move`).
    """
    speed, turn_speed, avoid, steer_sigma, steer_max = (wparams[0], wparams[1], wparams[2],
                                                         wparams[3], wparams[4])
    steer, turn, last_v = state[0], state[1], state[2]
    n_ir = ir_angles.shape[0]
    n_block, n_rays = noise_block.shape
    pos = noise_pos[0]
    noise = np.zeros(n_rays)
    ir = np.empty(n_ir)
    while True:
        dx, dy = x - dest_x, y - dest_y
        if not (k < n or (dx * dx + dy * dy <= goal_r2 and k < n_max)):
            break
        if noisy:
            if pos == n_block:
                for i in range(n_block):
                    for r in range(n_rays):
                        noise_block[i, r] = noise_rng.standard_normal() * sigmas[r]
                pos = 0
            noise = noise_block[pos]
            pos += 1
        ir_into(x, y, th, ir_angles, planes, radius, ir_range, noise, noisy, ir)
        # WanderPolicy.act
        stuck = last_v > 0.0 and 0.5 * (wl + wr) < 0.25 * last_v
        front_min = np.inf
        for r in range(n_ir):
            if front[r]:
                front_min = min(front_min, ir[r])
        if stuck or front_min < avoid:
            if turn == 0.0:
                # turn toward the freer side (left = counter-clockwise = +1); ties: random
                sum_left = _masked_sum(ir, left)
                sum_right = _masked_sum(ir, right)
                if sum_left == sum_right:
                    turn = 1.0 if rng.random() < 0.5 else -1.0
                else:
                    turn = 1.0 if sum_left > sum_right else -1.0
            steer = 0.0
            last_v = 0.0
            u_left, u_right = -turn * turn_speed, turn * turn_speed
        else:
            turn = 0.0
            last_v = speed
            if steer_sigma > 0.0:
                steer += steer_sigma * rng.standard_normal()
                steer = min(steer_max, max(-steer_max, steer))
            u_left, u_right = speed - steer, speed + steer
        x, y, th, wl, wr, _blocked, touching = move(x, y, th, u_left, u_right, v_max,
                                                    wheel_base, dt, radius, boxes, half, tol,
                                                    n_bisect)
        k += 1
    state[0], state[1], state[2] = steer, turn, last_v
    noise_pos[0] = pos
    return x, y, th, wl, wr, touching, k
