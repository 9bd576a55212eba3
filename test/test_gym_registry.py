"""Gymnasium registration of ``CRNav-v0`` (docs/gym.md): ``gymnasium.make`` and
``gymnasium.make_vec`` in a fresh interpreter with no import of cr_sim first, as a
Stable-Baselines3 or CleanRL script calls them; each registration path on its own."""

from __future__ import annotations

import json
from pathlib import Path
import subprocess
import sys
import sysconfig
import textwrap

import pytest

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

REPO = Path(__file__).resolve().parent.parent
PLUGIN = REPO / 'src' / 'cr_sim' / 'cr_sim' / 'gym_plugin.py'


def run_fresh(code: str) -> dict:
    """Run ``code`` in a new interpreter (this one's environment); its last stdout line is
    JSON."""
    out = subprocess.run([sys.executable, '-c', textwrap.dedent(code)], capture_output=True,
                         text=True, timeout=120, cwd=REPO / 'test')
    assert out.returncode == 0, out.stdout + out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_venv_start_up_hook_is_the_current_plugin():
    hook = Path(sysconfig.get_paths()['purelib']) / '_cr_sim_gym_hook.py'
    pth = hook.with_name('cr_sim_gym.pth')
    if not (hook.is_file() and pth.is_file()):
        pytest.fail(f'no {hook.name} / {pth.name} in {hook.parent}: run make setup')
    assert hook.read_bytes() == PLUGIN.read_bytes(), f'{hook} is stale: run make setup'
    assert pth.read_text().strip() == 'import _cr_sim_gym_hook; _cr_sim_gym_hook.install_hook()'


def test_sb3_style_loop_through_gymnasium_make_in_a_fresh_interpreter():
    got = run_fresh("""
        import json, sys
        import gymnasium as gym
        import numpy as np

        before = sorted(m for m in sys.modules if m.startswith('cr_sim'))
        spec = gym.spec('CRNav-v0')

        def episode(seed):
            # what SB3's collect_rollouts / evaluate_policy do with one env
            env = gym.make('CRNav-v0', max_episode_steps=200)
            obs, info = env.reset(seed=seed)
            env.action_space.seed(seed)
            steps, ret, digest, done = 0, 0.0, 0.0, False
            while not done:
                obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
                assert env.observation_space.contains(obs), obs
                steps, ret = steps + 1, ret + reward
                digest += float(np.sum(obs, dtype=np.float64)) * steps
                done = terminated or truncated
            env.close()
            return dict(steps=steps, t=info['t'], terminated=bool(terminated),
                        truncated=bool(truncated), ret=ret, digest=digest,
                        type=type(env.unwrapped).__name__)

        print(json.dumps(dict(before=before, entry_point=spec.entry_point,
                              vector_entry_point=spec.vector_entry_point,
                              a=episode(7), b=episode(7), c=episode(8))))
    """)
    assert got['before'] == []                  # nothing of cr_sim imported before make
    assert got['entry_point'] == 'cr_sim.gym_env:CRNavEnv'
    assert got['vector_entry_point'] == 'cr_sim.gym_env:CRNavVectorEnv'
    a, b, c = got['a'], got['b'], got['c']
    assert a['type'] == 'CRNavEnv'
    # the episode ends by the goal or at the 200 steps of TimeLimit, 0.05 s of sim time each
    assert (a['truncated'] and a['steps'] == 200) or (a['terminated'] and a['steps'] < 200)
    assert a['t'] == pytest.approx(0.05 * a['steps'], abs=1e-9)
    assert a == b                                # reset(seed=) reproduces the episode
    assert c['digest'] != a['digest']


def test_make_vec_vector_entry_point_equals_sync_vectorization():
    got = run_fresh("""
        import json
        import gymnasium as gym
        import numpy as np
        from cr_sim.core.sim import load_sim_params

        params = load_sim_params(overrides={'episode.time_limit': 2.0})   # 40 steps
        native = gym.make_vec('CRNav-v0', num_envs=3, params=params)
        sync = gym.make_vec('CRNav-v0', num_envs=3, vectorization_mode='sync', params=params)
        o1, _ = native.reset(seed=11)
        o2, _ = sync.reset(seed=11)
        assert np.array_equal(o1, o2)
        rng = np.random.default_rng(0)
        ends = 0
        for _ in range(300):
            a = rng.uniform(-1.3, 1.3, (3, 2)).astype(np.float32)
            r1, r2 = native.step(a), sync.step(a)
            for x, y in zip(r1[:4], r2[:4]):
                assert np.array_equal(x, y)
            ends += int(np.sum(r1[2] | r1[3]))
        print(json.dumps(dict(native=type(native.unwrapped).__name__,
                              sync=type(sync.unwrapped).__name__,
                              shape=list(o1.shape), ends=ends,
                              spec=native.unwrapped.spec.kwargs['vectorization_mode'])))
    """)
    assert got['native'] == 'CRNavVectorEnv' and got['sync'] == 'SyncVectorEnv'
    assert got['shape'] == [3, 17] and got['spec'] == 'vector_entry_point'
    # 3 robots, episodes of <= 40 steps and one autoreset step each, over 300 steps
    assert got['ends'] >= 3 * (300 // 41)


def test_cleanrl_style_vector_env_records_episode_statistics():
    got = run_fresh("""
        import json
        import gymnasium as gym
        import numpy as np

        def make_env(seed):
            def thunk():
                env = gym.make('CRNav-v0', max_episode_steps=50)
                env = gym.wrappers.RecordEpisodeStatistics(env)
                env.action_space.seed(seed)
                return env
            return thunk

        envs = gym.vector.SyncVectorEnv([make_env(i) for i in range(2)])
        obs, _ = envs.reset(seed=1)
        lengths = []
        for _ in range(120):
            obs, reward, terminated, truncated, infos = envs.step(envs.action_space.sample())
            if 'episode' in infos:
                lengths += [int(n) for n, done in zip(infos['episode']['l'], infos['_episode'])
                            if done]
        print(json.dumps(dict(obs=list(obs.shape), lengths=lengths)))
    """)
    assert got['obs'] == [2, 17]
    # each robot ends an episode by step 50 and (after its autoreset step) again by step 101
    assert len(got['lengths']) >= 4 and all(1 <= n <= 50 for n in got['lengths'])


def test_each_registration_path_on_its_own():
    got = run_fresh("""
        import json, sys
        # without the venv's start-up hook: Gymnasium 1.x's own ways
        sys.meta_path[:] = [f for f in sys.meta_path if type(f).__name__ != '_GymnasiumHook']
        import gymnasium as gym
        out = dict(bare='CRNav-v0' in gym.registry)
        env = gym.make('cr_sim.gym_env:CRNav-v0')          # 'module:id' imports the module
        out['module_id'] = type(env.unwrapped).__name__
        del gym.registry['CRNav-v0']
        import importlib
        importlib.reload(sys.modules['cr_sim.gym_env'])     # registration at import
        out['import'] = 'CRNav-v0' in gym.registry
        del gym.registry['CRNav-v0']
        from importlib.metadata import entry_points         # gymnasium 0.26-0.29's plugins
        eps = [ep for ep in entry_points(group='gymnasium.envs') if ep.name == '__root__'
               and ep.value.startswith('cr_sim.')]
        for ep in eps:
            ep.load()()
        out['entry_point'] = [ep.value for ep in eps]
        out['plugin'] = 'CRNav-v0' in gym.registry
        print(json.dumps(out))
    """)
    assert got == {'bare': False, 'module_id': 'CRNavEnv', 'import': True,
                   'entry_point': ['cr_sim.gym_plugin:register_envs'], 'plugin': True}
