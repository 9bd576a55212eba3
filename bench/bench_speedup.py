#!/usr/bin/env python3
"""The headless runner's speed-up over a base commit, measured side by side in one invocation.

The base commit (default 949756d) is checked out in a ``git worktree`` (a temporary folder,
removed at the end) and run from its own ``src`` and ``config`` (on ``PYTHONPATH``, as
``tools/rules_digest.py --at`` does); this checkout runs from the workspace. Both run:

1. the per-condition cost: one run of ``--cost-episodes`` learning episodes (seed 0, no
   evaluation but the final 10 per start) of each of innate, view, place, sync, async and
   ``async:innate+view+place+wall``, in one process, its CPU time per episode;
2. the reproduction workload of ``bench/bench_reproduction.py``: ``clis experiment
   --conditions innate,view,place,sync,async --episodes 1000 --seeds 10 --eval-every 0`` with
   ``--workers`` processes, its wall and CPU time (the children's).

The two experiments' ``episodes.csv`` are then compared row for row: the speed-up is only one
if the results are the same to the bit (the last line says whether they are).

    python bench/bench_speedup.py [--base 949756d] [--new REV] [--seeds 10] [--episodes 1000]
                                  [--cost-episodes 300] [--workers 2] [--json FILE]

Each build's numba kernels are compiled (or loaded from their cache) by a short warm-up
experiment before anything is timed.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import resource
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parent.parent
CONDITIONS = 'innate,view,place,sync,async'
COST_CONDITIONS = ('innate', 'view', 'place', 'sync', 'async', 'async:innate+view+place+wall')
GOAL = 3.0

#: Run in a build's environment: CPU seconds per episode of one run of each condition.
_COST = r"""
import json, sys, tempfile, time
try:
    from clis_app.experiments.runner import JobSpec, run_job
except ImportError:
    try:                               # before the application's rooms
        from clis_app.core.runner import JobSpec, run_job
    except ImportError:                # before the application package
        from clis_learner.core.runner import JobSpec, run_job
n, conditions = int(sys.argv[1]), sys.argv[2].split(',')
out = {}
with tempfile.TemporaryDirectory() as d:
    for c in conditions:
        spec = dict(index=0, label=c, condition=c, overrides={}, sim_overrides={}, seed=0,
                    episodes=n, eval_episodes=10, arena=None, run_dir=d)
        run_job(JobSpec(**{**spec, 'episodes': 2}))          # kernels loaded
        t0 = time.process_time()
        run_job(JobSpec(**spec))
        out[c] = (time.process_time() - t0) / (n + 50)
