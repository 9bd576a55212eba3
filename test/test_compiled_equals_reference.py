"""Every compiled kernel of the fast paths equals its reference implementation bit for bit on
random inputs (hypothesis): the gym observation layout, and the runner's batched draws."""

from __future__ import annotations

import math

from cr_sim.gym_env import _layout, _layout_into
from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np

PROPERTY = settings(max_examples=200, deadline=None)

readings = st.floats(-1.0, 2.0, allow_nan=False, width=64)
bearings = st.one_of(st.just(math.nan), st.floats(-4.0, 4.0, allow_nan=False, width=64))


@PROPERTY
@given(st.lists(readings, min_size=1, max_size=9), st.lists(bearings, min_size=1, max_size=6))
def test_gym_layout_kernel_equals_the_numpy_layout(ir, bear):
    ir, bear = np.array(ir), np.array(bear)
    n = len(ir) + 2 * len(bear)
    pi = np.float32(math.pi)
    low = np.concatenate([np.zeros(len(ir)), np.tile([0.0, -pi], len(bear))]).astype(np.float32)
    high = np.concatenate([np.full(len(ir), 1.5), np.tile([1.0, pi], len(bear))]
                          ).astype(np.float32)
    want, got = np.empty(n, np.float32), np.empty(n, np.float32)
    _layout(ir, bear, want, low, high)
    _layout_into(ir, bear, got, low, high)
    # every value exactly; the sign of a zero is compared by value only: numpy's own clip
    # gives -0.0 or +0.0 for a -0.0 depending on whether its SIMD loop or its scalar tail
    # handles the element (the array's length)
    assert np.array_equal(want, got, equal_nan=True)
    nonzero = want != 0.0
    assert want[nonzero].view(np.uint32).tolist() == got[nonzero].view(np.uint32).tolist()
