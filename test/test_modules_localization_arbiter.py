"""Tests of grid Markov localization (paper III-D) and of the selection (3) and arbiter."""

from __future__ import annotations

import math

from clis_modules.core.arbiter import Arbiter, ArbiterParams, selection_probs
from clis_modules.core.localization import LocalizationParams, MarkovLocalizer
from clis_modules.core.plugin import Floor
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])
HALF = 1.5
FLOOR = Floor.square(HALF)


def loc_params(**kw) -> LocalizationParams:
    base = dict(cell_size=0.15, n_headings=12, bearing_sigma_deg=5.0, trans_noise=0.1,
                trans_noise_min=0.03, rot_noise=0.1, rot_noise_min_deg=5.0, floor=1e-6,
                sub_cells=2, sub_headings=3)
    base.update(kw)
    return LocalizationParams(**base)


def exact_bearings(x: float, y: float, theta: float) -> np.ndarray:
    """Bearings of the landmarks from a pose, relative to the heading, in (-pi, pi]."""
    return np.array([math.remainder(math.atan2(ly - y, lx - x) - theta, 2 * math.pi)
                     for lx, ly in LANDMARKS])


def arc(v: float, omega: float, dt: float) -> tuple[float, float, float]:
    """Exact displacement (robot frame) after holding (v, omega) for dt."""
    a = 0.5 * omega * dt
    chord = v * dt * (math.sin(a) / a if a else 1.0)
    return chord * math.cos(a), chord * math.sin(a), omega * dt


# ------------------------------------------------------------------------------ grid

def test_grid_geometry_and_uniform_prior():
    loc = MarkovLocalizer(loc_params(), LANDMARKS, FLOOR)
    assert loc.shape == (12, 20, 20) and loc.size == 4800      # the paper's "450 states"
    assert loc.xs[0] == pytest.approx(-1.425) and loc.xs[-1] == pytest.approx(1.425)
    assert loc.belief.sum() == pytest.approx(1.0) and np.ptp(loc.belief) == 0.0
    boxed = MarkovLocalizer(loc_params(), LANDMARKS, FLOOR, boxes=[[-0.2, -0.2, 0.2, 0.2]])
    g = boxed.belief_grid
    assert g[:, 9, 9].sum() == 0.0 and g[:, 0, 0].sum() > 0.0
    assert boxed.belief.sum() == pytest.approx(1.0)
    with pytest.raises(ValueError):
        loc.belief[0] = 1.0                                     # read-only view


def test_predict_shifts_each_heading_layer():
    loc = MarkovLocalizer(loc_params(trans_noise=0.0, trans_noise_min=0.0, rot_noise=0.0,
                                     rot_noise_min_deg=0.0), LANDMARKS, FLOOR)
    p = np.zeros(loc.shape)
    p[0, 10, 10] = 0.5                # heading 0 deg: forward = +x
    p[3, 10, 10] = 0.5                # heading 90 deg: forward = +y
    loc.set_belief(p)
    loc.predict(0.15, 0.0, 0.0)       # one cell forward
    g = loc.belief_grid
    assert g[0, 11, 10] == pytest.approx(0.5) and g[3, 10, 11] == pytest.approx(0.5)
    loc.predict(0.075, 0.0, 0.0)      # half a cell: split between two cells
    assert loc.belief_grid[0, 11, 10] == pytest.approx(0.25)
    assert loc.belief_grid[0, 12, 10] == pytest.approx(0.25)
    loc.predict(0.0, 0.0, math.radians(30.0))   # one heading bin counter-clockwise
    assert loc.belief_grid[1].sum() == pytest.approx(0.5)
    assert loc.belief_grid[4].sum() == pytest.approx(0.5)
    loc.predict(0.0, 0.0, -math.radians(60.0))  # periodic: bin 1 -> bin 11
    assert loc.belief_grid[11].sum() == pytest.approx(0.5)


def test_predict_noise_conserves_mass_and_drops_impossible_poses():
    loc = MarkovLocalizer(loc_params(), LANDMARKS, FLOOR)
    p = np.zeros(loc.shape)
    p[0, 10, 10] = 0.5
    p[0, 19, 5] = 0.5                 # at the east wall, facing it
    loc.set_belief(p)
    loc.predict(0.3, 0.0, 0.0)        # the pose at the wall cannot move 2 cells east
    g = loc.belief_grid
    assert g.sum() == pytest.approx(1.0)
    assert g[:, 12, 10].max() == g.max()
    assert g[:, 15:, :8].sum() < 1e-6


def test_predict_wheels_equals_predict_of_integrated_arc():
    a = MarkovLocalizer(loc_params(), LANDMARKS, FLOOR)
    b = MarkovLocalizer(loc_params(), LANDMARKS, FLOOR)
    a.update(exact_bearings(0.2, 0.1, 0.5))
    b.update(exact_bearings(0.2, 0.1, 0.5))
    wb, dt = 0.16, 0.05
    wheels = np.tile([0.1, 0.2], (10, 1))
    v, omega = 0.15, 0.1 / wb
    a.predict_wheels(wheels, dt, wb)
    b.predict(*arc(v, omega, 10 * dt))
    assert np.allclose(a.belief, b.belief, atol=1e-12)