print(json.dumps(out))
"""


class Build:
    """How to run one build: its environment and its ``clis`` module."""

    def __init__(self, name: str, root: Path, env: dict[str, str]) -> None:
        self.name, self.root, self.env = name, root, env
        app = root / 'src' / 'clis_app' / 'clis_app'
        self.cli = ('clis_app.cli' if (app / 'cli.py').is_file()
                    or (app / 'cli' / '__init__.py').is_file() else 'clis_learner.cli')
        # the workload is the paper preset's: a build whose default is another says so
        config = root / 'src' / 'clis_learner' / 'clis_learner' / 'core' / 'config.py'
        self.paper = (['--preset', 'paper'] if config.is_file()
                      and 'DEFAULT_PRESET' in config.read_text() else [])

    def run(self, args: list[str], **kw) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, *args], env=self.env, cwd=self.root, **kw)


def current_build() -> Build:
    return Build('this checkout', ROOT, dict(os.environ))


def worktree_build(name: str, rev: str, where: Path) -> Build:
    """``rev`` checked out at ``where`` (a detached git worktree), run from its ``src``."""
    subprocess.run(['git', '-C', str(ROOT), 'worktree', 'add', '--detach', '--force',
                    str(where), rev], check=True, capture_output=True)
    src = where / 'src'
    paths = [str(p) for p in sorted(src.iterdir()) if p.is_dir()]
    # none of this checkout's own packages (env.sh's build/ and install/): a package that
    # the commit does not have must not be found here instead
    inherited = [p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep)
                 if p and not Path(p).resolve().is_relative_to(ROOT)]
    env = dict(os.environ, CLIS_CONFIG_DIR=str(where / 'config'),
               PYTHONPATH=os.pathsep.join(paths + inherited))
    return Build(name, where, env)


def remove_worktree(build: Build | None) -> None:
    """Remove the worktree of a build made by :func:`worktree_build` (not this checkout)."""
    if build is not None and build.root != ROOT:
        subprocess.run(['git', '-C', str(ROOT), 'worktree', 'remove', '--force',
                        str(build.root)], capture_output=True)


def children_cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def experiment(build: Build, out: Path, seeds: int, episodes: int, workers: int,
               conditions: str = CONDITIONS) -> tuple[float, float]:
    """Wall and CPU seconds of ``clis experiment`` of ``build`` into ``out``."""
    if out.exists():
        shutil.rmtree(out)
    cmd = ['-m', build.cli, 'experiment', '--conditions', conditions, '--episodes',
           str(episodes), '--seeds', str(seeds), '--workers', str(workers), '--out', str(out),
           '--eval-every', '0', '--block', str(min(50, episodes)), '--quiet', *build.paper]
    cpu0, t0 = children_cpu(), time.monotonic()
    proc = build.run(cmd, capture_output=True, text=True)
    wall, cpu = time.monotonic() - t0, children_cpu() - cpu0
    if proc.returncode != 0:
        raise RuntimeError(f'{build.name}: the experiment failed:\n{proc.stdout}{proc.stderr}')
    return wall, cpu


def costs(build: Build, episodes: int) -> dict[str, float]:
    proc = build.run(['-c', _COST, str(episodes), ','.join(COST_CONDITIONS)],
                     capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f'{build.name}: the cost runs failed:\n{proc.stderr}')
    return json.loads(proc.stdout.strip().splitlines()[-1])


def same_rows(a: Path, b: Path) -> tuple[bool, str]:
    """Whether the two ``episodes.csv`` hold the same rows (column order aside)."""
    import csv

    def rows(p: Path) -> list[dict[str, str]]:
        with open(p, newline='') as fh:
            return [dict(sorted(r.items())) for r in csv.DictReader(fh)]

    ra, rb = rows(a), rows(b)
    if len(ra) != len(rb):
        return False, f'{len(ra)} rows against {len(rb)}'
    for k, (x, y) in enumerate(zip(ra, rb)):
        if x != y:
            keys = sorted(set(x) | set(y))
            diff = [c for c in keys if x.get(c) != y.get(c)]
            return False, f'row {k} differs in {", ".join(diff[:8])}'
    return True, f'{len(ra)} rows identical'


def fmt(seconds: float) -> str:
    return f'{int(seconds // 60)} min {seconds % 60:4.1f} s'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--base', default='949756d', help='the commit to compare with')
    ap.add_argument('--new', metavar='REV',
                    help='measure this commit (in a worktree of its own) instead of the '
                         'checkout: the code stays what it was while the benchmark runs')
    ap.add_argument('--seeds', type=int, default=10)
    ap.add_argument('--episodes', type=int, default=1000)
    ap.add_argument('--cost-episodes', type=int, default=300,
                    help='learning episodes of each per-condition cost run (0: none)')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    ap.add_argument('--keep', type=Path, help='keep both experiments in this folder')
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix='bench_speedup_'))
    keep = args.keep or tmp
    base = new = None
    try:
        base = worktree_build(f'base {args.base}', args.base, tmp / 'worktree')
        new = (worktree_build('this checkout', args.new, tmp / 'worktree_new') if args.new
               else current_build())
        builds = [base, new]
        for b in builds:                                     # kernels compiled or loaded
            experiment(b, tmp / 'warm', 1, 2, 1, 'async')
        cost = {}
        if args.cost_episodes > 0:
            for b in builds:
                cost[b.name] = costs(b, args.cost_episodes)
        times = {}
        for b, sub in zip(builds, ('exp_base', 'exp_new')):
            print(f'{b.name}: {b.cli} experiment, {len(CONDITIONS.split(","))} conditions x '
                  f'{args.seeds} seeds x {args.episodes} episodes, --eval-every 0, '
                  f'{args.workers} workers ...', flush=True)
            times[b.name] = experiment(b, keep / sub, args.seeds, args.episodes, args.workers)
            print(f'  {fmt(times[b.name][0])} wall, {fmt(times[b.name][1])} CPU', flush=True)
        same, how = same_rows(keep / 'exp_base' / 'episodes.csv',
                              keep / 'exp_new' / 'episodes.csv')
    finally:
        for b in (base, new):
            remove_worktree(b)
        if args.keep is None:
            shutil.rmtree(tmp, ignore_errors=True)
    (wb, cb), (wn, cn) = times[base.name], times['this checkout']
    print()
    print(f'reproduction workload ({CONDITIONS}; {args.seeds} seeds x {args.episodes} '
          f'episodes, --eval-every 0, {args.workers} workers):')
    print(f'  {"":16s} {"wall":>14s} {"CPU":>14s}')
    print(f'  {"base " + args.base:16s} {fmt(wb):>14s} {fmt(cb):>14s}')
    print(f'  {(args.new or "this checkout"):16s} {fmt(wn):>14s} {fmt(cn):>14s}')
    print(f'  {"ratio":16s} {wb / wn:13.2f}x {cb / cn:13.2f}x   (goal >= {GOAL:.0f}x)')
    rows = [{'measure': f'reproduction workload, wall: base {args.base} / this checkout',
             'value': f'{fmt(wb)} / {fmt(wn)} = {wb / wn:.2f}x', 'goal': f'>= {GOAL:.0f}x'},
            {'measure': f'reproduction workload, CPU: base {args.base} / this checkout',
             'value': f'{fmt(cb)} / {fmt(cn)} = {cb / cn:.2f}x', 'goal': f'>= {GOAL:.0f}x'}]
    if cost:
        print()
        print(f'CPU per episode, one run of {args.cost_episodes} learning + 50 evaluation '
              'episodes, seed 0 [ms]:')
        print(f'  {"condition":32s} {"base":>8s} {"now":>8s} {"ratio":>7s}')
        for c in COST_CONDITIONS:
            before, after = 1e3 * cost[base.name][c], 1e3 * cost['this checkout'][c]
            print(f'  {c:32s} {before:8.2f} {after:8.2f} {before / after:6.2f}x')
            rows.append({'measure': f'CPU per episode, {c} [ms]: base / now',
                         'value': f'{before:.2f} / {after:.2f} = {before / after:.2f}x',
                         'goal': ''})
    print()
    print(f'episodes.csv of the two experiments: {how}')
    rows.append({'measure': 'episodes.csv, base and this checkout', 'value': how,
                 'goal': 'identical'})
    if args.json:
        Path(args.json).write_text(json.dumps({
            'base': args.base, 'wall_s': {'base': wb, 'new': wn},
            'cpu_s': {'base': cb, 'new': cn}, 'cost_s_per_episode': cost, 'same': same,
            'rows': rows}, indent=2))
    return 0 if same else 1


if __name__ == '__main__':
    raise SystemExit(main())
