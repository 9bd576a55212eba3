"""Best real-time factor of the simulator node with ``/clock`` (real rclpy + Fast DDS).

Starts ``cr_sim.sim_node`` with ``node.speed_factor:=0`` (as fast as possible) in its own
process, subscribes to ``/clock`` and every sensor topic from this process, and reports sim
seconds per wall second, plus the fraction of ``/clock`` messages that arrived. Loopback-only DDS
and a private ROS_DOMAIN_ID, like the tests.

    python bench/bench_sim_node.py [--seconds 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_learner'))

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_app'))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'cr_sim'))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_base'))
from clis_app.graph.ros_env import apply_ros_env, pick_domain_id  # noqa: E402


def measure(seconds: float, speed: float) -> dict:
    import rclpy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import LaserScan

    proc = subprocess.Popen([sys.executable, '-m', 'cr_sim.sim_node', '--ros-args',
                             '-p', f'node.speed_factor:={speed}'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rclpy.init()
    node = rclpy.create_node('bench_clock')
    stamps: list[float] = []
    scans = [0]
    node.create_subscription(Clock, '/clock', lambda m: stamps.append(
        m.clock.sec + m.clock.nanosec * 1e-9), 100)
    node.create_subscription(LaserScan, 'ir', lambda m: scans.__setitem__(0, scans[0] + 1), 100)
    try:
        deadline = time.monotonic() + 30
        while len(stamps) < 20 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        stamps.clear()
        scans[0] = 0
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            rclpy.spin_once(node, timeout_sec=0.01)
        wall = time.monotonic() - t0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        proc.send_signal(2)
        proc.wait(10)
    sim = stamps[-1] - stamps[0] if len(stamps) > 1 else 0.0
    expected = sim / 0.05 + 1
    return {'speed_factor': speed, 'wall_s': wall, 'sim_s': sim, 'rtf': sim / wall,
            'clock_received_fraction': len(stamps) / expected if expected else 0.0,
            'ir_received': scans[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seconds', type=float, default=5.0)
    ap.add_argument('--json', metavar='FILE')
    args = ap.parse_args()
    os.environ.pop('ROS_DOMAIN_ID', None)
    apply_ros_env(domain_id=pick_domain_id())
    best = measure(args.seconds, 0.0)
    paced = measure(args.seconds, 10.0)
    for r in (best, paced):
        print(f'speed_factor {r["speed_factor"]:5.1f}: real-time factor {r["rtf"]:6.1f} '
              f'({r["sim_s"]:.1f} s sim in {r["wall_s"]:.1f} s wall), /clock received '
              f'{100 * r["clock_received_fraction"]:.0f}%')
    if args.json:
        Path(args.json).write_text(json.dumps({'best': best, 'paced_10x': paced, 'rows': [
            {'measure': 'sim node real-time factor, speed_factor 0 (max), /clock received',
             'value': f'{best["rtf"]:.1f}x ({100 * best["clock_received_fraction"]:.0f}%)',
             'goal': ''},
            {'measure': 'sim node paced at 10x: achieved',
             'value': f'{paced["rtf"]:.2f}x', 'goal': '10x'}]}, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
