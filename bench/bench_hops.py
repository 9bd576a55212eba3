"""The floor under the graph's sensor-to-command round trip: a bare chain of rclpy processes.

The CLIS graph's round trip at a decision instant crosses three processes (simulator ->
module -> arbiter -> simulator), each hop a DDS delivery (Fast DDS's receive thread, then the
node's executor thread) and a Python executor wakeup. This measures that chain with nothing
else in it: an *origin* process publishes a small message (``std_msgs/Int64``, a sequence number)
to *relay 1*, whose callback publishes it to *relay 2*, whose callback publishes it back; the
origin records the round trip. Same DDS profile as the graph (``config/fastdds_graph.xml``:
shared memory between the processes, loopback only), its own ROS_DOMAIN_ID.

Measured at the graph's operating points: 4 round trips per second with every process idle
in between (the robot at real time: an Async decision instant every 0.25 s), and back to back
(as fast as it goes), with the :class:`clis_base.ros.executor.LeanExecutor` (the graph's
default) and rclpy's SingleThreadedExecutor; and with the LeanExecutor with all three processes
(every thread) under ``SCHED_FIFO`` priority 10 with idle cores polling, as ``clis run
--realtime 10`` runs the graph's sensor-to-command path
(:func:`clis_base.ros.process.realtime`; needs root, CAP_SYS_NICE or ``ulimit -r``, else
that row says so). p50 / p99 in ms.

Under all of it, the host: a busy loop pinned to each core (normal priority, nothing else
running) reads the clock back to back and counts its stalls, the times the core was taken
from it (an interrupt, a kernel thread, or on a VM the hypervisor descheduling the vCPU:
*steal*, also read from ``/proc/stat``). No process on that host answers faster than its
stalls allow: a host whose busy loop stalls > 5 ms several times a minute cannot give a round
trip of several hops a p99 <= 5 ms, whatever the software does.

    python bench/bench_hops.py [--count 240] [--stall-seconds 20] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import numpy as np

HERE = Path(__file__).resolve()
sys.path.insert(0, str(HERE.parent.parent / 'src' / 'clis_learner'))
sys.path.insert(0, str(HERE.parent.parent / 'src' / 'clis_app'))
sys.path.insert(0, str(HERE.parent.parent / 'src' / 'cr_sim'))
sys.path.insert(0, str(HERE.parent.parent / 'src' / 'clis_base'))
from clis_app.graph.plan import REALTIME_PRIORITY as FIFO_PRIORITY  # noqa: E402
from clis_app.graph.ros_env import apply_ros_env, pick_domain_id  # noqa: E402
from clis_base.ros.executor import make_executor  # noqa: E402
from clis_base.ros.process import realtime  # noqa: E402

GRAPH_PROFILE = HERE.parent.parent / 'config' / 'fastdds_graph.xml'


def relay(kind: str, src: str, dst: str, priority: int = 0) -> None:
    """A relay process: every message on ``src`` is published on ``dst`` from its callback
    (``priority`` > 0: every thread under ``SCHED_FIFO`` at it)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from std_msgs.msg import Int64
    rclpy.init()
    node = rclpy.create_node(f'relay_{src}')
    pub = node.create_publisher(Int64, dst, 10)
    node.create_subscription(Int64, src, pub.publish, 10)
    executor = make_executor(kind)
    executor.add_node(node)
    realtime(priority)                  # after rclpy started its threads: all of them
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