@pytest.mark.parametrize('seed,start', [
    (0, (0.3, -0.4, 100.0)), (1, (-1.0, 1.0, -45.0)), (2, (1.1, -0.9, 200.0)),
    (3, (-0.2, 0.6, 10.0)),
])
def test_localization_concentrates_on_true_pose(seed, start):
    """From a uniform prior, a robot driving in a plain square arena with 4 landmarks is
    localised within 1-2 cells and 1 heading bin after a few predict+update cycles."""
    rng = np.random.default_rng(seed)
    loc = MarkovLocalizer(loc_params(), LANDMARKS, FLOOR)
    x, y, th = start[0], start[1], math.radians(start[2])
    errors = []
    for _ in range(5):
        z = exact_bearings(x, y, th) + rng.normal(0.0, math.radians(1.0), 4)
        loc.update(z)
        k, i, j = np.unravel_index(int(np.argmax(loc.belief)), loc.shape)
        kt, it, jt = loc.cell_of(x, y, th)
        dk = abs(int(k) - kt) % loc.n_headings
        errors.append((max(abs(int(i) - it), abs(int(j) - jt)), min(dk, loc.n_headings - dk)))
        # drive: a random smooth arc that stays inside the floor
        v, omega = 0.15, rng.uniform(-0.6, 0.6)
        dx, dy, dth = arc(v, omega, 1.2)
        nx = x + dx * math.cos(th) - dy * math.sin(th)
        ny = y + dx * math.sin(th) + dy * math.cos(th)
        if abs(nx) > 1.3 or abs(ny) > 1.3:                       # turn in place instead
            dx, dy, dth = 0.0, 0.0, math.radians(90.0)
            nx, ny = x, y
        x, y, th = nx, ny, th + dth
        loc.predict(dx, dy, dth)
    # every MAP cell from the third reading on is within 2 cells and 1 heading bin of the truth
    for cells, bins in errors[2:]:
        assert cells <= 2 and bins <= 1, errors
    assert loc.belief.max() > 0.02               # concentrated (uniform: 1/4800 = 2e-4)


@pytest.mark.parametrize('floor', [0.0, 1e-6])
def test_update_recovers_from_a_wrong_confident_belief(floor):
    loc = MarkovLocalizer(loc_params(floor=floor), LANDMARKS, FLOOR)
    p = np.zeros(loc.shape)
    p[6, 2, 2] = 1.0                              # certain, and wrong (kidnapped robot)
    loc.set_belief(p)
    truth = (0.66, 0.52, 0.1)
    loc.update(exact_bearings(*truth))
    assert np.all(np.isfinite(loc.belief)) and loc.belief.sum() == pytest.approx(1.0)
    assert loc.cell_of(*truth) == np.unravel_index(int(np.argmax(loc.belief)), loc.shape)


def test_update_ignores_unseen_landmarks():
    loc = MarkovLocalizer(loc_params(), LANDMARKS, FLOOR)
    loc.update(np.full(4, np.nan))
    assert np.ptp(loc.belief) == 0.0
    z = exact_bearings(0.1, 0.2, 1.0)
    z[[0, 2]] = np.nan
    one = MarkovLocalizer(loc_params(), LANDMARKS[[1, 3]], FLOOR)
    loc.update(z)
    one.update(z[[1, 3]])
    assert np.allclose(loc.belief, one.belief)
    with pytest.raises(ValueError):
        loc.update(np.zeros(3))


# ------------------------------------------------------------------------------ selection (3)

def test_selection_probs_hand_computed():
    p = selection_probs([1.0, 0.5, 0.0], [0.9, 0.8, 0.5], beta=2.0)
    # (3): exponents beta (1 - gamma_i) V_i = 0.2, 0.2, 0
    e = np.exp([0.2, 0.2, 0.0])
    assert p == pytest.approx(e / e.sum(), rel=1e-14)


def test_selection_limits_and_availability():
    v, g = np.array([0.3, 0.9, 0.5]), np.array([0.9, 0.9, 0.9])
    assert selection_probs(v, g, beta=0.0) == pytest.approx([1 / 3] * 3)
    assert selection_probs(v, g, beta=1e5) == pytest.approx([0.0, 1.0, 0.0])
    p = selection_probs(v, g, beta=1.0, available=[True, False, True])
    assert p[1] == 0.0 and p.sum() == pytest.approx(1.0)
    big = selection_probs([1e6, 2e6], [0.0, 0.0], beta=1e3)             # no overflow
    assert big == pytest.approx([0.0, 1.0])
    with pytest.raises(ValueError, match='no module'):
        selection_probs(v, g, 1.0, available=[False] * 3)
    with pytest.raises(ValueError, match='non-finite'):
        selection_probs([np.nan, 0.0, 0.0], g, 1.0)


def arbiter_params(selection: str) -> ArbiterParams:
    return ArbiterParams(selection=selection, stale_periods=1.5, start_timeout=0.5,
                         rule='paper', scale_min=0.1, explore=0.0, bonus=0.0)


def test_arbiter_frequencies_and_modes():
    values, gammas = [0.0, 1.0, 2.0], [0.5, 0.5, 0.5]
    p = selection_probs(values, gammas, 2.0)
    arb = Arbiter(arbiter_params('episode'), 2.0, np.random.default_rng(0))
    counts = np.bincount([arb.begin_episode(values, gammas) for _ in range(6000)], minlength=3)
    assert counts / 6000 == pytest.approx(p, abs=0.02)
    # episode mode keeps the module...
    first = arb.begin_episode(values, gammas)
    assert all(arb.on_decision(values, gammas) == first for _ in range(50))
    # ...unless it stops proposing
    avail = np.ones(3, bool)
    avail[first] = False
    assert arb.on_decision(values, gammas, avail) != first
    # decision mode redraws (same draws as begin_episode for the same rng)
    a = Arbiter(arbiter_params('decision'), 2.0, np.random.default_rng(5))
    b = Arbiter(arbiter_params('decision'), 2.0, np.random.default_rng(5))
    seq_a = [a.on_decision(values, gammas) for _ in range(100)]
    seq_b = [b.begin_episode(values, gammas) for _ in range(100)]
    assert seq_a == seq_b and len(set(seq_a)) == 3
