"""CLIS through the standard path: learning on the Husky in PyBullet, or on our simulator.

    python bench/bench_robots.py              # the Husky: View 3 seeds x 135, Async 1 x 24
    python bench/bench_robots.py [--profile husky] [--conditions view,async:1:24] [--seeds 3]
                                 [--episodes 135] [--jobs 4] [--camera 160x120]
                                 [--time-limit 45] [--wander S] [--out docs/figures/robots]
    python bench/bench_robots.py --profile cr --native --conditions view,async --episodes 300 \
        --jobs 3 --time-limit 60 --wander 5 --out docs/figures/robots/cr

Each run is the robot and ``clis run --robot ros --profile P --condition C --seed S --episodes
N`` (the CLIS graph in ``/clis``, the blob detector, the robot adapter), on a ROS_DOMAIN_ID of
its own, ``--jobs`` runs at a time. ``--conditions`` names the conditions, each run on
``--seeds`` seeds of ``--episodes`` episodes, or as its colons say (``async:1:24``: seed 0
only, 24 episodes). The robot:
``--profile husky``, the Husky world (``husky_world world``), a robot nobody here wrote;
``--profile cr``, our simulator as a plain world, started by ``clis run`` itself. ``--native``
(profile cr): the same conditions and seeds through the native path too, headless (``clis
experiment``, which ``clis run --robot sim`` equals row for row), saved as
``OUT/runs/native-C-seedS.json``, and the table compares the two.
Every run's episodes go to ``OUT/runs/P-C-seedS.json`` (reached, duration, return,
collisions, who acted; the small summaries the figure is drawn from), then ``OUT/P.png`` (the
success rate per third of the runs, per condition: the mean over seeds with its 95%
t-interval, cut to [0, 100]) and the table (stdout; docs/robots.md) are drawn from them. A run
whose summary is saved with all its episodes is not run again, and a run stopped on the way
goes on from its checkpoint in ``--work`` (``clis run --resume``): an interrupted benchmark
goes on. ``--only`` runs some of the runs, ``--adopt`` saves a finished run's folder;
``--redraw`` draws the table and the figure again from the saved runs without running
anything. ``--ground-truth`` (the Husky) logs the world's true pose of the robot in each run's
folder, which nothing of the graph reads (``bench/husky_starts.py`` tells where each episode
started).

Both robots wait for the graph: our simulator always, the Husky world in lockstep (its
``lockstep`` parameter and ``clis run --lockstep``: it holds its clock at each camera frame
until the command on it; its camera and lidar at the slowest rate at which every decision
falls on a frame and no input is older than half the profile's ``stale_timeout``: View 4 Hz,
Async 20 Hz, :func:`frame_rate`), so that each decision is made on the frame of its instant
however loaded the host is (the table counts the waits that timed out), and its clock runs as
fast as the graph answers (``--rtf``, the clock over wall time, 0 = no pacing).
``--no-lockstep`` runs the Husky world free at ``--rtf`` instead: the modules then decide later
in sim time the slower the host, and the learner says so (records that did not arrive; the
table counts these warnings).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parent.parent
#: Student's t at 97.5% for n - 1 degrees of freedom (n seeds), for the 95% interval.
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306,
        9: 2.262}


def frame_rate(condition: str, stale_timeout: float) -> float:
    """The Husky world's frame rate in lockstep for ``condition`` [Hz]: the slowest at which
    every decision instant of the condition's modules is a frame (the frame period divides
    each decision period, in whole physics steps of 1/240 s) and no input the adapter reads is
    ever older than half the profile's ``stale_timeout`` (a frame period at most that): View
    (0.5 s, stale after 0.5 s) 4 Hz, Async (0.25, 0.5, 0.75 and 1.2 s) 20 Hz. Every frame costs
    the world a render, a scan and five messages, the adapter and the detector a turn each:
    the slower the frames, the more episodes the same CPU runs."""
    from clis_learner.core.config import load_clis_params
    from clis_modules.core.modules import condition_periods
    from husky_world.world import PHYSICS_HZ
    steps = [round(tau * PHYSICS_HZ) for _, tau in condition_periods(load_clis_params(),
                                                                     condition)]
    period = math.gcd(*steps)               # [physics steps] every decision on a frame
    k = 1
    while period % k or period / k / PHYSICS_HZ > 0.5 * stale_timeout + 1e-9:
        k += 1
    return PHYSICS_HZ / (period / k)


def run_one(profile: str, condition: str, seed: int, episodes: int, rtf: float, domain: int,
            out: Path, episode_keys: dict, lockstep: bool = False,
            work: Path = ROOT / 'results' / 'bench_robots', camera: str = '',
            ground_truth: bool = False, params: dict | None = None) -> dict:
    """One run (module docstring): its episodes and costs. ``episode_keys``: the profile's
    ``episode`` keys this benchmark sets (a copy of the profile is run). The run's folder is
    ``work/P-C-seedS/run``: a run stopped before its last episode goes on from its checkpoint
    (``clis run --resume``) the next time. ``camera``: the Husky world's image size
    ``'WxH'`` ('' = the world's default). ``ground_truth`` (the Husky): the world's true pose
    of the robot, which nothing of the graph reads, logged to ``work/P-C-seedS/ground_truth.csv``
    (``t,x,y,yaw`` at each odom; :func:`log_ground_truth`). ``params``: CLIS keys (dotted)
    for the run, given to ``clis run`` as a ``--params`` file in its folder."""
    from clis_app.graph.ros_env import apply_ros_env
    from clis_base.params import config_dir
    import yaml
    env = apply_ros_env(dict(os.environ), domain_id=domain)    # loopback DDS, its own domain
    home = work / f'{profile}-{condition}-seed{seed}'
    run_dir = home / 'run'
    home.mkdir(parents=True, exist_ok=True)
    data = yaml.safe_load((config_dir() / 'robots' / f'{profile}.yaml').read_text())
    data['episode'].update(episode_keys)
    profile_file = home / f'{profile}.yaml'
    profile_file.write_text(yaml.safe_dump(data))
    given = []
    if params:
        from clis_base.params import unflatten
        (home / 'params.yaml').write_text(yaml.safe_dump(
            {'/**': {'ros__parameters': unflatten(params)}}))
        given = ['--params', str(home / 'params.yaml')]
    walls = home / 'wall_s'
    spent = float(walls.read_text()) if walls.is_file() else 0.0
    done = 0
    if (run_dir / 'checkpoint.npz').is_file() and (run_dir / 'episodes.csv').is_file():
        with open(run_dir / 'episodes.csv', newline='') as fh:
            done = sum(1 for _ in csv.DictReader(fh))
    go_on = ['--resume', str(run_dir / 'checkpoint.npz')] if done else []
    if not done and run_dir.exists():
        shutil.rmtree(run_dir)                  # a run that learned nothing: afresh
    if done < episodes:
        rate = frame_rate(condition, float(data['episode']['stale_timeout']))
        held = ['-p', 'lockstep:=true', *(x for k in ('clock', 'odom', 'scan', 'image')
                                          for x in ('-p', f'{k}_rate:={rate!r}'))
                ] if lockstep else []
        if camera:
            w, h = camera.split('x')
            held += ['-p', f'width:={int(w)}', '-p', f'height:={int(h)}']
        truth = None
        if ground_truth and profile == 'husky':
            held += ['-p', 'ground_truth:=true']
            truth = subprocess.Popen([sys.executable, __file__, '--log-ground-truth',
                                      str(home / 'ground_truth.csv')], env=env,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        world = (subprocess.Popen(
            [sys.executable, '-m', 'husky_world.world_node', '--ros-args', '-p',
             f'real_time_factor:={rtf!r}', *held], env=env,
            stdout=open(home / 'world.log', 'a'), stderr=subprocess.STDOUT)
            if profile == 'husky' else None)
        speed = (['--lockstep'] if lockstep else []) if world is not None \
            else ['--speed', repr(rtf)]
        t0 = time.monotonic()
        try:
            proc = subprocess.run(
                [sys.executable, '-m', 'clis_app.cli', '--domain-id', str(domain), 'run',
                 '--robot', 'ros', '--profile', str(profile_file), '--condition', condition,
                 '--seed', str(seed), '--episodes', str(episodes - done), '--out',
                 str(run_dir), '--quiet', *speed, *given, *go_on], env=env,
                capture_output=True,
                text=True)
        finally:
            spent += time.monotonic() - t0
            walls.write_text(f'{spent:.1f}')
            for node in (world, truth):
                if node is not None:
                    node.send_signal(2)
                    try:
                        node.wait(10)
                    except subprocess.TimeoutExpired:
                        node.kill()
        if proc.returncode != 0:
            raise RuntimeError(f'{condition} seed {seed}: clis run exited '
                               f'{proc.returncode}\n{proc.stderr[-2000:]}')
    return save_run(run_dir, out, profile, rtf, lockstep or profile == 'cr', episode_keys,
                    spent, episodes, camera if profile == 'husky' else '', params)


def log_ground_truth(path: Path) -> None:
    """A node that appends the Husky world's ``ground_truth`` (its true pose of the robot,
    frame ``map``) to ``path`` as ``t,x,y,yaw`` until Ctrl-C or SIGINT; run by
    :func:`run_one` on the run's ROS_DOMAIN_ID (``--log-ground-truth PATH``)."""
    from cr_bridge.conversions import odom_from_msg
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.executors import ExternalShutdownException
    new = not path.is_file()
    with open(path, 'a', encoding='utf-8') as fh:
        if new:
            fh.write('t,x,y,yaw\n')

        def write(msg: Odometry) -> None:
            t, (x, y, yaw), _, _ = odom_from_msg(msg)
            fh.write(f'{t:.6f},{x:.4f},{y:.4f},{yaw:.4f}\n')
            fh.flush()

        rclpy.init()
        node = rclpy.create_node('ground_truth_log')
        node.create_subscription(Odometry, 'ground_truth', write, 100)
        try:
            rclpy.spin(node)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            node.destroy_node()
            rclpy.try_shutdown()


