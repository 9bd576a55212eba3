#!/usr/bin/env python3
"""Wall time of the full reproduction: ``clis experiment --conditions innate,view,place,sync,async
--episodes 1000 --seeds 10 --eval-every 0`` (50 runs, 1000 learning + 50 evaluation
episodes each, the Fig. 4 maps and the figures), with ``--workers`` processes (default: all
cores).

    python bench/bench_reproduction.py [--seeds 10] [--episodes 1000] [--out DIR] [--json FILE]

The experiment folder is kept (default ``bench/results/reproduction``) for ``clis report``.
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
import time

ROOT = Path(__file__).resolve().parent.parent
GOAL_S = 6 * 60


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seeds', type=int, default=10)
    ap.add_argument('--episodes', type=int, default=1000)
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    ap.add_argument('--out', type=Path, default=ROOT / 'bench' / 'results' / 'reproduction')
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    if args.out.exists():
        shutil.rmtree(args.out)
    cmd = [sys.executable, '-m', 'clis_app.cli', 'experiment', '--preset', 'paper',
           '--conditions', 'innate,view,place,sync,async', '--episodes', str(args.episodes),
           '--seeds', str(args.seeds), '--workers', str(args.workers), '--out', str(args.out),
           '--eval-every', '0', '--quiet']   # the reproduction workload: no periodic evaluation
    print(' '.join(cmd[2:]), flush=True)
    t0 = time.monotonic()
    proc = subprocess.run(cmd)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        print('the experiment failed', file=sys.stderr)
        return 1
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = usage.ru_utime + usage.ru_stime
    full = args.seeds == 10 and args.episodes == 1000
    print(f'{int(wall // 60)} min {wall % 60:.0f} s wall, {cpu / 60:.1f} min CPU, '
          f'{args.workers} workers' + (f' (goal <= {GOAL_S // 60} min)' if full else ''))
    label = (f'full reproduction (5 conditions x {args.seeds} seeds x {args.episodes} '
             f'episodes, {args.workers} workers): wall (CPU)')
    rows = [{'measure': label, 'value': f'{int(wall // 60)} min {wall % 60:.0f} s '
                                        f'({cpu / 60:.1f} min)',
             'goal': f'<= {GOAL_S // 60} min' if full else ''}]
    if args.json:
        Path(args.json).write_text(json.dumps({'wall_s': wall, 'cpu_s': cpu,
                                               'out': str(args.out), 'rows': rows}, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
