"""Tests of the native vector env cr_sim.gym_env.CRNavVectorEnv and the fast action sampling."""

from __future__ import annotations

from cr_sim.gym_env import CRNavEnv, CRNavVectorEnv
from gymnasium import spaces
from gymnasium.vector import SyncVectorEnv
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits


def test_vector_env_equals_sync_vector_env_of_single_envs():
    n = 3
    fast = CRNavVectorEnv(n, start='random')
    ref = SyncVectorEnv([lambda: CRNavEnv(start='random') for _ in range(n)])
    assert fast.action_space == ref.action_space
    assert fast.observation_space == ref.observation_space
    obs_f, _ = fast.reset(seed=7)
    obs_r, _ = ref.reset(seed=7)
    np.testing.assert_array_equal(obs_f, obs_r)
    rng = np.random.default_rng(0)
    ends = 0
    for k in range(1500):                       # past the 1200-step time limit: autoresets
        a = rng.uniform(-1.3, 1.3, size=(n, 2)).astype(np.float32)
        if k % 50 < 10:
            a[:, :] = 1.3                       # drive into walls: contacts, collisions
        got, want = fast.step(a), ref.step(a)
        for x, y in zip(got[:4], want[:4]):
            np.testing.assert_array_equal(x, y)
        ends += int(np.sum(got[2] | got[3]))
    assert ends >= n                            # every robot ended an episode at least once
    np.testing.assert_array_equal(fast.poses, [e.sim.pose for e in ref.envs])
    fast.close()
    ref.close()


def test_vector_env_rejects_bad_actions_and_sizes():
    env = CRNavVectorEnv(2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match='shape'):
        env.step(np.zeros((3, 2)))
    with pytest.raises(ValueError, match='num_envs'):
        CRNavVectorEnv(0)
    with pytest.raises(ValueError, match='seeds'):
        env.reset(seed=[1, 2, 3])


def test_action_sampling_draws_what_box_sample_draws():
    env = CRNavEnv()
    box = spaces.Box(env.action_space.low, env.action_space.high, dtype=np.float32)
    env.action_space.seed(11)
    box.seed(11)
    for _ in range(20000):
        a, b = env.action_space.sample(), box.sample()
        assert a.dtype == b.dtype == np.float32
        np.testing.assert_array_equal(a, b)
