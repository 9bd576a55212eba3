"""CLIS cores: cost of one place-module localization update, of the learner per episode, and
of headless episodes per condition (CPU time of this process: episodes per second on one
core), with where the time of an Async episode goes (a profile, which inflates the Python
calls against the compiled kernels: their share without a profiler, and the bound it sets on
the runner's speed, is ``bench/bench_floor.py``'s).

    python bench/bench_learning.py [--episodes 30] [--json FILE]

Episodes start where the wander policy leaves the robot (the reproduction's protocol) with
untrained modules: most run the full 60 s, so these are the slow episodes of early learning.
"""

from __future__ import annotations

import argparse
import cProfile
import json
from pathlib import Path
import pstats
import sys
import time

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
for pkg in ('clis_base', 'cr_sim', 'clis_modules', 'clis_learner', 'clis_app'):
    sys.path.insert(0, str(ROOT / 'src' / pkg))

from clis_app.experiments.runner import Agent, run_episode  # noqa: E402
from clis_learner.core.config import load_clis_params  # noqa: E402
from cr_sim.core.arena import load_arena  # noqa: E402
from cr_sim.core.sim import Simulator, load_sim_params  # noqa: E402
from cr_sim.core.starts import draw_start  # noqa: E402

CONDITIONS = ('innate', 'view', 'place', 'sync', 'async')


def setup(condition: str, seed: int = 0):
    sim_params = load_sim_params()
    arena = load_arena(None, sim_params.robot.radius)
    sim = Simulator(arena, sim_params, np.random.default_rng([seed, 0]))
    agent = Agent(load_clis_params(), condition, arena, np.random.default_rng([seed, 2]),
                  sim_params.robot.wheel_base)
    return sim, agent, arena, np.random.default_rng([seed, 1])


def bench_localization(repeats: int = 2000) -> float:
    """ms per place decision: motion update (predict) + landmark update."""
    sim, agent, arena, _ = setup('place')
    loc = agent.place.localizer
    obs = sim.reset('A')
    loc.predict(0.1, 0.0, 0.05)
    loc.update(obs.landmark_bearings)
    t0 = time.process_time()
    for _ in range(repeats):
        loc.predict(0.1, 0.0, 0.05)
        loc.update(obs.landmark_bearings)
    return 1e3 * (time.process_time() - t0) / repeats


def bench_episodes(condition: str, episodes: int) -> tuple[float, float]:
    """(ms per episode, ms of learner per episode), CPU time of this process."""
    sim, agent, arena, start_rng = setup(condition)
    run_episode(sim, agent, 'A', None)      # warm-up: the compiled kernels are loaded once
    learn_s = 0.0
    original = agent.learner.learn

    def timed(memory, update=True):
        nonlocal learn_s
        t = time.process_time()
        out = original(memory, update)
        learn_s += time.process_time() - t
        return out
    agent.learner.learn = timed
    t0 = time.process_time()
    for _ in range(episodes):
        start, heading = draw_start('wander', arena, start_rng)
        run_episode(sim, agent, start, heading)
    total = time.process_time() - t0
    return 1e3 * total / episodes, 1e3 * learn_s / episodes


def breakdown(episodes: int = 10, condition: str = 'async') -> dict[str, float]:
    """Share of an episode's time in each part (cProfile, cumulative)."""
    sim, agent, arena, start_rng = setup(condition)
    run_episode(sim, agent, 'A', None)      # warm-up
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(episodes):
        start, heading = draw_start('wander', arena, start_rng)
        run_episode(sim, agent, start, heading)
    prof.disable()
    stats = pstats.Stats(prof).stats
    total = max(v[3] for v in stats.values())
    parts = {'simulator step (physics, collisions)': ('sim.py', '_advance'),
             'simulator sensors (IR, camera)': ('sim.py', '_sensors'),
             'decisions (features, policy, value; with localization)': ('decider.py', 'decide'),
             "the place belief at the other modules' instants (for (6))": ('place.py', 'peek'),
             'localization motion update (compiled kernel)': ('localization_fused.py',
                                                              '_predict_kernel'),
             'localization sensor update (compiled kernel)': ('localization_fused.py',
                                                              '_update_kernel'),
             'learner (resampling, (7)-(9))': ('learner.py', 'learn'),
             'wander between episodes': ('sim.py', '_run_wander')}
    out = {}
    for label, (file, func) in parts.items():
        out[label] = sum(v[3] for k, v in stats.items()
                         if k[0].endswith(file) and k[2] == func) / total
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--episodes', type=int, default=30)
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    loc_ms = bench_localization()
    print(f'place localization update (predict + landmarks, 4800 cells): {loc_ms:.3f} ms '
          f'(goal <= 1 ms; budget 1200 ms)')
    rows = [{'measure': 'place module: one localization update (predict + landmarks)',
             'value': f'{loc_ms:.2f} ms', 'goal': '<= 1 ms'}]
    per = {}
    for condition in CONDITIONS:
        ep_ms, learn_ms = bench_episodes(condition, args.episodes)
        per[condition] = {'ms_per_episode': ep_ms, 'learner_ms_per_episode': learn_ms}
        print(f'{condition:7s} {ep_ms:7.1f} ms/episode = {1e3 / ep_ms:5.0f} episodes/s  '
              f'(learner {learn_ms:5.2f} ms)')
        rows.append({'measure': f'{condition}: headless episode, untrained: CPU time = '
                                'episodes/s on one core (learner part)',
                     'value': f'{ep_ms:.1f} ms = {1e3 / ep_ms:.0f}/s ({learn_ms:.1f} ms)',
                     'goal': ''})
    total_s = sum(v['ms_per_episode'] for v in per.values()) * 1000 * 10 / 1e3 / 2
    print(f'upper bound of the full reproduction (5 x 10 x 1000, 2 workers): '
          f'{total_s / 60:.0f} min (episodes get shorter as learning succeeds)')
    shares = breakdown()
    for label, share in shares.items():
        print(f'  {100 * share:5.1f}%  {label}')
    rows.append({'measure': 'Async episode time: ' + ', '.join(
        f'{label} {100 * s:.0f}%' for label, s in shares.items()), 'value': '', 'goal': ''})
    # (the kernels' share without a profiler, and what it bounds: bench/bench_floor.py)
    if args.json:
        Path(args.json).write_text(json.dumps({
            'localization_ms': loc_ms, 'episodes': per, 'async_breakdown': shares,
            'reproduction_upper_bound_min': total_s / 60, 'rows': rows}, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
