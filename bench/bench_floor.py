#!/usr/bin/env python3
"""The floor under the headless runner's speed: the CPU time of the place module's Markov
localization kernels in the reproduction workload, and the speed-up that would be left if
everything else took no time at all.

The two compiled updates (:func:`~clis_modules.core.localization_fused.predict_into`, the
motion update, and :func:`~clis_modules.core.localization_fused.update_into`, the sensor
update) compute the place module's belief. Their arithmetic is fixed by the golden digests
(the same results to the bit), and they already run as one compiled call each, near the cost
of their floating-point work (the call itself is about 1 us of their 20-30 us). Every call
is a belief that the run reads: at the place module's decisions, and at the other modules'
instants for the behaviour density of (6).

Each run of the workload (``clis experiment``'s: ``--episodes`` learning episodes, then 10
evaluation episodes per start, no periodic evaluation) is made here by
:func:`clis_app.experiments.runner.run_job`, with the two entry points wrapped in a timer
(``perf_counter`` around each call); ``--workers`` runs at a time, each in a process of its
own. Printed per condition: the CPU of a run, the kernels' part of it, and their share; then
the bound ``CPU / kernels`` over the whole workload (Amdahl's law with the rest at zero).

With ``--base REV`` the same workload is also run by ``clis experiment`` of that commit, built
in a ``git worktree`` as ``bench/bench_speedup.py`` does, and the bound is also given against
it: ``CPU of the base / kernels of this checkout``, the most any faster build with these
kernels could show against that base.

    python bench/bench_floor.py [--seeds 10] [--episodes 1000] [--workers 2] [--base REV]
                                [--json FILE]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
import json
import multiprocessing as mp
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_speedup import CONDITIONS as WORKLOAD  # noqa: E402
from bench_speedup import experiment, fmt, remove_worktree, worktree_build  # noqa: E402

#: The reproduction workload's conditions (bench_speedup's, bench_reproduction's).
CONDITIONS = tuple(WORKLOAD.split(','))


def _run(job: tuple[str, int, int]) -> tuple[str, int, float, float, int]:
    """One run of the workload: ``(condition, seed, CPU s, kernel s, kernel calls)``."""
    from clis_app.experiments.runner import JobSpec, run_job
    import clis_modules.core.localization as localization

    condition, seed, episodes = job
    spent = [0.0, 0]

    def timed(fn):
        def call(*args):
            t0 = time.perf_counter()
            try:
                return fn(*args)
            finally:
                spent[0] += time.perf_counter() - t0
                spent[1] += 1
        return call

    # the names MarkovLocalizer calls (imported into its module)
    localization.predict_into = timed(localization.predict_into)
    localization.update_into = timed(localization.update_into)
    with tempfile.TemporaryDirectory() as run_dir:
        spec = dict(index=0, label=condition, condition=condition, overrides={},
                    sim_overrides={}, seed=seed, episodes=episodes, eval_episodes=10,
                    arena=None, run_dir=run_dir)
        run_job(JobSpec(**{**spec, 'episodes': 2, 'eval_episodes': 1}))   # kernels loaded
        spent[:] = [0.0, 0]
        t0 = time.process_time()
        run_job(JobSpec(**spec))
        cpu = time.process_time() - t0
    return condition, seed, cpu, spent[0], spent[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', type=int, default=10)
    ap.add_argument('--episodes', type=int, default=1000)
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    ap.add_argument('--base', metavar='REV',
                    help='also run the workload with this commit (e.g. 949756d)')
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    base_cpu = None
    if args.base:
        tmp = Path(tempfile.mkdtemp(prefix='bench_floor_'))
        base = None
        try:
            base = worktree_build(f'base {args.base}', args.base, tmp / 'worktree')
            experiment(base, tmp / 'warm', 1, 2, 1, 'async')      # kernels compiled or loaded
            print(f'base {args.base}: clis experiment, the same workload ...', flush=True)
            base_wall, base_cpu = experiment(base, tmp / 'exp', args.seeds, args.episodes,
                                             args.workers)
            print(f'  {fmt(base_wall)} wall, {fmt(base_cpu)} CPU', flush=True)
        finally:
            remove_worktree(base)
            shutil.rmtree(tmp, ignore_errors=True)
    jobs = [(c, s, args.episodes) for c in reversed(CONDITIONS) for s in range(args.seeds)]
    print(f'{len(jobs)} runs ({", ".join(CONDITIONS)} x {args.seeds} seeds x {args.episodes} '
          f'episodes + 50 evaluation episodes), {args.workers} at a time ...', flush=True)
    per = {c: [0.0, 0.0, 0] for c in CONDITIONS}
    with ProcessPoolExecutor(args.workers, mp_context=mp.get_context('spawn')) as pool:
        for condition, _, cpu, kern, calls in pool.map(_run, jobs):
            acc = per[condition]
            acc[0] += cpu
            acc[1] += kern
            acc[2] += calls
    total = sum(a[0] for a in per.values())
    kernels = sum(a[1] for a in per.values())
    print(f'\n{"condition":10s} {"CPU per run":>12s} {"kernels":>9s} {"share":>6s} '
          f'{"us per call":>11s}')
    rows = []
    for c, (cpu, kern, calls) in per.items():
        us = 1e6 * kern / calls if calls else 0.0
        print(f'{c:10s} {cpu / args.seeds:11.2f}s {kern / args.seeds:8.2f}s '
              f'{100 * kern / cpu:5.1f}% {us:11.1f}')
    bound = total / kernels if kernels else float('inf')
    print(f'{"all":10s} {total:11.1f}s {kernels:8.1f}s {100 * kernels / total:5.1f}%')
    print(f"\nbound on the speed-up with the kernels' arithmetic kept: {bound:.2f}x "
          '(everything but the kernels at zero cost)')
    if base_cpu is not None:
        print(f'against {args.base} (its experiment: {fmt(base_cpu)} CPU): at most '
              f'{base_cpu / kernels:.2f}x')
    shares = ', '.join(f'{c} {100 * k / cpu:.0f}%' for c, (cpu, k, _) in per.items() if k)
    rows.append({'measure': 'reproduction workload (CPU of the runs): the localization '
                            "kernels' share, per condition",
                 'value': f'{100 * kernels / total:.1f}% of {total:.0f} CPU-s ({shares})',
                 'goal': ''})
    rows.append({'measure': 'bound on the speed-up with the same kernels (the rest at zero)',
                 'value': f'{bound:.2f}x', 'goal': ''})
    if base_cpu is not None:
        rows.append({'measure': f"the same against {args.base} (its experiment's CPU / "
                                'these kernels)',
                     'value': f'{base_cpu / kernels:.2f}x', 'goal': '>= 3x wanted'})
    if args.json:
        Path(args.json).write_text(json.dumps({
            'results': {'per_condition': {c: {'cpu_s': a[0], 'kernel_s': a[1], 'calls': a[2]}
                                          for c, a in per.items()},
                        'seeds': args.seeds, 'episodes': args.episodes, 'bound': bound,
                        'base': args.base, 'base_cpu_s': base_cpu},
            'rows': rows}, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
