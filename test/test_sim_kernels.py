"""The compiled kernels (cr_sim.core.kernels, the localization's) give the results of the
reference numpy/Python code they replace: bit for bit where the docstrings say so."""

from __future__ import annotations

import math
from types import SimpleNamespace

from clis_modules.core.decider import Decider
from clis_modules.core.features import RbfGrid, uniform_centers
from clis_modules.core.localization import MarkovLocalizer
from clis_modules.core.localization_reference import EVIDENCE_MIN, EXP_LOG_LIK_MIN, LOG_LIK_MIN
from clis_modules.core.modules import arena_map, load_module_params
from cr_sim.core import kernels
from cr_sim.core.arena import load_arena
from cr_sim.core.geometry import box_planes, disc_gap, slab_planes, wrap_angle, wrap_angles
from cr_sim.core.robot import clamp_wheels, integrate_arc, twist_to_wheels, wheels_to_twist
from cr_sim.core.sim import Simulator, load_sim_params
from localization_kernels import (
    blur,
    gaussian_weights,
    log_likelihood,
    row_max,
    shift_pose,
    sub_pose_sums,
    unclipped,
)
import numpy as np
import pytest
from scipy import ndimage

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits


@pytest.fixture(scope='module')
def world():
    params = load_sim_params()
    arena = load_arena(robot_radius=params.robot.radius)
    return params, arena


def _move_reference(x0, y0, th0, u, rp, dt, boxes, half, tol):
    """The simulator's motion step as written before the kernel (pure Python)."""
    vl, vr = clamp_wheels(u, rp.v_wheel_max)
    v, w = wheels_to_twist(vl, vr, rp.wheel_base)
    x, y, th = integrate_arc(x0, y0, th0, v, w, dt)
    gap = disc_gap(x, y, rp.radius, boxes, half)
    blocked = gap < 0.0
    if blocked:
        lo, hi = 0.0, 1.0
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            xm, ym, _ = integrate_arc(x0, y0, th0, mid * v, w, dt)
            if disc_gap(xm, ym, rp.radius, boxes, half) >= 0.0:
                lo = mid
            else:
                hi = mid
        v *= lo
        x, y, th = integrate_arc(x0, y0, th0, v, w, dt)
        gap = disc_gap(x, y, rp.radius, boxes, half)
        vl, vr = twist_to_wheels(v, w, rp.wheel_base)
    return x, y, wrap_angle(th), float(vl), float(vr), blocked, blocked or gap < tol


def test_move_kernel_is_the_reference_motion_bit_for_bit(world):
    params, arena = world
    rp, ep = params.robot, params.episode
    boxes, half = arena.box_tuples(), arena.half
    rng = np.random.default_rng(0)
    blocked = 0
    for _ in range(3000):
        # free poses near the walls and obstacles, commands incl. out of range and NaN
        while True:
            x, y = rng.uniform(-half + rp.radius, half - rp.radius, 2)
            if disc_gap(x, y, rp.radius, boxes, half) >= 0.0 and rng.random() < 0.3 + 0.7 * (
                    disc_gap(x, y, rp.radius, boxes, half) < 0.05):
                break
        th = rng.uniform(-4.0, 4.0)
        u = rng.uniform(-2.0, 2.0, 2)
        if rng.random() < 0.05:
            u[rng.integers(2)] = np.nan
        want = _move_reference(x, y, th, u, rp, ep.dt, boxes, half, ep.contact_tolerance)
        got = kernels.move(x, y, th, u[0], u[1], rp.v_wheel_max, rp.wheel_base, ep.dt,
                           rp.radius, boxes, half, ep.contact_tolerance, 20)
        assert got == want
        blocked += want[5]
    assert blocked > 100                     # the contact search was exercised