def chain(kind: str, rate: float, count: int, priority: int = 0) -> np.ndarray:
    """Round trips [ms] of ``count`` messages through two relay processes (``priority`` > 0:
    the three processes under ``SCHED_FIFO`` at it; :class:`PermissionError` without the
    right)."""
    import rclpy
    from std_msgs.msg import Int64
    relays = [subprocess.Popen([sys.executable, str(HERE), '--relay', kind, src, dst,
                                str(priority)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
              for src, dst in (('hop0', 'hop1'), ('hop1', 'hop2'))]
    rclpy.init()
    node = rclpy.create_node('bench_hops_origin')
    pub = node.create_publisher(Int64, 'hop0', 10)
    # each message carries its sequence number: a late reply of the connection phase must not
    # be taken for the answer to the next message (every round trip would then be one late)
    arrived: dict[int, int] = {}
    node.create_subscription(
        Int64, 'hop2', lambda m: arrived.__setitem__(m.data, time.perf_counter_ns()), 10)
    executor = make_executor(kind)
    executor.add_node(node)
    if priority > 0:
        ok, said = realtime(priority)
        if not ok:
            raise PermissionError(said)
    rtt: list[float] = []
    try:
        end = time.monotonic() + 30.0
        seq = -1
        while len(arrived) < 5 and time.monotonic() < end:   # the chain is connected
            pub.publish(Int64(data=seq))
            seq -= 1
            executor.spin_once(timeout_sec=0.2)
        time.sleep(1.0)
        for k in range(count):
            sent = time.perf_counter_ns()
            pub.publish(Int64(data=k))
            deadline = time.monotonic() + 2.0
            while k not in arrived and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.5)
            if k in arrived:
                rtt.append((arrived[k] - sent) / 1e6)
            if rate > 0:
                time.sleep(1.0 / rate)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        for p in relays:
            p.send_signal(signal.SIGINT)
        for p in relays:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    return np.asarray(rtt)


def stalls(cpu: int, seconds: float) -> list[float]:
    """Stalls [ms] longer than 0.2 ms seen by a busy loop pinned to ``cpu`` for ``seconds``:
    the gaps between two consecutive reads of the clock."""
    os.sched_setaffinity(0, {cpu})
    gaps: list[float] = []
    last = time.perf_counter_ns()
    end = last + int(seconds * 1e9)
    while last < end:
        now = time.perf_counter_ns()
        if now - last > 200_000:
            gaps.append((now - last) / 1e6)
        last = now
    return gaps


def _steal_jiffies() -> int:
    """The host's steal time so far, summed over the cores (USER_HZ ticks; 0 if unknown)."""
    try:
        fields = Path('/proc/stat').read_text().splitlines()[0].split()
        return int(fields[8])
    except (OSError, IndexError, ValueError):
        return 0


def host_stalls(seconds: float) -> dict:
    """One :func:`stalls` busy loop per core, at the same time (a process each): stalls
    > 1 ms and > 5 ms per minute and per core, the longest, and the steal over the window in %
    of the cores' time."""
    cpus = sorted(os.sched_getaffinity(0))
    steal0 = _steal_jiffies()
    procs = [subprocess.Popen([sys.executable, '-c', (
        f'import sys, json; sys.path.insert(0, {str(HERE.parent)!r}); import bench_hops as b; '
        f'print(json.dumps(b.stalls({cpu}, {seconds})))')], stdout=subprocess.PIPE, text=True)
        for cpu in cpus]
    gaps = np.concatenate([np.asarray(json.loads(p.communicate()[0]), dtype=float)
                           for p in procs] + [np.zeros(0)])
    steal = (_steal_jiffies() - steal0) / os.sysconf('SC_CLK_TCK') / (seconds * len(cpus))
    per_min = 60.0 / (seconds * len(cpus))
    return {'cores': len(cpus), 'seconds': seconds,
            'over_1ms_per_min': float(np.sum(gaps > 1.0) * per_min),
            'over_5ms_per_min': float(np.sum(gaps > 5.0) * per_min),
            'max_ms': float(gaps.max(initial=0.0)), 'steal_pct': 100.0 * steal}


def host_cell(host: dict) -> str:
    """:func:`host_stalls` in one line: stalls > 1 ms | > 5 ms per minute and core, the
    longest, the steal."""
    return (f'{host["over_1ms_per_min"]:.0f} | {host["over_5ms_per_min"]:.0f} per min, '
            f'{host["max_ms"]:.1f} ms; steal {host["steal_pct"]:.1f}%')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--count', type=int, default=240,
                    help='round trips per measurement (10x that back to back)')
    ap.add_argument('--stall-seconds', type=float, default=20.0,
                    help='seconds of the busy loops that measure the host stalls (0: not)')
    ap.add_argument('--json', metavar='FILE')
    ap.add_argument('--relay', nargs=4, metavar=('EXECUTOR', 'SRC', 'DST', 'PRIORITY'),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.relay:
        relay(*args.relay[:3], int(args.relay[3]))
        return 0
    os.environ.pop('ROS_DOMAIN_ID', None)
    apply_ros_env(domain_id=pick_domain_id())
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(GRAPH_PROFILE)
    res = {}
    host = host_stalls(args.stall_seconds) if args.stall_seconds > 0 else None
    if host:
        print(f'host stalls, a busy loop per core ({host["cores"]} x {host["seconds"]:.0f} s), '
              f'> 1 ms | > 5 ms: {host_cell(host)}', flush=True)
    for rate, label in ((4.0, 'idle between (4 per s)'), (0.0, 'back to back')):
        for kind, prio in (('lean', 0), ('single', 0), ('lean', FIFO_PRIORITY)):
            # a fresh process for each: rclpy.init once per process
            out = subprocess.run([sys.executable, '-c', (
                'import sys, json; sys.argv = [""]; '
                f'sys.path.insert(0, {str(HERE.parent)!r}); import bench_hops as b; '
                f'r = b.chain({kind!r}, {rate}, {args.count if rate else 10 * args.count}, '
                f'{prio}); print(json.dumps([float(x) for x in r]))')],
                capture_output=True, text=True)
            name = f'{kind}{" fifo" if prio else ""} {label}'
            if out.returncode != 0:
                why = out.stderr.strip().splitlines()[-1] if out.stderr.strip() else '?'
                if prio and 'PermissionError' in why:
                    res[name] = {'error': why.split(': ', 1)[-1]}
                    print(f'{name}: not measured ({res[name]["error"]})', flush=True)
                    continue
                raise RuntimeError(f'{name}: {out.stderr}')
            rtt = np.asarray(json.loads(out.stdout.strip().splitlines()[-1]))
            res[name] = {'n': int(rtt.size), 'p50': float(np.percentile(rtt, 50)),
                         'p99': float(np.percentile(rtt, 99))}
            r = res[name]
            print(f'{name:40s}: 3 hops p50 {r["p50"]:.2f} ms, p99 {r["p99"]:.2f} ms '
                  f'({r["n"]} round trips)', flush=True)
    if args.json:
        def cell(key):
            r = res[key]
            return r['error'] if 'error' in r else f'{r["p50"]:.2f} / {r["p99"]:.2f} ms'
        rows = [] if host is None else [
            {'measure': 'the host under it: stalls of a busy loop pinned to each core (nothing '
                        'else running; interrupts, kernel, hypervisor), > 1 ms | > 5 ms per '
                        'minute and core, longest; steal',
             'value': host_cell(host)}]
        Path(args.json).write_text(json.dumps({'results': res, 'host': host, 'rows': rows + [
            {'measure': 'floor: bare 3-process rclpy chain (origin -> relay -> relay -> '
                        'origin, Int64), round trip p50 / p99, 4 per s idle between: '
                        'LeanExecutor | SingleThreadedExecutor | LeanExecutor, all under '
                        f'SCHED_FIFO {FIFO_PRIORITY} (idle cores polling, as clis run '
                        '--realtime)',
             'value': ' | '.join(cell(f'{k} idle between (4 per s)')
                                 for k in ('lean', 'single', 'lean fifo'))},
            {'measure': 'the same back to back',
             'value': ' | '.join(cell(f'{k} back to back')
                                 for k in ('lean', 'single', 'lean fifo'))}]},
            indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