def save_run(run_dir: Path, out: Path, profile: str, rtf: float, lockstep: bool,
             episode_keys: dict, wall: float, planned: int, camera: str = '',
             params: dict | None = None) -> dict:
    """The summary of the ``clis run`` in ``run_dir`` (its condition and seed are its
    episodes'; ``planned``: the episodes it was started for, more than it has if it was
    stopped; ``camera``: the world's image size, if set; ``params``: the CLIS keys the
    benchmark gave it, if any), saved as
    ``OUT/runs/P-C-seedS.json``."""
    with open(run_dir / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    log = run_dir / 'logs' / 'learner.log'
    late = sum(line.count('did not arrive') for line in
               (log.read_text().splitlines() if log.is_file() else []))
    # the waits that timed out (a node late by more than its timeout: the run went on
    # without it there, not in lockstep): the arbiter's, our simulator's, the Husky world's,
    # the adapter's for the graph and the learner
    from clis_app.graph.supervise import lockstep_timeouts
    timeouts = lockstep_timeouts(run_dir)
    for log, marker in ((run_dir.parent / 'world.log', 'running free'),
                        (run_dir / 'logs' / 'robot.log', 'was not connected within'),
                        (run_dir / 'logs' / 'robot.log', 'the learner did not report')):
        timeouts += log.read_text(errors='replace').count(marker) if log.is_file() else 0
    condition, seed = rows[0]['condition'], int(rows[0]['seed'])
    run = {'profile': profile, 'condition': condition, 'seed': seed, 'rtf': rtf,
           'lockstep': lockstep, 'episode_keys': episode_keys, 'wall_s': round(wall, 1),
           'planned': planned, **({'camera': camera} if camera else {}),
           **({'params': params} if params else {}),
           'late_warnings': late, 'lockstep_timeouts': timeouts,
           'episodes': [{'episode': int(r['episode']), 'reached': int(r['reached']),
                         'duration': float(r['duration']), 'ret': float(r['ret']),
                         'collisions': int(float(r['collisions'])),
                         'behaviour': r['behaviour']} for r in rows]}
    (out / 'runs').mkdir(parents=True, exist_ok=True)
    (out / 'runs' / f'{profile}-{condition}-seed{seed}.json').write_text(
        json.dumps(run, indent=1))
    return run


def run_native(conditions: list[str], seeds: int, episodes: int, out: Path,
               episode_keys: dict) -> None:
    """The native path's runs of the same conditions and seeds (``clis experiment``, headless:
    ``clis run --robot sim`` row for row), saved as ``native-C-seedS.json``. ``episode_keys``:
    the profile's time limit and wander, which must be the simulator's own."""
    from cr_sim.core.sim import load_sim_params
    ep = load_sim_params().episode
    mine = {'time_limit': ep.time_limit, 'wander_time': ep.wander_time}
    if any(abs(float(episode_keys[k]) - v) > 1e-9 for k, v in mine.items()):
        raise SystemExit(f'--native compares like with like: --time-limit {mine["time_limit"]} '
                         f'--wander {mine["wander_time"]} (the simulator\'s own)')
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.monotonic()
        proc = subprocess.run(
            [sys.executable, '-m', 'clis_app.cli', 'experiment', '--conditions',
             ','.join(conditions), '--seeds', str(seeds), '--episodes', str(episodes),
             '--eval-every', '0', '--eval-episodes', '0', '--out', tmp, '--quiet'],
            capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f'clis experiment exited {proc.returncode}\n'
                               f'{proc.stderr[-2000:]}')
        wall = time.monotonic() - t0
        with open(Path(tmp) / 'episodes.csv', newline='') as fh:
            rows = [r for r in csv.DictReader(fh) if r['phase'] == 'train']
    (out / 'runs').mkdir(parents=True, exist_ok=True)
    for c in conditions:
        for seed in range(seeds):
            mine = [r for r in rows if r['condition'] == c and int(r['seed']) == seed]
            run = {'profile': 'native', 'condition': c, 'seed': seed, 'rtf': 0.0,
                   'lockstep': True, 'episode_keys': episode_keys,
                   'wall_s': round(wall / (len(conditions) * seeds), 1), 'late_warnings': 0,
                   'episodes': [{'episode': int(r['episode']), 'reached': int(r['reached']),
                                 'duration': float(r['duration']), 'ret': float(r['ret']),
                                 'collisions': int(float(r['collisions'])),
                                 'behaviour': r['behaviour']} for r in mine]}
            (out / 'runs' / f'native-{c}-seed{seed}.json').write_text(json.dumps(run, indent=1))


def collisions(runs: list[dict]) -> tuple[float, float]:
    """Collisions per episode in the first and the last third, over ``runs`` (NaN if the
    summaries do not have them)."""
    out = []
    for part in (0, 2):
        xs = []
        for r in runs:
            eps = sorted(r['episodes'], key=lambda e: e['episode'])
            k = len(eps) // 3
            xs += [e.get('collisions', math.nan) for e in
                   (eps[:k] if part == 0 else eps[len(eps) - k:])]
        out.append(sum(xs) / len(xs) if xs else math.nan)
    return out[0], out[1]


def complete(path: Path, episodes: int) -> bool:
    """Whether the run saved at ``path`` has ``episodes`` episodes (a stopped run, saved with
    ``--adopt``, is run again)."""
    return path.is_file() and len(json.loads(path.read_text())['episodes']) >= episodes


def thirds(run: dict) -> list[float]:
    """The success rate of each third of the run's episodes."""
    eps = [e['reached'] for e in sorted(run['episodes'], key=lambda e: e['episode'])]
    k = len(eps) // 3
    return [sum(part) / len(part) if part else math.nan
            for part in (eps[:k], eps[k:len(eps) - k], eps[len(eps) - k:])]


def pct(rate: float) -> str:
    """A rate in percent, rounded; 'n/a' for NaN (a third without episodes)."""
    return 'n/a' if math.isnan(rate) else str(round(100 * rate))


def mean_ci(values: list[float]) -> tuple[float, float, float]:
    """Mean and its 95% t-interval ``(lo, hi)``, cut to the rates' [0, 1] (the mean itself for
    one value)."""
    n = len(values)
    m = sum(values) / n
    if n < 2:
        return m, m, m
    sd = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1))
    h = T975.get(n - 1, 1.96) * sd / math.sqrt(n)
    return m, max(0.0, m - h), min(1.0, m + h)