def test_hold_is_repeated_steps_bit_for_bit(world):
    """Simulator.hold(u, n) = step(u) until n steps, a reward or the end: same poses, wheels,
    flags and rewards; odometry composed over its wheels = per step."""
    params, arena = world
    held = Simulator(arena, params, np.random.default_rng(1))
    stepped = Simulator(arena, params, np.random.default_rng(1))
    rng = np.random.default_rng(6)
    # deciders of a module that localizes (only its odometry is used here)
    d_held, d_step = (Decider(SimpleNamespace(on_motion=print, reset=lambda: None), rng,
                              params.robot.wheel_base) for _ in range(2))
    dt = params.episode.dt
    ends = 0
    for _ in range(6):
        held.reset('random')
        stepped.reset('random')
        while not held.done:
            u = rng.uniform(-0.6, 0.6, 2)
            n = int(rng.integers(1, 40))
            res, wheels = held.hold(u, n)
            d_held.on_wheel_steps(wheels, dt)
            assert res.steps == len(wheels) and 1 <= res.steps <= n
            for k in range(res.steps):
                ref = stepped.step(u)
                np.testing.assert_array_equal(wheels[k], stepped.wheels)
                d_step.on_wheels(*stepped.wheel_speeds, dt)
                if k < res.steps - 1:
                    assert ref.reward == 0.0 and not ref.done
            assert (ref.t, ref.reward, ref.collision, ref.reached, ref.timeout) == (
                res.t, res.reward, res.collision, res.reached, res.timeout)
            assert res.steps == n or res.reward != 0.0 or res.done
            np.testing.assert_array_equal(held.pose, stepped.pose)
            assert held.wheel_speeds == stepped.wheel_speeds and held.touching == stepped.touching
            assert d_held._odo == d_step._odo
            ends += res.reward != 0.0
    assert ends > 0


def test_scan_kernel_is_the_reference_sensor_model_bit_for_bit(world):
    params, arena = world
    sp = params.sensors
    angles = np.radians(np.asarray(sp.ir_angles_deg, dtype=np.float64))
    n = len(angles)
    dest = arena.destination
    targets = np.array([[dest.x, dest.y]] + [[lm.x, lm.y] for lm in arena.landmarks])
    tx, ty = np.ascontiguousarray(targets[:, 0]), np.ascontiguousarray(targets[:, 1])
    planes = box_planes(arena.box_array(walls=True))
    n_tall, r = len(arena.tall_obstacles), params.robot.radius
    rng = np.random.default_rng(1)
    hidden = 0
    for k in range(2000):
        while True:
            x, y = rng.uniform(-arena.half + r, arena.half - r, 2)
            if arena.gap(x, y, r) >= 0.0:
                break
        th = rng.uniform(-math.pi, math.pi)
        noise = rng.standard_normal(n + len(targets)) * 0.01
        noisy = k % 2 == 0
        # the reference: the numpy sensor model (slab method over all rays and boxes)
        d = np.empty((2, n + len(targets)))
        d[0, :n], d[1, :n] = np.cos(angles + th), np.sin(angles + th)
        d[0, n:], d[1, n:] = tx - x, ty - y
        t_near, t_far = slab_planes(x, y, d, planes)
        hit = np.where((t_near <= t_far) & (t_near >= 0.0), t_near, np.inf)
        ir = hit[:n].min(axis=1) - r + (noise[:n] if noisy else 0.0)
        ir = np.minimum(np.maximum(ir, 0.0), sp.ir_range)
        bearing = np.arctan2(d[1, n:], d[0, n:]) - th + (noise[n:] if noisy else 0.0)
        bearing = wrap_angles(bearing)
        bearing[hit[n:, :n_tall].min(axis=1) <= 1.0] = np.nan
        got_ir, got_b = kernels.scan(x, y, th, angles, tx, ty, np.arctan2(ty - y, tx - x),
                                     planes, n_tall, r, sp.ir_range, noise, noisy)
        np.testing.assert_array_equal(got_ir, ir)
        np.testing.assert_array_equal(got_b, bearing)
        hidden += int(np.isnan(bearing).sum())
    assert hidden > 50                       # occlusion by the tall obstacles was exercised


