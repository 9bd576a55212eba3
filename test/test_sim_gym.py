"""Tests of the Gymnasium wrapper cr_sim.gym_env.CRNavEnv."""

from __future__ import annotations

import math
import warnings

from cr_sim.core.sim import load_sim_params
from cr_sim.gym_env import CRNavEnv
from gymnasium.utils.env_checker import check_env
import numpy as np
import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits


@pytest.fixture
def env():
    e = CRNavEnv()
    yield e
    e.close()


def test_check_env_passes(env):
    with warnings.catch_warnings():
        # the paper's action is wheel velocities in m/s, so the box is +-1.3, not +-1
        warnings.filterwarnings('ignore', message='.*symmetric and normalized space.*')
        warnings.filterwarnings('ignore', message='.*alternative render modes.*')
        check_env(env.unwrapped, skip_render_check=True)


def test_spaces(env):
    assert env.action_space.shape == (2,) and env.action_space.dtype == np.float32
    assert env.action_space.low.tolist() == pytest.approx([-1.3, -1.3])
    assert env.action_space.high.tolist() == pytest.approx([1.3, 1.3])
    assert env.observation_space.shape == (7 + 2 + 2 * 4,)
    assert env.observation_space.dtype == np.float32


def test_observation_layout_and_flags():
    p = load_sim_params(overrides={'sensors.ir_noise_sigma': 0.0,
                                   'sensors.bearing_noise_deg': 0.0})
    env = CRNavEnv(params=p)
    obs, info = env.reset(seed=0, options={'start': 'E'})
    assert obs in env.observation_space
    assert obs[7] == 0.0 and obs[8] == 0.0                  # E: destination hidden -> (0, 0)
    assert info['pose'] == pytest.approx([1.2, -0.7, math.radians(150)])
    obs, _ = env.reset(options={'start': 'A'})
    assert obs[7] == 1.0 and abs(obs[8]) < 0.05             # A: seen, straight ahead
    assert np.all(obs[9::2] == 1.0)                          # all landmarks seen from A
    sim_obs = env.sim.observe()
    assert obs[:7] == pytest.approx(sim_obs.ir, abs=1e-6)
    assert obs[10::2] == pytest.approx(sim_obs.landmark_bearings, abs=1e-6)
    # drive straight from near the destination: terminated with +1
    obs, _ = env.reset(options={'start': (0.0, -0.4, math.pi / 2)})
    total, terminated, truncated = 0.0, False, False
    for _ in range(30):
        obs, r, terminated, truncated, info = env.step(np.array([0.5, 0.5], dtype=np.float32))
        total += r
        if terminated or truncated:
            break
    assert terminated and not truncated and total == 1.0
    # collision flag in info
    env.reset(options={'start': 'D'})
    hits = 0
    for _ in range(20):
        _, r, _, _, info = env.step(np.array([1.3, 1.3], dtype=np.float32))
        hits += info['collision']
        assert (r == -0.1) == info['collision']
    assert hits == 1
    with pytest.raises(ValueError, match='unknown reset options'):
        env.reset(options={'strat': 'A'})


def test_truncation_at_time_limit(env):
    env.reset(seed=3, options={'start': 'A'})
    for k in range(1200):
        _, r, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
        assert not terminated and r == 0.0
        assert truncated == (k == 1199)
    assert info['t'] == pytest.approx(60.0)


def test_seeding_reproducible(env):
    def run(seed):
        obs, _ = env.reset(seed=seed, options={'start': 'random'})
        rng = np.random.default_rng(seed)
        out = [obs]
        for _ in range(100):
            obs, *_ = env.step(rng.uniform(-1.3, 1.3, 2).astype(np.float32))
            out.append(obs)
        return np.array(out)
    assert np.array_equal(run(1), run(1))
    assert not np.array_equal(run(1), run(2))
