"""``clis replay BAG``: republish a bag's serialized messages with their recorded timing and QoS.

One publisher per topic, with the type and the QoS recorded in the bag (reliability and
durability of its publishers; keep-last with their depth, 10 when unknown), publishing the CDR
bytes as they were recorded (``publish`` of rclpy takes serialized bytes), in log-time order
(streamed),
each at ``t0 + (log_time - first log_time) / rate`` of the wall clock (sleeping to within 2 ms,
then spinning on the clock). ``/clock`` is replayed like any topic when the bag has it (the
graph's sim time), else published at ``--clock`` Hz from the bag's time, so that nodes with
``use_sim_time`` follow the replay. Playing starts ``--delay`` s after the publishers are
created (for the subscribers to match them), or once every topic has a subscriber with
``--wait-for-subscribers``. ``--loop`` starts again at the end; Ctrl-C stops.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time

__all__ = ['replay']

SPIN_S = 0.002          # sleep until this close to a message's time, then spin on the clock


def _wait_until(deadline: float) -> None:
    while True:
        left = deadline - time.perf_counter()
        if left <= 0:
            return
        if left > SPIN_S:
            time.sleep(left - SPIN_S)


def replay(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock

    from clis_app.bags.mcap import BagError, BagReader, bag_topics
    from clis_app.bags.recorder_node import message_class, qos_from_dict

    if not args.rate > 0:
        print(f'clis replay: --rate {args.rate}: must be > 0', file=sys.stderr)
        return 2
    wanted = [t.strip() for t in args.topics.split(',') if t.strip()] or None
    try:
        reader = BagReader(args.bag)
        topics = {name: info for name, info in bag_topics(args.bag).items()
                  if wanted is None or name in wanted}
    except (BagError, OSError) as exc:
        print(f'clis replay: {exc}', file=sys.stderr)
        return 2
    if not any(t.count for t in topics.values()):
        print(f'clis replay: {args.bag}: no messages{" on " + args.topics if wanted else ""}',
              file=sys.stderr)
        return 2
    rclpy.init(args=['clis_replay', '--ros-args', '--disable-rosout-logs'],
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node('clis_replay')
    pubs = {}
    for name, info in topics.items():
        try:
            cls = message_class(info.type)
        except (ImportError, AttributeError, ValueError):
            print(f'clis replay: {name}: type {info.type} not installed: skipped',
                  file=sys.stderr)
            continue
        qos = qos_from_dict(info.qos_profiles[0] if info.qos_profiles else {})
        pubs[name] = node.create_publisher(cls, name, qos)
    own_clock = '/clock' not in topics and args.clock > 0
    clock_pub = node.create_publisher(Clock, '/clock', 10) if own_clock else None
    stop = []
    old = signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    tty = sys.stderr.isatty() and not args.quiet
    total = sum(t.count for t in topics.values())
    print(f'clis replay: {total} messages, {len(pubs)} topics at x{args.rate:g}, ROS_DOMAIN_ID '
          f'{os.environ.get("ROS_DOMAIN_ID")}', file=sys.stderr, flush=True)
    # give the subscribers of the graph a moment to match the new publishers
    t_match = time.monotonic() + args.delay
    t_limit = time.monotonic() + 60.0
    while not stop and (time.monotonic() < t_match or (
            args.wait_for_subscribers and time.monotonic() < t_limit
            and not all(p.get_subscription_count() for p in pubs.values()))):
        rclpy.spin_once(node, timeout_sec=0.05)
    sent = 0
    damage = None
    try:
        while not stop:
            start = time.perf_counter()
            first = None
            next_clock = 0.0
            messages = reader.messages_by_time(wanted)
            try:
                for m in messages:
                    if stop:
                        break
                    first = m.log_ns if first is None else first
                    off = (m.log_ns - first) / 1e9 / args.rate
                    while clock_pub is not None and next_clock <= off:
                        _wait_until(start + next_clock)
                        ns = first + int(next_clock * args.rate * 1e9)
                        c = Clock()
                        c.clock.sec, c.clock.nanosec = divmod(ns, 1_000_000_000)
                        clock_pub.publish(serialize_message(c))
                        next_clock += 1.0 / args.clock
                    _wait_until(start + off)
                    pub = pubs.get(m.topic)
                    if pub is not None:
                        pub.publish(m.data)
                        sent += 1
                    if tty and sent % 200 == 0:
                        print(f'\r\033[Kclis replay: {sent}/{total} sent, '
                              f'{off * args.rate:.1f} s', end='', file=sys.stderr, flush=True)
            except BagError as exc:
                damage = str(exc)
                print(f'\nclis replay: {damage}; replayed the messages before it',
                      file=sys.stderr)
            if not args.loop or damage:
                break
        # let reliable messages reach late readers before the publishers go
        t_end = time.monotonic() + 0.5
        while time.monotonic() < t_end and not stop:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        signal.signal(signal.SIGINT, old)
        node.destroy_node()
        rclpy.try_shutdown()
    print(('\r\033[K' if tty else '') + f'clis replay: {sent} messages sent'
          f'{" (interrupted)" if stop else ""}', file=sys.stderr)
    return 130 if stop else (1 if damage else 0)