def test_wrap_in_scan_matches_wrap_angles_at_the_edges():
    a = np.array([math.pi, -math.pi, 3 * math.pi, -3 * math.pi, 0.0, -0.0, 1e-17, -1e-17,
                  math.pi + 1e-15, 7.0, -7.0, 2 * math.pi, -2 * math.pi, 1e6, -1e6])
    zero = np.zeros(1)
    got = np.array([kernels.scan(0.0, 0.0, 0.0, np.zeros(0), zero + 1.0, zero, np.array([v]),
                                 np.zeros((2, 2, 0)), 0, 0.1, 1.0, zero, False)[1][0]
                    for v in a])
    np.testing.assert_array_equal(got, wrap_angles(a))


def _shift_reference(loc, p, dx, dy, dtheta):
    """The localization's motion shift in numpy, array by array."""
    n = loc.shape[1]
    c, s = np.cos(loc.thetas), np.sin(loc.thetas)
    sx = np.clip((c * dx - s * dy) / loc.cell, -n - 1.0, n + 1.0)
    sy = np.clip((s * dx + c * dy) / loc.cell, -n - 1.0, n + 1.0)
    ix, iy = np.floor(sx).astype(int), np.floor(sy).astype(int)
    fx, fy = (sx - ix)[:, None, None], (sy - iy)[:, None, None]
    pad = int(max(np.abs(ix).max(), np.abs(iy).max())) + 2
    pp = np.zeros((loc.n_headings, n + 2 * pad, n + 2 * pad))
    pp[:, pad:pad + n, pad:pad + n] = p
    kk, idx = np.arange(loc.n_headings)[:, None], np.arange(n)
    rows = pad + idx[None, :] - ix[:, None]
    a = (1.0 - fx) * pp[kk, rows, :] + fx * pp[kk, rows - 1, :]
    cols = (pad + idx[None, :] - iy[:, None])[:, None, :]
    kk3, ii3 = kk[:, :, None], idx[None, :, None]
    out = (1.0 - fy) * a[kk3, ii3, cols] + fy * a[kk3, ii3, cols - 1]
    st = dtheta / loc.bin
    it = int(math.floor(st))
    ft = st - it
    rolled = np.roll(out, it, axis=0)
    if ft > 0.0:
        rolled = (1.0 - ft) * rolled + ft * np.roll(out, it + 1, axis=0)
    return rolled


@pytest.fixture(scope='module')
def localizer():
    lm, half, boxes = arena_map(load_arena())
    return MarkovLocalizer(load_module_params().place.localization, lm, half, boxes)


def _shift(loc, p, dx, dy, dtheta):
    """Steps 1-2 of the motion update on ``loc``'s grid, compiled (shift_pose)."""
    return shift_pose(p, np.cos(loc.thetas), np.sin(loc.thetas), dx, dy, dtheta, loc.cell,
                      loc.bin)


def _log_likelihood(loc, z):
    """log_likelihood on ``loc``'s grid at the bearings ``z`` (NaN: not seen)."""
    seen = np.isfinite(z)
    zs = np.where(seen, z, 0.0)
    return log_likelihood(np.cos(zs), np.sin(zs), seen, loc.kappa, loc.cos_phi, loc.sin_phi,
                          loc.cos_th, loc.sin_th)


def test_localization_shift_kernel_is_the_reference_bit_for_bit(localizer):
    rng = np.random.default_rng(2)
    p = rng.random(localizer.shape)
    for dx, dy, dth in [(0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.0, 0.0, math.pi / 6)] + [
            tuple(rng.normal(0.0, s) for s in (0.3, 0.1, 1.0)) for _ in range(40)] + [
            (5.0, -4.0, 20.0)]:
        np.testing.assert_array_equal(_shift(localizer, p, dx, dy, dth),
                                      _shift_reference(localizer, p, dx, dy, dth))


def test_localization_blur_is_scipy_gaussian_filter_bit_for_bit():
    rng = np.random.default_rng(4)
    for trial in range(150):
        shape = (12, 20, 20) if trial < 80 else tuple(int(v) for v in rng.integers(1, 16, 3))
        p = rng.random(shape)
        s_th, s_xy = (float(rng.choice([0.0, rng.uniform(0.01, 3.0), rng.uniform(3.0, 12.0)],
                                       p=[0.1, 0.8, 0.1])) for _ in range(2))
        want = ndimage.gaussian_filter(p, sigma=(s_th, s_xy, s_xy), truncate=3.0,
                                       mode=('wrap', 'reflect', 'reflect'))
        w = gaussian_weights(s_xy, 3.0)
        np.testing.assert_array_equal(blur(p, gaussian_weights(s_th, 3.0), w, w), want)


