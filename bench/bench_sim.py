#!/usr/bin/env python3
"""Speed of the pure simulator core: step()+observe() and step() alone, one env, one core.

Random wheel commands (uniform in +-v_wheel_max, drawn in blocks outside the timed calls'
critical path), reset on done (start 'random'), the full sensor model of ``config/sim.yaml``.
Each measurement is repeated and the best repeat is reported (least disturbed by other load).

Usage::

    python bench/bench_sim.py [--seconds 2.0] [--repeats 3] [--json results.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
from pathlib import Path
import platform
import sys
import time

import numpy as np

_REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(_REPO / 'src' / 'cr_sim'))
sys.path.insert(0, str(_REPO / 'src' / 'clis_base'))

from cr_sim.core.arena import load_arena  # noqa: E402
from cr_sim.core.sim import Simulator, load_sim_params  # noqa: E402

_BLOCK = 4096


def _run(sim: Simulator, rng: np.random.Generator, seconds: float, observe: bool) -> dict:
    """Step (and observe) for about ``seconds``; return counts and rate."""
    vmax = sim.params.robot.v_wheel_max
    sim.reset('random')
    steps = resets = 0
    elapsed = 0.0
    while elapsed < seconds:
        actions = rng.uniform(-vmax, vmax, size=(_BLOCK, 2))
        t0 = time.perf_counter()
        for u in actions:
            res = sim.step(u)
            if observe:
                sim.observe()
            if res.done:
                sim.reset('random')
                resets += 1
        elapsed += time.perf_counter() - t0
        steps += _BLOCK
    return {'steps': steps, 'resets': resets, 'seconds': elapsed, 'per_second': steps / elapsed,
            'us_per_step': 1e6 * elapsed / steps}


def machine_info() -> dict:
    """Platform, CPU count, Python and numpy versions, date."""
    return {
        'platform': platform.platform(),
        'machine': platform.machine(),
        'processor': platform.processor() or 'unknown',
        'cpu_count': os.cpu_count(),
        'python': sys.version.split()[0],
        'numpy': np.__version__,
        'date': datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print a table, optionally write JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=2.0, help='timed seconds per repeat')
    ap.add_argument('--repeats', type=int, default=3, help='repeats; the best one is reported')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--json', metavar='FILE', help='write the results as JSON')
    args = ap.parse_args(argv)

    params = load_sim_params()
    arena = load_arena(robot_radius=params.robot.radius)
    rng = np.random.default_rng(args.seed)
    sim = Simulator(arena, params, rng)
    _run(sim, rng, 0.2, True)   # warm-up

    results = {}
    for name, observe in (('step+observe', True), ('step', False)):
        runs = [_run(sim, rng, args.seconds, observe) for _ in range(args.repeats)]
        best = max(runs, key=lambda r: r['per_second'])
        best['repeats_per_second'] = [round(r['per_second']) for r in runs]
        results[name] = best

    info = machine_info()
    print(f'cr_sim core benchmark  ({info["platform"]}, {info["cpu_count"]} CPUs, '
          f'Python {info["python"]}, numpy {info["numpy"]})')
    print(f'{"measure":<14} {"per second":>12} {"us/step":>9} {"steps":>9} {"resets":>7}')
    for name, r in results.items():
        print(f'{name:<14} {r["per_second"]:>12,.0f} {r["us_per_step"]:>9.2f} '
              f'{r["steps"]:>9d} {r["resets"]:>7d}')
    goal = 20_000
    ok = results['step+observe']['per_second'] >= goal
    print(f'goal step+observe >= {goal:,}/s: {"met" if ok else "NOT met"}')
    if args.json:
        out = {'machine': info, 'config': {
            'n_ir': sim.n_ir, 'n_landmarks': len(arena.landmarks),
            'n_obstacles': len(arena.obstacles), 'dt': params.episode.dt,
            'ir_noise_sigma': params.sensors.ir_noise_sigma,
            'bearing_noise_deg': params.sensors.bearing_noise_deg},
            'results': results, 'goal_step_observe_per_second': goal, 'goal_met': ok,
            'rows': [
                {'measure': 'sim core step()+observe() per s (one env, full sensors)',
                 'value': f'{results["step+observe"]["per_second"]:,.0f}',
                 'goal': f'>= {goal:,}'},
                {'measure': 'sim core step() per s (no sensors)',
                 'value': f'{results["step"]["per_second"]:,.0f}', 'goal': ''}]}
        Path(args.json).write_text(json.dumps(out, indent=2) + '\n', encoding='utf-8')
        print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
