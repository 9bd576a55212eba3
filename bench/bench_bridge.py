#!/usr/bin/env python3
"""The real robot's bridge: wire protocol throughput, the emulator's speed, and on real rclpy
the command and watchdog latencies through the bridge and the emulator (UDP on loopback).

- parser: sensor frames (61 bytes, the CR's 7 IR + 5 blobs) parsed per second, fed in 64-byte
  chunks as a serial driver delivers them; clean, and with garbage before every 10th frame;
- encoder: sensor frames encoded per second;
- emulator: device ticks (cr_sim physics + sensors + encoding) per second: how much faster
  than the robot's 20 Hz the emulator can run;
- with ROS (``--ros-trials N``, default 10): the emulator at real speed and ``cr_bridge
  bridge``; wall time from publishing a ``cmd_vel`` to the first ``wheels`` reading that
  executes it (command latency), and from the last ``cmd_vel`` to the first zero reading
  (watchdog latency, ``node.watchdog`` = 0.2 s; goal <= 300 ms), p50 / max.

    python bench/bench_bridge.py [--seconds 2] [--ros-trials 10] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import time

import numpy as np

_REPO = Path(__file__).resolve().parent.parent
for pkg in ('clis_base', 'cr_sim', 'cr_bridge', 'clis_learner', 'clis_app', 'clis_modules'):
    sys.path.insert(0, str(_REPO / 'src' / pkg))

from cr_bridge.core import protocol as proto  # noqa: E402
from cr_bridge.emulator import make_device  # noqa: E402


def rate(fn, seconds: float) -> float:
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        n += fn()
    return n / (time.perf_counter() - t0)


def sensor_frame(k: int) -> proto.SensorFrame:
    return proto.SensorFrame(0.05 * k, (0.3,) * 7, (0.1, math.nan, 1.0, -2.0, 3.0),
                             (1.2, math.nan, 2.0, 2.5, 1.9), (0.3, 0.32), 0, (0.1, 0.0, 9.8))


def core_rates(seconds: float) -> dict:
    frames = [proto.encode(sensor_frame(k), k) for k in range(1000)]
    clean = b''.join(frames)
    rng = np.random.default_rng(0)
    dirty = b''.join((rng.bytes(20) if k % 10 == 0 else b'') + f for k, f in enumerate(frames))

    def parse(data: bytes) -> int:
        p = proto.FrameParser()
        n = 0
        for i in range(0, len(data), 64):
            n += len(p.feed(data[i:i + 64]))
        return n

    device = make_device(0, 'A')
    return {'parse_per_s': rate(lambda: parse(clean), seconds),
            'parse_garbage_per_s': rate(lambda: parse(dirty), seconds),
            'encode_per_s': rate(lambda: len([proto.encode(sensor_frame(k), k)
                                              for k in range(100)]), seconds),
            'device_ticks_per_s': rate(lambda: len(device.tick()) and 1, seconds)}


def ros_latencies(trials: int) -> dict:
    from clis_app.graph.ros_env import apply_ros_env, pick_domain_id
    os.environ.pop('ROS_DOMAIN_ID', None)
    apply_ros_env(domain_id=pick_domain_id())
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    url = f'udp://127.0.0.1:{port}'
    procs = [subprocess.Popen([sys.executable, '-m', 'cr_bridge.emulator', '--link', url,
                               '--quiet'], stdout=subprocess.DEVNULL),
             subprocess.Popen([sys.executable, '-m', 'cr_bridge.bridge_node', '--ros-args',
                               '-p', f'node.device:={url}', '-p', 'node.start:=here'],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    from geometry_msgs.msg import TwistStamped
    import rclpy
    from sensor_msgs.msg import JointState
    rclpy.init()
    node = rclpy.create_node('bench_bridge')
    arrivals: list[tuple[float, float]] = []
    node.create_subscription(JointState, 'wheels', lambda m: arrivals.append(
        (time.monotonic(), abs(m.velocity[1]))), 100)
    pub = node.create_publisher(TwistStamped, 'cmd_vel', 10)

    def spin(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.01)

    def wait(pred, timeout: float) -> float | None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.005)
            hit = pred()
            if hit is not None:
                return hit
        return None

    cmd = TwistStamped()
    cmd.twist.angular.z = 4.0               # turn in place: wheels +-0.32 m/s
    command, watchdog = [], []
    try:
        if wait(lambda: True if len(arrivals) > 5 else None, 30) is None:
            raise RuntimeError('the bridge did not come up')
        for _ in range(trials):
            spin(0.4)
            arrivals.clear()
            t_cmd = time.monotonic()
            pub.publish(cmd)
            hit = wait(lambda: next((t for t, v in arrivals if v > 0.3), None), 2.0)
            command.append(hit - t_cmd if hit else math.nan)
            for _ in range(10):
                pub.publish(cmd)
                spin(0.05)
            pub.publish(cmd)
            t_last = time.monotonic()
            arrivals.clear()
            hit = wait(lambda: next((t for t, v in arrivals if v == 0.0), None), 2.0)
            watchdog.append(hit - t_last if hit else math.nan)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        for p in procs:
            p.send_signal(signal.SIGINT)
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
    return {'command_ms': [round(1000 * x, 1) for x in command],
            'watchdog_ms': [round(1000 * x, 1) for x in watchdog]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=2.0, help='timed seconds per core rate')
    ap.add_argument('--ros-trials', type=int, default=10, help='latency trials (0 = none)')
    ap.add_argument('--json', metavar='FILE', help='write the results as JSON')
    args = ap.parse_args(argv)
    res = core_rates(args.seconds)
    rows = [{'measure': 'bridge parser: sensor frames parsed per s (64-byte chunks)',
             'value': f'{res["parse_per_s"]:,.0f}', 'goal': '>= 200 (10x the robot)'},
            {'measure': 'bridge parser, garbage before every 10th frame',
             'value': f'{res["parse_garbage_per_s"]:,.0f}', 'goal': ''},
            {'measure': 'bridge encoder: sensor frames per s', 'value':
             f'{res["encode_per_s"]:,.0f}', 'goal': ''},
            {'measure': 'emulator device ticks per s (physics + sensors + frames)',
             'value': f'{res["device_ticks_per_s"]:,.0f}', 'goal': '>= 200 (--speed 10)'}]
    if args.ros_trials:
        lat = ros_latencies(args.ros_trials)
        res.update(lat)
        for key, name, goal in (('command_ms', 'cmd_vel -> executed wheel reading', ''),
                                ('watchdog_ms', 'watchdog: last cmd_vel -> zero wheel reading',
                                 '<= 300 ms')):
            v = np.array(lat[key])
            rows.append({'measure': f'bridge + emulator (x1): {name}, p50 / max',
                         'value': f'{np.nanmedian(v):.0f} / {np.nanmax(v):.0f} ms',
                         'goal': goal})
    for r in rows:
        print(f'{r["measure"]:<72} {r["value"]:>16}  {r["goal"]}')
    if args.json:
        Path(args.json).write_text(json.dumps({'results': res, 'rows': rows}, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