def test_localization_likelihood_is_the_von_mises_sum(localizer):
    """kappa sum_m cos(s_m - mu_m) at every sub-pose, from the landmark directions."""
    loc = localizer
    z = np.array([0.3, -2.0, np.nan, 2.9])
    seen = np.isfinite(z)
    zs = np.where(seen, z, 0.0)
    got = _log_likelihood(loc, z)
    phi = np.arctan2(loc.sin_phi, loc.cos_phi)                          # (Q, M, nx, ny)
    theta = np.arctan2(loc.sin_th, loc.cos_th)                          # (K, T)
    mu = phi[:, None, None] - theta.T[None, :, :, None, None, None]     # (Q, T, K, M, ...)
    want = loc.kappa * np.cos(zs[None, None, None, :, None, None] - mu)
    want = (want * seen[None, None, None, :, None, None]).sum(axis=3)
    np.testing.assert_allclose(got, want.reshape(got.shape), rtol=0, atol=1e-9)


def test_localization_cell_likelihood_is_the_reference_bit_for_bit(localizer):
    """Pr(s | cell): exp of the clipped log-likelihoods summed over the sub-poses, computed
    only where a cell has an unclipped sub-pose, = the whole array's numpy reference."""
    loc = localizer
    rng = np.random.default_rng(7)
    for _ in range(60):
        z = rng.uniform(-math.pi, math.pi, len(loc.landmarks_xy))
        z[rng.random(len(z)) < 0.3] = np.nan
        if not np.isfinite(z).any():
            continue
        ll = _log_likelihood(loc, z)
        rows = ll.reshape(ll.shape[0], -1)
        v = np.maximum(rows - rows.max(), LOG_LIK_MIN)
        e = np.full(v.shape, EXP_LOG_LIK_MIN)
        e[v > LOG_LIK_MIN] = np.exp(v[v > LOG_LIK_MIN])
        want = e[0].copy()
        for row in e[1:]:
            want += row
        cell_max = row_max(rows)
        np.testing.assert_array_equal(cell_max, rows.max(axis=0))
        best = float(cell_max.max())
        cells, vals = unclipped(rows, cell_max, best, LOG_LIK_MIN)
        got = sub_pose_sums(rows, cells, best, LOG_LIK_MIN, EXP_LOG_LIK_MIN, np.exp(vals))
        np.testing.assert_array_equal(got, want)


def test_rbf_single_input_is_the_batch_row_bit_for_bit():
    rng = np.random.default_rng(3)
    theta = uniform_centers(-math.pi, math.pi, 9, True)
    for normalize in (True, False):
        g1 = RbfGrid([theta], [0.3], [True], normalize)
        g2 = RbfGrid([theta, uniform_centers(0.0, 0.5, 9, False)], [0.3, 0.01],
                     [True, False], normalize)
        for _ in range(3000):
            x = [rng.uniform(-4.0, 4.0), rng.uniform(-0.1, 0.7)]
            if rng.random() < 0.05:
                x[0] = np.nan
            np.testing.assert_array_equal(g1([x[0]]), g1.batch([[x[0]]])[0])
            np.testing.assert_array_equal(g2(x), g2.batch([x])[0])


def _predict_reference(loc, dx, dy, dtheta):
    """MarkovLocalizer.predict as the step kernels composed (test/localization_kernels.py)."""
    p = _shift(loc, loc.belief_grid, dx, dy, dtheta)
    prm = loc.params
    s_xy = (prm.trans_noise * math.hypot(dx, dy) + prm.trans_noise_min) / loc.cell
    s_th = (prm.rot_noise * abs(dtheta) + math.radians(prm.rot_noise_min_deg)) / loc.bin
    if s_xy > 0.0 or s_th > 0.0:
        w_xy = gaussian_weights(s_xy, 3.0)
        p = blur(p, gaussian_weights(s_th, 3.0), w_xy, w_xy)
    p *= loc.free
    total = p.sum()
    if not (total > 0.0 and math.isfinite(total)):
        return loc.uniform.copy()
    p /= total
    return p


