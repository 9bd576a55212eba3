"""A load for the recorder: K topics, one JointState each per tick, like the simulator's tick.

    python bench/bag_publisher.py --topics 10 --rate 400 --seconds 5 --size 20 [--wait-subs 1]

Waits until every topic has ``--wait-subs`` subscribers, then every 1/rate s publishes one
message on each ``/load/tK`` (reliable, depth 10, as the graph's topics): ``position[0]`` = its
index on that topic, ``velocity`` = ``--size`` floats, the stamp = the tick's time. Prints one
JSON line: messages published per topic, bytes per message, the achieved tick rate.
"""

from __future__ import annotations

import argparse
import json
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--topics', type=int, default=10)
    ap.add_argument('--rate', type=float, default=400.0, help='ticks per second')
    ap.add_argument('--seconds', type=float, default=5.0)
    ap.add_argument('--size', type=int, default=20, help='floats per message')
    ap.add_argument('--wait-subs', type=int, default=1)
    args = ap.parse_args()
    import rclpy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node('bag_load')
    pubs = [node.create_publisher(JointState, f'/load/t{k}', 10) for k in range(args.topics)]
    deadline = time.monotonic() + 30.0
    while any(p.get_subscription_count() < args.wait_subs for p in pubs):
        if time.monotonic() > deadline:
            print(json.dumps({'error': 'no subscribers'}), flush=True)
            return 1
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(0.5)                                    # let the matching settle
    msg = JointState(name=['seq'], position=[0.0], velocity=[0.5] * args.size)
    n = int(args.seconds * args.rate)
    t0 = time.perf_counter()
    for i in range(n):
        target = t0 + i / args.rate
        while time.perf_counter() < target:
            pass
        msg.position = [float(i)]
        now = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
        for p in pubs:
            p.publish(msg)
    wall = time.perf_counter() - t0
    size = len(serialize_message(msg))
    time.sleep(1.0)                                     # reliable: let the last ones arrive
    print(json.dumps({'per_topic': n, 'topics': args.topics, 'bytes': size,
                      'tick_rate': n / wall, 'wall_s': wall}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
