"""``clis replay BAG``: republish a bag's serialized messages with their recorded timing and QoS.

One publisher per topic, with the type and the QoS recorded in the bag (reliability and
durability of its publishers; keep-last with their depth, 10 when unknown), publishing the CDR
bytes as they were recorded (``publish`` of rclpy takes serialized bytes), in recorded order,
each at ``t0 + (log_time - first log_time) / rate`` of the wall clock (sleeping to within 2 ms,
then spinning on the clock). ``/clock`` is replayed like any topic when the bag has it (the
graph's sim time), else published at ``--clock`` Hz from the bag's time, so that nodes with
``use_sim_time`` follow the replay. ``--loop`` starts again at the end; Ctrl-C stops.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time

__all__ = ['replay', 'schedule']

SPIN_S = 0.002          # sleep until this close to a message's time, then spin on the clock


def schedule(log_ns: list[int], rate: float) -> list[float]:
    """Offsets [s] from the replay start at which messages logged at ``log_ns`` go out."""
    if not log_ns:
        return []
    t0 = log_ns[0]
    return [(t - t0) / 1e9 / rate for t in log_ns]


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

    from clis_learner.core.bag import BagError, BagReader
    from clis_learner.recorder_node import message_class, qos_from_dict

    if not args.rate > 0:
        print(f'clis replay: --rate {args.rate}: must be > 0', file=sys.stderr)
        return 2
    try:
        reader = BagReader(args.bag)
        wanted = [t.strip() for t in args.topics.split(',') if t.strip()] or None
        messages = _partial(reader, wanted)
        damage = reader.damage
    except (BagError, OSError) as exc:
        print(f'clis replay: {exc}', file=sys.stderr)
        return 2
    if damage:
        print(f'clis replay: {damage}; replaying the {len(messages)} messages before it',
              file=sys.stderr)
    if not messages:
        print(f'clis replay: {args.bag}: no messages{" on " + args.topics if wanted else ""}',
              file=sys.stderr)
        return 2
    messages.sort(key=lambda m: m.log_ns)
    rclpy.init(args=['clis_replay', '--ros-args', '--disable-rosout-logs'],
                signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node('clis_replay')
    pubs = {}
    for name, info in reader.topics.items():
        if wanted is not None and name not in wanted:
            continue
        try:
            cls = message_class(info.type)
        except (ImportError, AttributeError, ValueError):
            print(f'clis replay: {name}: type {info.type} not installed: skipped',
                  file=sys.stderr)
            continue
        qos = qos_from_dict(info.qos_profiles[0] if info.qos_profiles else {})
        pubs[name] = node.create_publisher(cls, name, qos)
    own_clock = '/clock' not in reader.topics and args.clock > 0
    clock_pub = node.create_publisher(Clock, '/clock', 10) if own_clock else None
    stop = []
    old = signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    offsets = schedule([m.log_ns for m in messages], args.rate)
    tty = sys.stderr.isatty() and not args.quiet
    print(f'clis replay: {len(messages)} messages, {len(pubs)} topics, '
          f'{offsets[-1] * args.rate:.1f} s at x{args.rate:g}, ROS_DOMAIN_ID '
          f'{os.environ.get("ROS_DOMAIN_ID")}', file=sys.stderr, flush=True)
    # give the subscribers of the graph a moment to match the new publishers
    t_match = time.monotonic() + 0.5
    while time.monotonic() < t_match and not stop:
        rclpy.spin_once(node, timeout_sec=0.05)
    sent = 0
    try:
        while not stop:
            start = time.perf_counter()
            next_clock = 0.0
            for m, off in zip(messages, offsets):
                if stop:
                    break
                if clock_pub is not None:
                    while next_clock <= off:
                        _wait_until(start + next_clock)
                        ns = messages[0].log_ns + int(next_clock * args.rate * 1e9)
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
                    print(f'\r\033[Kclis replay: {sent} sent, {off * args.rate:.1f} s',
                          end='', file=sys.stderr, flush=True)
            if not args.loop:
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
    return 130 if stop else 0


def _partial(reader, wanted):
    """The messages before the damage (the reader raises after yielding them)."""
    from clis_learner.core.bag import BagError
    out = []
    try:
        for m in reader.messages(wanted):
            out.append(m)
    except BagError:
        pass
    return out