def _update_reference(loc, z):
    """MarkovLocalizer.update as the step kernels composed (test/localization_kernels.py)."""
    if not np.isfinite(z).any():
        return loc.belief_grid
    loglik = _log_likelihood(loc, z)
    rows = loglik.reshape(loglik.shape[0], -1)
    cell_max = row_max(rows)
    best = float(cell_max.max())
    cells, vals = unclipped(rows, cell_max, best, LOG_LIK_MIN)
    lik = sub_pose_sums(rows, cells, best, LOG_LIK_MIN, EXP_LOG_LIK_MIN,
                        np.exp(vals)).reshape(loc.shape)
    p = lik * loc.belief_grid
    total = p.sum()
    if not (total > EVIDENCE_MIN and math.isfinite(total)):
        p = lik * loc.uniform
        total = p.sum()
    f = loc.params.floor
    p *= (1.0 - f) / total
    if f > 0.0:
        p += f * loc.uniform
    return p


@pytest.mark.parametrize('floor', [1e-6, 0.0, 0.05])
def test_localization_fused_predict_and_update_are_the_reference_bit_for_bit(world, floor):
    """The fused kernels of predict and update (pruned cell maxima, one call for the
    posterior) give the beliefs of the composition of the kernels they replace, along a
    robot's trajectory with its real bearings, and on random beliefs, odometry and bearings
    (some or all landmarks unseen, contradicting readings, no motion, large motions)."""
    import dataclasses
    params, arena = world
    lm, half, boxes = arena_map(arena)
    prm = dataclasses.replace(load_module_params().place.localization, floor=floor)
    loc = MarkovLocalizer(prm, lm, half, boxes)
    sim = Simulator(arena, params, np.random.default_rng(5))
    rng = np.random.default_rng(6)
    sim.reset('A')
    n_checked = 0
    for step in range(400):
        if step % 100 == 0:
            loc.reset()
        if step % 7 == 3:                                    # a random belief
            loc.set_belief(rng.random(loc.shape) ** 8)
        u = rng.uniform(-0.6, 0.6, 2)
        res, wheels = sim.hold(u, 24)
        x = y = th = 0.0
        for vl, vr in wheels:
            x, y, th = kernels.odometry_step(x, y, th, vl, vr, params.robot.wheel_base,
                                             params.episode.dt)
        if step % 11 == 5:
            x, y, th = rng.normal(0.0, [0.5, 0.2, 2.0])      # large odometry
        if step % 13 == 6:
            x = y = th = 0.0
        want = _predict_reference(loc, x, y, th)
        loc.predict(x, y, th)
        np.testing.assert_array_equal(loc.belief_grid, want)
        z = np.array(sim.observe().landmark_bearings)
        if step % 5 == 1:                                    # random bearings, some unseen
            z = rng.uniform(-math.pi, math.pi, len(z))
            z[rng.random(len(z)) < 0.3] = np.nan
        if step % 17 == 2:
            z[:] = np.nan
        want = _update_reference(loc, z)
        loc.update(z)
        np.testing.assert_array_equal(loc.belief_grid, want)
        n_checked += 1
        if res.done:
            sim.reset('random')
    assert n_checked == 400


def test_pairwise_sum_is_numpys_sum():
    from clis_modules.core.localization_fused import _pairwise_sum as pairwise
    rng = np.random.default_rng(8)
    for n in list(range(0, 300)) + [1600, 4800, 4801, 9999]:
        a = rng.random(n) * rng.choice([1e-9, 1.0, 1e7], n)
        assert pairwise(a, 0, n) == a.sum()
        if n > 10:
            assert pairwise(a, 3, n - 5) == a[3:n - 2].sum()


