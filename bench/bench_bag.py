"""Recorder throughput (messages/s, MB/s without loss) against the graph's message rate; bag size
per hour of running (real rclpy + Fast DDS, loopback, a private ROS_DOMAIN_ID).

1. The graph's rate: ``clis run --condition async --episodes N --record`` (as fast as the
   graph keeps up, lockstep), then the bag's messages and bytes per wall second and per sim
   second, and the bag size per hour (of wall time at that speed, and of sim time).
2. The recorder alone: ``bench/bag_publisher.py`` publishes K topics at increasing tick rates
   into a ``recorder`` process; the highest rate with every message recorded, the recorder's
   CPU share, and the MB/s it wrote.

    python bench/bench_bag.py [--episodes 3] [--seconds 4] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / 'src' / 'clis_learner'))
sys.path.insert(0, str(HERE.parent / 'src' / 'clis_app'))
sys.path.insert(0, str(HERE.parent / 'src' / 'cr_sim'))
sys.path.insert(0, str(HERE.parent / 'src' / 'clis_base'))
from clis_app.graph.ros_env import apply_ros_env, pick_domain_id  # noqa: E402


def graph_rate(episodes: int, out: Path) -> dict:
    from clis_app.bags.mcap import bag_info
    bag = out / 'graph'
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, '-m', 'clis_app.cli', 'run', '--preset', 'paper',
                           '--condition',
                           'async', '--episodes', str(episodes), '--quiet', '--out',
                           str(out / 'run'), '--record', str(bag)], capture_output=True,
                          text=True, timeout=1800)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise RuntimeError(proc.stdout + proc.stderr)
    info = bag_info(bag)
    clock = info.topics.get('/clock')
    sim = (clock.count * 0.05) if clock else float('nan')     # one /clock per 50 ms tick
    return {'messages': info.message_count, 'bytes': info.size, 'wall_s': info.duration_s,
            'run_wall_s': wall, 'sim_s': sim,
            'msg_per_s': info.message_count / info.duration_s,
            'mb_per_s': info.size / info.duration_s / 1e6,
            'mb_per_wall_hour': info.size / info.duration_s * 3600 / 1e6,
            'mb_per_sim_hour': info.size / sim * 3600 / 1e6,
            'topics': {t.name: t.count for t in info.topics.values()}}


def _cpu_ticks(pid: int) -> int:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return int(fields[11]) + int(fields[12])


def recorder_rate(topics: int, rate: float, seconds: float, out: Path) -> dict:
    from clis_app.bags.mcap import bag_info
    bag = out / f'load-{topics}x{rate:g}'
    rec = subprocess.Popen([sys.executable, '-m', 'clis_app.bags.recorder_node', '--ros-args',
                            '-p', f'recorder.path:={bag}', '-p', 'use_sim_time:=false',
                            '-p', 'recorder.topics:=' + ','.join(f'/load/t{k}'
                                                                for k in range(topics))],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while not (bag / 'metadata.yaml').is_file():
        time.sleep(0.05)
    c0, t0 = _cpu_ticks(rec.pid), time.monotonic()
    pub = subprocess.run([sys.executable, str(HERE / 'bag_publisher.py'), '--topics',
                          str(topics), '--rate', str(rate), '--seconds', str(seconds)],
                         capture_output=True, text=True, timeout=120)
    c1, t1 = _cpu_ticks(rec.pid), time.monotonic()
    rec.send_signal(signal.SIGINT)
    rec.wait(30)
    res = json.loads(pub.stdout.strip().splitlines()[-1])
    info = bag_info(bag)
    published = res['per_topic'] * topics
    hz = os.sysconf('SC_CLK_TCK')
    return {'topics': topics, 'tick_rate': res['tick_rate'], 'published': published,
            'recorded': info.message_count, 'lost': published - info.message_count,
            'msg_per_s': published / res['wall_s'],
            'mb_per_s': published * res['bytes'] / res['wall_s'] / 1e6,
            'cpu_share': (c1 - c0) / hz / (t1 - t0)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--episodes', type=int, default=3)
    ap.add_argument('--seconds', type=float, default=4.0)
    ap.add_argument('--rates', default='300,1000,2000', help='ticks/s of 10 topics')
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    os.environ.pop('ROS_DOMAIN_ID', None)
    apply_ros_env(domain_id=pick_domain_id())
    out = Path(tempfile.mkdtemp(prefix='bench_bag_'))
    g = graph_rate(args.episodes, out)
    print(f'graph (async, max speed): {g["msg_per_s"]:.0f} msg/s, {g["mb_per_s"]:.2f} MB/s; '
          f'bag {g["mb_per_wall_hour"]:.0f} MB per wall hour, {g["mb_per_sim_hour"]:.0f} MB '
          f'per sim hour', flush=True)
    loads = []
    for rate in (float(r) for r in args.rates.split(',')):
        r = recorder_rate(10, rate, args.seconds, out)
        loads.append(r)
        print(f'recorder: 10 topics x {r["tick_rate"]:.0f} Hz = {r["msg_per_s"]:.0f} msg/s, '
              f'{r["mb_per_s"]:.2f} MB/s: lost {r["lost"]} of {r["published"]}, CPU '
              f'{100 * r["cpu_share"]:.0f}%', flush=True)
    best = max((r for r in loads if r['lost'] == 0), key=lambda r: r['msg_per_s'], default=None)
    rows = [
        {'measure': 'graph message rate (async, max speed, recorded)',
         'value': f'{g["msg_per_s"]:.0f} msg/s, {g["mb_per_s"]:.2f} MB/s', 'goal': ''},
        {'measure': 'bag size per hour (wall at max speed / sim time)',
         'value': f'{g["mb_per_wall_hour"]:.0f} MB / {g["mb_per_sim_hour"]:.0f} MB',
         'goal': ''},
    ]
    for r in loads:
        rows.append({'measure': f'recorder, 10 topics x {r["tick_rate"]:.0f} Hz: lost, CPU',
                     'value': f'{r["msg_per_s"]:.0f} msg/s, {r["mb_per_s"]:.2f} MB/s: lost '
                              f'{r["lost"]}/{r["published"]}, CPU {100 * r["cpu_share"]:.0f}%',
                     'goal': '0 lost'})
    if best is not None:
        rows.append({'measure': 'recorder throughput without loss (highest tested)',
                     'value': f'{best["msg_per_s"]:.0f} msg/s '
                              f'({best["msg_per_s"] / g["msg_per_s"]:.1f}x the graph)',
                     'goal': '> graph rate'})
    if args.json:
        Path(args.json).write_text(json.dumps({'graph': g, 'recorder': loads, 'rows': rows},
                                              indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
