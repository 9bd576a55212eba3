"""Every compiled kernel of the fast paths equals its reference implementation bit for bit on
random inputs (hypothesis): the gym observation layout; and the agent stream's draws made a
block of ticks at a time equal those made tick by tick; the episode times of a cut computed on
an array equal those computed one by one."""

from __future__ import annotations

import math

from clis_base.agent_stream import AgentStream
from clis_base.instants import DecisionClock
from clis_learner.core.memory import episode_time, episode_times
from cr_sim.gym_env import _layout, _layout_into
from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

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


class _PerTickStream(AgentStream):
    """The agent stream drawn one tick at a time (the reference of the blocks)."""

    def instant(self, k: int) -> None:
        if k < self.pos:
            return
        for j in range(self.pos, k + 1):
            self._draw(j)
        self.pos = k + 1

    def end_episode(self, k_end: int) -> None:
        if self.pos > k_end:
            self.rng.bit_generator.state = self.start_state
            self.pos = 0
        for j in range(self.pos, k_end):
            self._draw(j)
        self.pos = 0
        self.start_state = self.rng.bit_generator.state


@PROPERTY
@given(st.sampled_from([(0.25, 0.5, 1.2), (1.2,), (0.5,), (0.25, 0.5, 1.2, 0.75),
                        (1.2, 1.2, 1.2)]),
       st.sampled_from(['episode', 'decision']), st.integers(0, 2**32 - 1),
       st.lists(st.tuples(st.integers(0, 1500), st.lists(st.integers(1, 300), max_size=40)),
                min_size=1, max_size=3))
def test_agent_stream_blocks_equal_the_draws_tick_by_tick(periods, selection, seed, episodes):
    clock = DecisionClock(list(periods), 0.05)
    fast = AgentStream(np.random.default_rng(seed), len(periods), selection, clock)
    ref = _PerTickStream(np.random.default_rng(seed), len(periods), selection, clock)
    for k_end, steps in episodes:
        fast.begin_episode()
        ref.begin_episode()
        k = 0
        for step in [0, *steps]:                   # instants at, before and past the end
            k += step
            fast.instant(k)
            ref.instant(k)
            for i in clock.due_at(k):
                assert fast.normals[i].tolist() == ref.normals[i].tolist()
            assert fast.uniform == ref.uniform or math.isnan(fast.uniform + ref.uniform)
        fast.end_episode(k_end)
        ref.end_episode(k_end)
        assert fast.state() == ref.state()
        assert fast.rng.bit_generator.state == ref.rng.bit_generator.state


@PROPERTY
@given(st.lists(st.one_of(st.integers(0, 2000).map(lambda k: k * 0.05),
                          st.floats(0.0, 100.0, allow_nan=False),
                          st.integers(0, 2000).map(lambda k: k * 0.05 + 0.025)),
                min_size=0, max_size=60),
       st.sampled_from([0.0, 12.35, 1e3 + 0.05]), st.sampled_from([0.05, 0.0, 0.1]))
def test_episode_times_on_an_array_equal_episode_time(offsets, t0, dt):
    ts = [t0 + o for o in offsets]
    want = [episode_time(t, t0, dt) for t in ts]
    got = episode_times(ts, t0, dt)
    assert [float(v).hex() for v in got] == [float(v).hex() for v in want]