@pytest.mark.parametrize('noise', [True, False])
def test_wander_kernel_is_the_python_loop_bit_for_bit(world, noise):
    """Simulator.reset('wander') (the compiled loop) leaves the simulator, the wander policy
    and both random generators as the loop of observe, WanderPolicy.act and _move does."""
    import dataclasses
    params, arena = world
    if not noise:
        params = dataclasses.replace(params, sensors=dataclasses.replace(
            params.sensors, ir_noise_sigma=0.0, bearing_noise_deg=0.0))
    sims = [Simulator(arena, params, np.random.default_rng([9, int(noise)])) for _ in range(2)]

    def state(sim):
        w = sim._wander
        return (sim._x, sim._y, sim._th, sim._wl, sim._wr, sim._touching, sim._tick, sim._k,
                w._steer, w._turn, w._last_v, sim._rng.bit_generator.state,
                sim._noise_rng.bit_generator.state)

    rng = np.random.default_rng(10)
    for episode in range(40):
        for sim in sims:
            if episode % 3 == 1:
                sim.observe()              # the first wander tick reads this observation
        sims[0]._set_pose(*sims[0]._run_wander())
        sims[1]._set_pose(*sims[1]._run_wander_reference())
        assert state(sims[0]) == state(sims[1])
        u, n = rng.uniform(-1.0, 1.0, 2), int(rng.integers(1, 200))
        for sim in sims:                   # an episode's worth of driving in between
            sim.hold(u, n)
        assert state(sims[0]) == state(sims[1])


def test_sensing_is_the_reference_bit_for_bit(world):
    """Simulator.observe and Simulator.sense (one kernel with numpy's arctan2 loop, noise
    drawn in blocks) give the readings of the code before them: per observation
    standard_normal(n_rays) * sigmas, np.arctan2 then kernels.scan_into, d_o = min(ir)."""
    params, arena = world
    sim = Simulator(arena, params, np.random.default_rng(11))
    ref_noise = np.random.default_rng(11).spawn(1)[0]
    rng = np.random.default_rng(12)
    sim.reset('A')
    for step in range(3000):
        noise = ref_noise.standard_normal(sim._n_rays) * sim._sigmas
        x, y, th = sim._x, sim._y, sim._th
        dx, dy = sim._targets_x - x, sim._targets_y - y
        ir, bearing = kernels.scan(x, y, th, sim._ir_angles, sim._targets_x, sim._targets_y,
                                   np.arctan2(dy, dx), sim._planes, sim._n_tall, sim._r,
                                   sim._ir_range, noise, sim._noisy)
        if step % 2:
            obs = sim.observe()
            dest, d_o, lm = sim.sense()
        else:
            dest, d_o, lm = sim.sense()
            obs = sim.observe()
        np.testing.assert_array_equal(obs.ir, ir)
        np.testing.assert_array_equal(obs.landmark_bearings, bearing[1:])
        np.testing.assert_array_equal(lm, bearing[1:])
        assert d_o == obs.d_o == ir.min()
        assert (math.isnan(dest) and math.isnan(bearing[0])) or dest == bearing[0]
        assert (math.isnan(dest) and math.isnan(obs.dest_bearing)) or dest == obs.dest_bearing
        res = sim.step(rng.uniform(-1.0, 1.0, 2))
        if res.done:
            sim.reset('random')       # observes: the next reference draw is its noise


def test_the_numpy_layout_reader_is_pinned_to_the_versions_it_was_checked_on():
    """numpy's own loops are called from the kernels only on a numpy whose ufunc layout was
    checked (requirements-py.txt pins one); on any other the raw offsets are not read, the
    loops are zeros (the C library's functions) and a warning says so."""
    from clis_base import ufunc_loops
    assert ufunc_loops.supported(), ufunc_loops.numpy_version()
    assert ufunc_loops.LOOPS[0] != 0 and ufunc_loops.LOOPS[2] != 0
    assert not ufunc_loops.supported('2.5.0') and not ufunc_loops.supported('1.26.4')
    with pytest.warns(RuntimeWarning, match='numpy 9.9.0 is not one of'):
        loops = ufunc_loops._checked_loops('9.9.0')
    assert not loops.any()
