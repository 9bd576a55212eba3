"""How well the place module localizes on the Husky, from wheel odometry and detected landmarks.

    python bench/bench_localization.py [--episodes 6] [--seed 0] [--time-limit 45]
                                       [--out docs/figures/robots/localization]

One run of Async (innate, view, place) on the Husky world through the standard path, the world
in lockstep (``husky_world world -p lockstep:=true``, its clock and sensors at 20 Hz, its
camera 160 x 120 as in ``bench_robots.py``, ``clis run --robot ros --profile husky
--lockstep``) and with its ``ground_truth`` topic on: the body's true pose, which no module
reads. A probe in this process records the place module's belief
(``/clis/place/belief``, the grid marginalised over heading, published while someone listens),
the true pose of the same instant and the episodes' starts. Per belief, grouped by the time since
its episode's start (the belief is uniform at each start, paper II-D):

* the distance from the most probable cell's centre to the true position [m];
* the belief's mass within ``--radius`` of the true position, against a uniform belief's (the
  share of the arena's cells within that radius): localized means far above it.

Writes ``OUT/localization.json`` (the per-sample errors, a small summary anyone can redraw from)
and prints the table docs/robots.md shows. ``--redraw``: the table from the saved file only.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import subprocess
import sys
import tempfile
import threading
import time

ROOT = Path(__file__).resolve().parent.parent
#: [s since the episode's start] the bins of the table.
BINS = (0.0, 2.0, 5.0, 10.0, 20.0, 45.0, math.inf)


def record(args: argparse.Namespace, domain: int) -> list[dict]:
    """Run the world, ``clis run`` and the probe; the belief samples with their truth."""
    from clis_app.graph.ros_env import apply_ros_env
    apply_ros_env(domain_id=domain)         # loopback DDS, its own domain (the children too)
    from clis_base.params import config_dir
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import OccupancyGrid, Odometry
    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile
    import yaml

    from cr_sim import conversions as conv

    rclpy.init()
    node = rclpy.create_node('localization_probe')
    truth: dict[int, tuple[float, float]] = {}
    beliefs: list[tuple[float, np.ndarray, float, float, float]] = []
    starts: list[float] = []

    def key(t: float) -> int:
        return round(t * 1e6)

    def on_truth(msg: Odometry) -> None:
        p = msg.pose.pose.position
        truth[key(conv.from_time(msg.header.stamp))] = (p.x, p.y)

    def on_belief(msg: OccupancyGrid) -> None:
        g = np.frombuffer(bytes(msg.data), dtype=np.int8).astype(np.float64)
        g = g.reshape(msg.info.height, msg.info.width)          # rows: y, columns: x
        o = msg.info.origin.position
        beliefs.append((conv.from_time(msg.header.stamp), g, msg.info.resolution, o.x, o.y))

    def on_episode(msg: DiagnosticArray) -> None:
        t, name, _ = conv.event_from_msg(msg)
        if name == 'start':
            starts.append(t)
    deep = QoSProfile(depth=10000)
    node.create_subscription(Odometry, '/ground_truth', on_truth, deep)
    node.create_subscription(OccupancyGrid, '/clis/place/belief', on_belief, deep)
    node.create_subscription(DiagnosticArray, '/clis/episode', on_episode, QoSProfile(
        depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    done = threading.Event()
    spinner = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.05)
                                               for _ in iter(done.is_set, True)], daemon=True)
    spinner.start()
    with tempfile.TemporaryDirectory() as tmp:
        data = yaml.safe_load((config_dir() / 'robots' / 'husky.yaml').read_text())
        data['episode']['time_limit'] = args.time_limit
        profile = Path(tmp) / 'husky.yaml'
        profile.write_text(yaml.safe_dump(data))
        world = subprocess.Popen(
            [sys.executable, '-m', 'husky_world.world_node', '--ros-args',
             '-p', 'real_time_factor:=0.0', '-p', 'lockstep:=true', '-p', 'ground_truth:=true',
             '-p', 'width:=160', '-p', 'height:=120',
             *(x for k in ('clock', 'odom', 'scan', 'image') for x in ('-p', f'{k}_rate:=20.0'))],
            stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
        try:
            proc = subprocess.run(
                [sys.executable, '-m', 'clis_app.cli', '--domain-id', str(domain), 'run',
                 '--robot', 'ros', '--profile', str(profile), '--lockstep', '--condition',
                 'async', '--seed', str(args.seed), '--episodes', str(args.episodes), '--out',
                 str(Path(tmp) / 'run'), '--quiet'], capture_output=True, text=True)
        finally:
            world.send_signal(2)
            world.wait(20)
            done.set()
            spinner.join(5)
            node.destroy_node()
            rclpy.try_shutdown()
        if proc.returncode != 0:
            raise SystemExit(f'clis run exited {proc.returncode}\n{proc.stderr[-2000:]}')
    samples = []
    for t, g, cell, ox, oy in beliefs:
        xy = truth.get(key(t))
        t0 = max((s for s in starts if s <= t + 1e-6), default=None)
        if xy is None or t0 is None or g.sum() <= 0:
            continue
        p = g / g.sum()
        iy, ix = np.unravel_index(int(np.argmax(p)), p.shape)
        cx = ox + (np.arange(p.shape[1]) + 0.5) * cell
        cy = oy + (np.arange(p.shape[0]) + 0.5) * cell
        near = np.hypot(cx[None, :] - xy[0], cy[:, None] - xy[1]) <= args.radius
        samples.append({'since_start': round(t - t0, 3),
                        'map_error': round(float(math.hypot(cx[ix] - xy[0], cy[iy] - xy[1])), 3),
                        'mass_near': round(float(p[near].sum()), 4),
                        'uniform_near': round(float(near.mean()), 4)})
    return samples


def table(samples: list[dict], radius: float) -> str:
    """The table of the module docstring, one row per bin of time since the start."""
    import numpy as np
    lines = [f'| since the start [s] | beliefs | error of the most probable cell [m], median '
             f"[25%, 75%] | mass within {radius:g} m of the truth, mean | a uniform belief's |",
             '|---|---|---|---|---|']
    for lo, hi in zip(BINS, BINS[1:]):
        rows = [s for s in samples if lo <= s['since_start'] < hi]
        if not rows:
            continue
        e = np.array([s['map_error'] for s in rows])
        q25, q50, q75 = np.percentile(e, [25, 50, 75])
        lines.append(f'| {lo:g}-{hi:g} | {len(rows)} | {q50:.2f} [{q25:.2f}, {q75:.2f}] | '
                     f'{np.mean([s["mass_near"] for s in rows]):.2f} | '
                     f'{np.mean([s["uniform_near"] for s in rows]):.2f} |')
    return '\n'.join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--episodes', type=int, default=6)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--time-limit', type=float, default=45.0,
                   help="the profile's episode.time_limit for the run [s]")
    p.add_argument('--radius', type=float, default=1.0, help='[m] of the mass column')
    p.add_argument('--out', type=Path,
                   default=ROOT / 'docs' / 'figures' / 'robots' / 'localization')
    p.add_argument('--redraw', action='store_true', help='the table from the saved file')
    args = p.parse_args()
    saved = args.out / 'localization.json'
    if args.redraw:
        run = json.loads(saved.read_text())
    else:
        t0 = time.monotonic()
        from clis_app.graph.ros_env import pick_domain_id
        samples = record(args, pick_domain_id())   # held by this process: no other run's
        run = {'episodes': args.episodes, 'seed': args.seed, 'time_limit': args.time_limit,
               'radius': args.radius, 'wall_s': round(time.monotonic() - t0, 1),
               'date': time.strftime('%Y-%m-%d'), 'samples': samples}
        args.out.mkdir(parents=True, exist_ok=True)
        saved.write_text(json.dumps(run, indent=0))
        print(f'{len(samples)} beliefs in {run["wall_s"] / 60:.1f} min')
    print(table(run['samples'], run['radius']))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
