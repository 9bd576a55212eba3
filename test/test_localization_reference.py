"""The place module's Markov localization: its compiled updates (MarkovLocalizer, through
clis_modules.core.localization_fused) give the beliefs of the paper's updates as written in
numpy and scipy (clis_modules.core.localization_reference), bit for bit, on random beliefs,
odometry and bearings; the reference reads only the localizer's public names."""

from __future__ import annotations

import dataclasses
import functools
import math

from clis_modules.core import localization_reference as ref
from clis_modules.core.localization import MarkovLocalizer
from clis_modules.core.modules import arena_map, load_module_params
from clis_modules.core.plugin import Floor
from cr_sim.core.arena import load_arena
from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

PROPERTY = settings(max_examples=60, deadline=None)


@functools.cache
def _localizer(floor: float) -> MarkovLocalizer:
    lm, half, boxes = arena_map(load_arena())
    prm = dataclasses.replace(load_module_params().place.localization, floor=floor)
    return MarkovLocalizer(prm, lm, half, boxes)


def _belief(loc: MarkovLocalizer, seed: int, sharpness: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = rng.random(loc.shape) ** sharpness * loc.free
    return p / p.sum()


odometry = st.tuples(st.floats(-0.8, 0.8), st.floats(-0.3, 0.3), st.floats(-4.0, 4.0))
bearing = st.one_of(st.just(math.nan), st.floats(-math.pi, math.pi))


@PROPERTY
@given(st.sampled_from([1e-6, 0.0, 0.05]), st.integers(0, 2**32 - 1),
       st.sampled_from([1, 8, 40]), odometry,
       st.sampled_from([None, (0.0, 0.0, 0.0), (3.0, -2.0, 9.0)]))
def test_predict_is_the_reference(floor, seed, sharpness, odo, special):
    loc = _localizer(floor)
    dx, dy, dth = odo if special is None else special
    loc.set_belief(_belief(loc, seed, sharpness))
    p = loc.belief_grid.copy()                      # set_belief normalises again
    want = ref.predict(loc, p, dx, dy, dth)
    loc.predict(dx, dy, dth)
    assert loc.belief_grid.tobytes() == want.tobytes()


@PROPERTY
@given(st.sampled_from([1e-6, 0.0, 0.05]), st.integers(0, 2**32 - 1),
       st.sampled_from([1, 8, 40]), st.lists(bearing, min_size=4, max_size=4))
def test_update_is_the_reference(floor, seed, sharpness, z):
    loc = _localizer(floor)
    loc.set_belief(_belief(loc, seed, sharpness))
    p = loc.belief_grid.copy()
    want = ref.update(loc, p, z)
    loc.update(z)
    assert loc.belief_grid.tobytes() == want.tobytes()


def test_a_trajectory_is_the_reference():
    """Predict and update in turn, from the uniform belief, as the place module does."""
    loc = _localizer(1e-6)
    loc.reset()
    rng = np.random.default_rng(11)
    p = loc.belief_grid.copy()
    for _ in range(30):
        dx, dy, dth = rng.normal(0.0, [0.2, 0.05, 0.5])
        z = rng.uniform(-math.pi, math.pi, 4)
        z[rng.random(4) < 0.25] = np.nan
        p = ref.update(loc, ref.predict(loc, p, dx, dy, dth), z)
        loc.predict(dx, dy, dth)
        loc.update(z)
        assert loc.belief_grid.tobytes() == p.tobytes()
    assert p.max() > 10 * p.mean()            # the belief has concentrated


@PROPERTY
@given(st.integers(0, 2**32 - 1), st.floats(0.2, 3.5), st.floats(0.2, 3.5),
       st.sampled_from([0.15, 0.3, 0.6]), st.integers(1, 13), st.sampled_from([1, 8]),
       odometry, st.lists(bearing, min_size=4, max_size=4))
def test_any_rectangular_grid_is_the_reference(seed, width, height, cell, n_headings,
                                               sharpness, odo, z):
    """Floors of any size and grids of any resolution, down to one cell or one heading bin
    (blurs wider than the grid, shifts off it): the compiled updates are the reference's."""
    lm, _, _ = arena_map(load_arena())
    prm = dataclasses.replace(load_module_params().place.localization, cell_size=cell,
                              n_headings=n_headings)
    loc = MarkovLocalizer(prm, lm, Floor(-0.5 * width, -0.5 * height, 0.5 * width,
                                         0.5 * height))
    loc.set_belief(_belief(loc, seed, sharpness))
    p = loc.belief_grid.copy()
    moved = ref.predict(loc, p, *odo)
    loc.predict(*odo)
    assert loc.belief_grid.tobytes() == moved.tobytes()
    want = ref.update(loc, moved, z)
    loc.update(z)
    assert loc.belief_grid.tobytes() == want.tobytes()
