"""Where each episode of a Husky run started, from the world's ground truth: near the destination?

    python bench/bench_robots.py --conditions view --episodes 8 --ground-truth --work W --out O
    python bench/husky_starts.py W [--condition view]

For every run folder ``W/husky-C-seedS`` that ``bench_robots.py --ground-truth`` wrote (its
``ground_truth.csv``: the world's true pose of the robot at each odom, which nothing of the graph
reads), each episode's start: the robot's distance to the destination [m] and the destination's
bearing from its heading [deg, counter-clockwise], beside whether the episode reached it. An
episode starts at ``t_end - duration`` of the run's ``episodes.csv`` (a frame of the world in
lockstep, where the truth is logged too). The destination is the run's ``arena.yaml`` (the
layout at the robot's size). Runs through the standard path in lockstep repeat bit for bit, so
the first episodes of a long benchmark run are those of a short run of the same seed.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
import sys

from cr_sim.core.arena import load_arena
import numpy as np


def starts(run_home: Path) -> list[tuple[int, bool, float, float]]:
    """``(episode, reached, distance [m], bearing [deg])`` of each episode of the run in
    ``run_home`` (a ``bench_robots.py`` run folder with ``ground_truth.csv``)."""
    truth = np.loadtxt(run_home / 'ground_truth.csv', delimiter=',', skiprows=1, ndmin=2)
    dest = load_arena(run_home / 'run' / 'arena.yaml', robot_radius=0.0).destination
    with open(run_home / 'run' / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    out = []
    for r in rows:
        t0 = float(r['t_end']) - float(r['duration'])
        i = int(np.argmin(np.abs(truth[:, 0] - t0)))
        if abs(truth[i, 0] - t0) > 0.05:
            raise SystemExit(f'{run_home}: no true pose within 50 ms of the start of episode '
                             f"{r['episode']} ({t0:.2f} s)")
        _, x, y, yaw = truth[i]
        dx, dy = dest.x - x, dest.y - y
        bearing = (math.atan2(dy, dx) - yaw + math.pi) % (2.0 * math.pi) - math.pi
        out.append((int(r['episode']), r['reached'] == '1', math.hypot(dx, dy),
                    math.degrees(bearing)))
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('work', type=Path, help="bench_robots.py's --work folder")
    p.add_argument('--condition', default='view')
    args = p.parse_args()
    homes = sorted(h for h in args.work.glob(f'husky-{args.condition}-seed*')
                   if (h / 'ground_truth.csv').is_file())
    if not homes:
        print(f'no run of {args.condition} with ground_truth.csv in {args.work} '
              '(bench_robots.py --ground-truth)', file=sys.stderr)
        return 1
    for home in homes:
        rows = starts(home)
        print(f'{home.name}: start distance to the destination [m] (bearing [deg]), '
              'R = reached')
        print('  ' + '  '.join(f"{e}:{'R' if ok else '-'} {d:.1f} ({b:+.0f})"
                               for e, ok, d, b in rows))
        d = np.array([r[2] for r in rows])
        hit = np.array([r[1] for r in rows])
        print(f'  median {np.median(d):.1f} m, range {d.min():.1f}-{d.max():.1f} m; '
              + (f'reached from {d[hit].min():.1f}-{d[hit].max():.1f} m' if hit.any()
                 else 'none reached'))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