def report(out: Path, profile: str) -> str:
    """The table and the figure from ``OUT/runs`` (module docstring); with the native path's
    runs there (``--native``), both paths side by side and whether each one's last-third
    success lies within the other's 95% interval."""
    paths = [profile] + (['native'] if profile == 'cr' else [])
    by: dict[tuple[str, str], list[dict]] = {}
    partial: list[dict] = []
    for path in paths:
        for f in sorted((out / 'runs').glob(f'{path}-*.json')):
            r = json.loads(f.read_text())
            if len(r['episodes']) < r.get('planned', 0):
                partial.append(r)           # stopped: not in the intervals
                continue
            by.setdefault((r['condition'], path), []).append(r)
    by = dict(sorted(by.items()))
    two = any(path == 'native' for _, path in by)
    lines = ['| condition | ' + ('path | ' if two else '') + 'seeds | episodes | success, first '
             'third [95% CI] | last third | per seed, first -> last [%] | wall min per run | '
             'late-record warnings |',
             '|---|' + ('---|' if two else '') + '---|---|---|---|---|---|---|']
    curves = {}

    def cell(c: tuple[float, float, float]) -> str:
        return f'{100 * c[0]:.0f}% [{100 * c[1]:.0f}, {100 * c[2]:.0f}]'
    for (cond, path), rs in by.items():
        t = [thirds(r) for r in rs]
        first, last = mean_ci([x[0] for x in t]), mean_ci([x[2] for x in t])
        curves[(cond, path)] = [mean_ci([x[i] for x in t]) for i in range(3)]
        per_seed = ', '.join(f'{pct(x[0])}->{pct(x[2])}' for x in t)
        name = {'native': 'native (headless)', profile: 'standard (clis run --robot ros)'}
        lines.append(
            f'| {cond} | ' + (f'{name[path]} | ' if two else '') + f'{len(rs)} | '
            f'{len(rs[0]["episodes"])} | {cell(first)} | {cell(last)} | {per_seed} | '
            f'{sum(r["wall_s"] for r in rs) / len(rs) / 60:.1f} | '
            f'{sum(r["late_warnings"] for r in rs)} |')
    waits = [(c, r['seed'], r['lockstep_timeouts']) for (c, _), rs in by.items() for r in rs
             if 'lockstep_timeouts' in r]
    if waits:
        lines.append('\nlockstep timeouts per run (a wait that timed out: the run went on '
                     'without the late node there): '
                     + ', '.join(f'{c} seed {s} {n}' for c, s, n in waits))
    for r in partial:
        eps = [e['reached'] for e in r['episodes']]
        k = len(eps) // 3
        lines.append(f'\n{r["condition"]} seed {r["seed"]} ({r["profile"]}): stopped after '
                     f'{len(eps)} of {r["planned"]} episodes, not in the table: reached '
                     f'{100 * sum(eps[:k]) / max(k, 1):.0f}% of its first third, '
                     f'{100 * sum(eps[len(eps) - k:]) / max(k, 1):.0f}% of its last')
    if two:
        for cond in sorted({c for c, _ in by}):
            if (cond, profile) in curves and (cond, 'native') in curves:
                a, b = curves[(cond, profile)][2], curves[(cond, 'native')][2]
                inside = b[1] <= a[0] <= b[2] and a[1] <= b[0] <= a[2]
                hits = {p: collisions(by[(cond, p)]) for p in (profile, 'native')}
                lines.append(f'\n{cond}, last third: standard {cell(a)}, native {cell(b)}: '
                             + ("each within the other's 95% CI" if inside else
                                "NOT within each other's 95% CIs")
                             + '; collisions per episode, first -> last third: standard '
                             + ' -> '.join(f'{x:.1f}' for x in hits[profile]) + ', native '
                             + ' -> '.join(f'{x:.1f}' for x in hits['native']))
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        import numpy as np
        fig, (ax, runs_ax) = plt.subplots(1, 2, figsize=(11, 3.6))
        colour = {c: f'C{i}' for i, c in enumerate(sorted({c for c, _ in curves}))}
        for k, ((cond, path), c) in enumerate(curves.items()):
            err = [[100 * (m - lo) for m, lo, _ in c], [100 * (hi - m) for m, _, hi in c]]
            x = [i + 1 + 0.06 * (k - (len(curves) - 1) / 2) for i in range(3)]
            ax.errorbar(x, [100 * m for m, _, _ in c], yerr=err, marker='o', capsize=4,
                        ls='--' if path == 'native' else '-', color=colour[cond],
                        label=f'{cond}' + ((', native' if path == 'native' else ', standard')
                                           if two else '')
                        + f' ({len(by[(cond, path)])} seed'
                        + ('s)' if len(by[(cond, path)]) > 1 else ')'))
        # each run, episode by episode: the share reached over a window of episodes
        for (cond, path), rs in by.items():
            for r in sorted(rs, key=lambda r: r['seed']):
                eps = [e['reached'] for e in sorted(r['episodes'], key=lambda e: e['episode'])]
                w = min(max(5, len(eps) // 20), len(eps))   # a run shorter than 5: all of it
                ma = np.convolve(eps, np.ones(w) / w, mode='valid')
                runs_ax.plot(np.arange(w, len(eps) + 1), 100 * ma, color=colour[cond],
                             ls=('--', '-', ':', '-.')[(r['seed'] % 3) + 1
                                                        if path != 'native' else 0],
                             lw=1.2, alpha=0.8,
                             label=f'{cond}' + (', native' if path == 'native' else '')
                             + f' seed {r["seed"]}')
        runs_ax.set_xlabel('episode')
        runs_ax.set_ylabel('reached over the last max(5, N/20) [%]', fontsize=8)
        runs_ax.set_ylim(-5, 105)
        runs_ax.set_title('each run (N episodes)')
        runs_ax.legend(fontsize=6, ncol=2)
        ax.set_xticks([1, 2, 3], ['first third', 'middle', 'last third'])
        ax.set_ylabel('episodes reached [%]')
        ax.set_ylim(-5, 105)
        ax.set_title({'husky': 'Husky in PyBullet', 'cr': 'our simulator'}.get(profile, profile)
                     + ' through the standard path')
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / f'{profile}.png', dpi=120)
    except ImportError:
        pass
    return '\n'.join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--profile', default='husky', choices=('husky', 'cr'))
    p.add_argument('--conditions', default='view,async:1:24',
                   help='conditions, each on --seeds seeds and --episodes episodes, or C:N '
                        'on N seeds, or C:N:E on N seeds and E episodes')
    p.add_argument('--seeds', type=int, default=3)
    p.add_argument('--episodes', type=int, default=135)
    p.add_argument('--rtf', type=float, default=0.0,
                   help='the world clock / wall clock (0: as fast as the graph answers)')
    p.add_argument('--jobs', type=int, default=4, help='runs at a time')
    p.add_argument('--time-limit', type=float, default=45.0,
                   help="the profile's episode.time_limit for the runs [s of the robot's clock]")
    p.add_argument('--wander', type=float, default=None,
                   help="the profile's episode.wander_time for the runs [s] (default: the "
                        "profile's own; the Husky's 10 s of wander decorrelate an episode's "
                        'start from where the last one ended)')
    p.add_argument('--out', type=Path, default=ROOT / 'docs' / 'figures' / 'robots')
    p.add_argument('--lockstep', action=argparse.BooleanOptionalAction, default=True,
                   help='husky: the world waits for the graph (module docstring)')
    p.add_argument('--camera', default='160x120', metavar='WxH',
                   help="husky: the world's image size (its camera_info gives the detector "
                        "the intrinsics); '' = the world's default")
    p.add_argument('--native', action='store_true',
                   help='cr: the native path on the same conditions and seeds too')
    p.add_argument('--work', type=Path, default=ROOT / 'results' / 'bench_robots',
                   help="the runs' folders (a stopped run goes on from there)")
    p.add_argument('--only', default='', metavar='C:S,...',
                   help='only these runs (condition:seed), e.g. view:2,async:0')
    p.add_argument('--adopt', type=Path, action='append', default=[], metavar='RUN_DIR',
                   help="save the summary of a finished clis run's folder (a run this script "
                        'started whose parent was stopped), with --wall-s its wall time')
    p.add_argument('--wall-s', type=float, default=0.0, help='with --adopt')
    p.add_argument('--redraw', action='store_true', help='only the table and the figure')
    p.add_argument('--ground-truth', action='store_true',
                   help="husky: log the world's true pose of the robot in each run's folder "
                        '(ground_truth.csv; bench/husky_starts.py reads it)')
    p.add_argument('--params', type=Path, action='append', default=[], metavar='FILE',
                   help='a CLIS parameter file for every run (clis run --params), e.g. '
                        "bench/view_one_not_visible.yaml: the paper's one not visible feature "
                        "where the Husky's forward camera turns on three")
    p.add_argument('--log-ground-truth', type=Path, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.log_ground_truth:
        log_ground_truth(args.log_ground_truth)
        return 0
    if args.native and args.profile != 'cr':
        p.error("--native compares our simulator's two paths: --profile cr")
    if args.wander is None:
        from cr_sim.core.profile import load_profile
        args.wander = load_profile(args.profile).episode.wander_time
    keys = {'time_limit': args.time_limit, 'wander_time': args.wander}
    params: dict = {}
    if args.params:
        from clis_learner.core.config import check_params_file
        for f in args.params:
            params.update(check_params_file(f))
    for run_dir in args.adopt:
        r = save_run(run_dir, args.out, args.profile, args.rtf,
                     args.lockstep or args.profile == 'cr', keys, args.wall_s, args.episodes,
                     params=params)
        print(f'adopted {r["condition"]} seed {r["seed"]}: {len(r["episodes"])} episodes')
    if not args.redraw and not args.adopt:
        from concurrent.futures import ThreadPoolExecutor
        # C, C:N (N seeds) or C:N:E (and E episodes)
        spec = {x.split(':')[0]: x.split(':')[1:] for x in args.conditions.split(',')}
        seeds = {c: int(v[0]) if v and v[0] else args.seeds for c, v in spec.items()}
        episodes = {c: int(v[1]) if len(v) > 1 else args.episodes for c, v in spec.items()}
        conditions = list(seeds)
        if args.native and not all((args.out / 'runs' / f'native-{c}-seed{s}.json').exists()
                                   for c in conditions for s in range(seeds[c])):
            if any(spec.values()):
                p.error('--native runs every condition on --seeds seeds and --episodes '
                        'episodes: no C:N')
            run_native(conditions, args.seeds, args.episodes, args.out, keys)
        # a run whose summary is saved already is not run again (an interrupted benchmark
        # goes on)
        only = {tuple(x.split(':')) for x in args.only.split(',') if x}
        todo = [(c, s) for c in conditions for s in range(seeds[c])
                if not complete(args.out / 'runs' / f'{args.profile}-{c}-seed{s}.json',
                                episodes[c]) and (not only or (c, str(s)) in only)]
        # each run on a ROS_DOMAIN_ID that no other process of the project holds (claimed
        # with a lock for as long as this process lives: a concurrent benchmark or run cannot
        # take it)
        from clis_app.graph.ros_env import pick_domain_id
        t0 = time.monotonic()
        with ThreadPoolExecutor(args.jobs) as pool:
            futures = [pool.submit(run_one, args.profile, c, s, episodes[c], args.rtf,
                                   pick_domain_id(), args.out, keys, args.lockstep, args.work,
                                   args.camera if args.profile == 'husky' else '',
                                   args.ground_truth, params)
                       for c, s in todo]
            for f in futures:
                r = f.result()
                print(f'{r["condition"]} seed {r["seed"]}: '
                      f'{sum(e["reached"] for e in r["episodes"])}/{len(r["episodes"])} '
                      f'reached, {r["wall_s"] / 60:.1f} min', flush=True)
        wall = (time.monotonic() - t0) / 60
        print(f'all runs: {wall:.1f} min on {os.cpu_count()} CPUs '
              f'({time.strftime("%Y-%m-%d")})')
        if todo:                        # what this benchmark took, beside its runs
            (args.out / f'{args.profile}-benchmark.json').write_text(json.dumps(
                {'command': ' '.join(['python', 'bench/bench_robots.py', *sys.argv[1:]]),
                 'runs': [f'{c}:{s}' for c, s in todo], 'wall_min': round(wall, 1),
                 'cpus': os.cpu_count(), 'jobs': args.jobs,
                 'date': time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, indent=1))
    print(report(args.out, args.profile))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
