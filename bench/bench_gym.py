#!/usr/bin/env python3
"""Gymnasium envs with random actions: CRNavEnv steps per second (one core), and robot-steps per
second of the vector envs at 1, 16 and 256 robots (the native CRNavVectorEnv and gymnasium's
SyncVectorEnv of CRNavEnv); the wrapper's cost: CRNavEnv.step against the simulator core's own
``step()`` + ``observe()`` on the same actions in the same process (their ratio, goal >= 0.8).

A new user's loop: ``a = env.action_space.sample(); env.step(a)``, reset when an episode ends
(start 'random'), the full sensor model of ``config/sim.yaml``; the vector envs autoreset. The
CPU time of the process is measured (``time.process_time``: the machine's other load counts
less), the best of ``--repeats`` reported.

    python bench/bench_gym.py [--seconds 1] [--repeats 2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / 'src' / 'cr_sim'))
sys.path.insert(0, str(ROOT / 'src' / 'clis_base'))

from cr_sim.gym_env import CRNavEnv, CRNavVectorEnv  # noqa: E402
from gymnasium.vector import SyncVectorEnv  # noqa: E402

GOAL = 25_000
RATIO_GOAL = 0.8
ROBOTS = (1, 16, 256)


def wrapper_ratio(n: int, repeats: int) -> tuple[float, float, float]:
    """CPU time per step of ``CRNavEnv.step`` and of the core's ``Simulator.step`` +
    ``Simulator.observe`` on the same ``n`` sampled actions from the same seed (best of
    ``repeats``, taken alternately), and their ratio core / env (1: the wrapper costs
    nothing)."""
    env = CRNavEnv(start='random')
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(n)]

    def wrapped() -> float:
        env.reset(seed=0)
        t0 = time.process_time()
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
        return time.process_time() - t0

    def core() -> float:
        env.reset(seed=0)
        sim = env.sim
        t0 = time.process_time()
        for a in actions:
            res = sim.step(a)
            sim.observe()
            if res.done:
                sim.reset(start='random')
        return time.process_time() - t0

    t_env = t_core = float('inf')
    for _ in range(repeats):
        t_env = min(t_env, wrapped())
        t_core = min(t_core, core())
    return t_env / n, t_core / n, t_core / t_env


def single(seconds: float, sample: bool) -> float:
    """Steps per second of CRNavEnv (random actions from ``action_space.sample()``)."""
    env = CRNavEnv(start='random')
    env.reset(seed=0)
    env.action_space.seed(0)
    a = env.action_space.sample()
    steps, t0 = 0, time.process_time()
    while time.process_time() - t0 < seconds:
        for _ in range(1000):
            if sample:
                a = env.action_space.sample()
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
        steps += 1000
    return steps / (time.process_time() - t0)


def vector(env, seconds: float) -> float:
    """Robot-steps per second of a vector env (random batched actions)."""
    env.reset(seed=0)
    env.action_space.seed(0)
    steps, t0 = 0, time.process_time()
    while time.process_time() - t0 < seconds:
        for _ in range(max(1, 2000 // env.num_envs)):
            env.step(env.action_space.sample())
            steps += env.num_envs
    rate = steps / (time.process_time() - t0)
    env.close()
    return rate


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seconds', type=float, default=1.0, help='CPU seconds per measurement')
    ap.add_argument('--repeats', type=int, default=2, help='repeats; the best is reported')
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    best = {}

    def measure(key: str, fn) -> float:
        best[key] = max(fn() for _ in range(args.repeats))
        return best[key]

    single(0.2, True)                                   # warm-up (compiled kernels loaded)
    rate = measure('env_sample', lambda: single(args.seconds, True))
    print(f'CRNavEnv, action_space.sample() + step: {rate:,.0f} steps/s (goal >= {GOAL:,})')
    rate = measure('env_fixed', lambda: single(args.seconds, False))
    print(f'CRNavEnv, step only (one fixed action): {rate:,.0f} steps/s')
    t_env, t_core, ratio = wrapper_ratio(20_000, max(3, args.repeats))
    best['wrapper_ratio'] = ratio
    print(f'CRNavEnv.step {1e6 * t_env:.2f} us, core step() + observe() {1e6 * t_core:.2f} us '
          f'per step: ratio {ratio:.2f} (goal >= {RATIO_GOAL})')
    rows = [{'measure': 'CRNavEnv steps/s, random actions (action_space.sample() + step)',
             'value': f'{best["env_sample"]:,.0f}', 'goal': f'>= {GOAL:,}'},
            {'measure': 'CRNavEnv steps/s, step() alone', 'value': f'{best["env_fixed"]:,.0f}',
             'goal': ''},
            {'measure': "CRNavEnv.step vs the core's step() + observe(), same actions: ratio "
                        'core / env', 'value': f'{ratio:.2f}', 'goal': f'>= {RATIO_GOAL}'}]
    for n in ROBOTS:
        fast = measure(f'native_{n}', lambda n=n: vector(CRNavVectorEnv(n), args.seconds))
        sync = measure(f'sync_{n}', lambda n=n: vector(
            SyncVectorEnv([lambda: CRNavEnv(start='random') for _ in range(n)]),
            args.seconds))
        print(f'{n:4d} robots: CRNavVectorEnv {fast:,.0f}, SyncVectorEnv {sync:,.0f} '
              'robot-steps/s')
        rows.append({'measure': f'vector env robot-steps/s, {n} robots: CRNavVectorEnv '
                                '(SyncVectorEnv of CRNavEnv)',
                     'value': f'{fast:,.0f} ({sync:,.0f})', 'goal': ''})
    if args.json:
        Path(args.json).write_text(json.dumps({'results': best, 'rows': rows}, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
