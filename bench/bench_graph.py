"""The full CLIS graph under sim time: real-time factor, CPU per node, sensor-to-cmd_vel latency.

Starts ``clis run --condition async`` (simulator, three modules, arbiter, learner as separate
processes, lockstep, every module timer firing) and observes it from this process for
``--seconds`` of wall time after the first learned episode:

- real-time factor: sim seconds per wall second (``/clock``), learner pauses included;
- wakeups per sim-second of each node (voluntary context switches of its main thread, the
  executor's);
- CPU per node: user + system time of each child process over the window, in % of one core,
  and per simulated second (CPU-s / sim-s, summed over the graph's processes and per node): the
  load-insensitive measure of the graph's cost. On an idle 2-core machine the graph is
  CPU-bound, so its real-time factor is about 2 / (summed CPU-s per sim-s); on a shared or
  loaded machine the real-time factor and the latency say little, the CPU per sim-second
  still compares two versions;
- sensor-to-command round trip, at the robot interface: for every instant the simulator holds
  its clock at (lockstep: every decision instant), wall time from its first publication of
  that instant's readings to the arrival of the ``cmd_vel`` answering it, as the simulator
  measures it (``node.round_trip_log``), p50 / p99: this includes the decisions due then,
  the arbiter and three DDS hops; and, as before, the same seen by a subscriber in this
  process (arrival of ``wheels`` stamped t to arrival of ``cmd_vel`` stamped t), which adds
  this process's own queueing; measured as fast as the graph goes and at real time
  (``--speed 1``: the robot's operating point, every node idle between instants; from
  :data:`PACED_WARMUP` s after the first commands);
- the same run with ``--single-process`` (every node in one process and one executor);
- the executors: the same run with every node on rclpy's SingleThreadedExecutor and on its
  EventsExecutor (the default is :class:`clis_base.ros.executor.LeanExecutor`), and the
  CPU of an idle module node (no ``/clock``) with each;
- the round trip with ``clis run --realtime`` (opt-in: simulator, modules and arbiter under
  ``SCHED_FIFO``; the row says whether the nodes got it), as fast as it goes and at real time.

    python bench/bench_graph.py [--seconds 30] [--json FILE]
    python bench/bench_graph.py --cpu-only [--cpus 1]   # CPU per sim-second of the processes

``--cpus LIST`` pins the graph (``taskset``) to those cores: on a shared machine, compare two
versions pinned the same way.
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_learner'))

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_app'))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'cr_sim'))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_base'))
from clis_app.graph.plan import REALTIME_ABOVE  # noqa: E402
from clis_app.graph.ros_env import apply_ros_env, pick_domain_id  # noqa: E402

TICK = os.sysconf('SC_CLK_TCK')
#: Paced runs (``--speed 1``) are measured from this many wall seconds after the first
#: commands: each node's first decisions and one full garbage collection per process (13-195 ms,
#: 4-34 s after its start) belong to the start-up
PACED_WARMUP = 15.0


def cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def wakeups(pid: int) -> int:
    """Voluntary context switches of the process's main thread (its executor): how often it
    went to sleep waiting, i.e. about how often it was woken."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('voluntary_ctxt_switches'):
            return int(line.split()[1])
    return 0


def children(pid: int) -> dict[str, int]:
    out = subprocess.run(['pgrep', '-P', str(pid), '-a'], capture_output=True, text=True).stdout
    found = {}
    for line in out.splitlines():
        child, cmd = line.split(' ', 1)
        for token in cmd.split():
            if '/lib/' in token:                     # install/PKG/lib/PKG/EXE
                found[token.rsplit('/', 1)[-1]] = int(child)
                break
    return found


def measure(seconds: float, single: bool, executor: str = 'lean',
            cpus: str = '', params: str = '', speed: float = 0.0, realtime: int = 0,
            foxglove: int = 0) -> dict:
    from geometry_msgs.msg import TwistStamped
    import rclpy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    out = Path(tempfile.mkdtemp(prefix='bench_graph_'))
    cmd = [sys.executable, '-m', 'clis_app.cli', 'run', '--preset', 'paper',
           '--condition', 'async',
           '--episodes', '100000', '--out', str(out), '--quiet']
    if single:
        cmd.append('--single-process')
    if speed > 0:
        cmd += ['--speed', str(speed)]
    if realtime:
        cmd += ['--realtime', str(realtime)]
    if foxglove:                                   # the live view (bench/foxglove_client.py)
        cmd += ['--foxglove', str(foxglove)]
    # the simulator logs the round trip of every held instant (readings out -> cmd_vel in)
    rtt_log = out / 'round_trips.txt'
    bench_params = out / 'bench.yaml'
    # the executor of the graph's nodes (graph.executor) and of the simulator (node.executor,
    # which has no EventsExecutor: it stays on the default then)
    bench_params.write_text(
        f'sim:\n  ros__parameters:\n    node:\n      round_trip_log: {str(rtt_log)!r}\n'
        + (f'      executor: {executor}\n' if executor == 'single' else '')
        + f'/**:\n  ros__parameters:\n    graph:\n      executor: {executor}\n')
    cmd += ['--params', str(bench_params)]
    if params:
        cmd += ['--params', params]
    if cpus:
        cmd = ['taskset', '-c', cpus, *cmd]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rclpy.init()
    node = rclpy.create_node('bench_graph')
    seen: dict[str, dict[float, float]] = {'wheels': {}, 'cmd_vel': {}}
    clock: list[tuple[float, float]] = []          # (sim time, wall time of arrival)

    def on(topic):
        def cb(msg):
            t = round(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, 6)
            seen[topic].setdefault(t, time.monotonic())
        return cb
    node.create_subscription(JointState, 'wheels', on('wheels'), 100)
    node.create_subscription(TwistStamped, 'cmd_vel', on('cmd_vel'), 100)
    node.create_subscription(Clock, '/clock', lambda m: clock.append(
        (m.clock.sec + m.clock.nanosec * 1e-9, time.monotonic())), 100)
    try:
        # as fast as it goes: from the first learned episode on (the learner's parameters
        # flowing); paced: from PACED_WARMUP s after the first commands on (an episode lasts up
        # to a minute; the start-up's first decisions and garbage collections come first)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (
                (out / 'episodes.csv').is_file() if speed == 0 else len(seen['cmd_vel']) > 10):
            rclpy.spin_once(node, timeout_sec=0.05)
        if speed > 0:
            settled = time.monotonic() + PACED_WARMUP
            while time.monotonic() < settled:
                rclpy.spin_once(node, timeout_sec=0.05)
        pids = {'clis run': proc.pid} if single else children(proc.pid)
        cpu0 = {name: cpu_seconds(pid) for name, pid in pids.items()}
        wake0 = {name: wakeups(pid) for name, pid in pids.items()}
        for d in seen.values():
            d.clear()
        clock.clear()
        load = os.getloadavg()[0]
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            rclpy.spin_once(node, timeout_sec=0.01)
        wall = time.monotonic() - t0
        used = {name: cpu_seconds(pid) - cpu0[name] for name, pid in pids.items()}
        woke = {name: wakeups(pid) - wake0[name] for name, pid in pids.items()}
        cpu = {name: 100 * c / wall for name, c in used.items()}
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:    # the EventsExecutor may not stop on SIGINT
            for pid in children(proc.pid).values():
                os.kill(pid, signal.SIGKILL)
            proc.kill()
            proc.wait()
    lat = np.array([seen['cmd_vel'][t] - w for t, w in seen['wheels'].items()
                    if t in seen['cmd_vel']]) * 1e3
    sim = clock[-1][0] - clock[0][0] if len(clock) > 1 else 0.0
    rtt = np.zeros(0)
    if rtt_log.is_file() and len(clock) > 1:
        rows = np.loadtxt(rtt_log, ndmin=2)
        if rows.size:
            inside = (rows[:, 0] >= clock[0][0]) & (rows[:, 0] <= clock[-1][0])
            rtt = rows[inside, 1]
    # wall time the clock stood still for more than 20 ms: the learner's pauses between
    # episodes (and any stall)
    gaps = np.diff([w for _, w in clock]) if len(clock) > 1 else np.zeros(0)
    steps = np.diff(sorted({round(t, 6) for t, _ in clock}))
    per_sim = {name: c / sim for name, c in used.items()} if sim > 0 else {}
    logs = ''.join(f.read_text(errors='replace') for f in (out / 'logs').glob('*.log')) \
        if (out / 'logs').is_dir() else ''
    granted = logs.count('real-time priority: SCHED_FIFO')
    held = logs.count('CPU wake-up latency 0 us held')
    return {'single_process': single, 'realtime': realtime, 'realtime_granted': granted,
            'wakeup_held': held,
            'executor': executor, 'speed': speed, 'wall_s': wall,
            'sim_s': sim,
            'rtf': sim / wall, 'paused_s': float(gaps[gaps > 0.02].sum()),
            'load_avg_1min': load, 'cpus': cpus or 'all',
            'cpu_s_per_sim_s': per_sim, 'cpu_s_per_sim_s_total': sum(per_sim.values()),
            'wakeups_per_sim_s': {name: w / sim for name, w in woke.items()} if sim > 0 else {},
            'tick_wall_ms_p50': float(np.median(gaps) * 1e3) if gaps.size else None,
            'ticks': int(steps.size),
            'cpu_percent': cpu, 'instants': int(lat.size),
            'round_trips': int(rtt.size),
            'round_trip_ms_p50': float(np.percentile(rtt, 50)) if rtt.size else None,
            'round_trip_ms_p99': float(np.percentile(rtt, 99)) if rtt.size else None,
            'latency_ms_p50': float(np.percentile(lat, 50)) if lat.size else None,
            'latency_ms_p99': float(np.percentile(lat, 99)) if lat.size else None}


def idle_cpu(executor: str, seconds: float = 5.0) -> float:
    """CPU (% of a core) of a view module node that gets no /clock, with ``executor``."""
    proc = subprocess.Popen([sys.executable, '-m', 'clis_modules.module_node', 'view',
                             '--ros-args', '-p', f'graph.executor:={executor}'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(4.0)
    c0, t0 = cpu_seconds(proc.pid), time.monotonic()
    time.sleep(seconds)
    cpu = 100 * (cpu_seconds(proc.pid) - c0) / (time.monotonic() - t0)
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:            # the EventsExecutor may not stop on SIGINT
        proc.kill()
        proc.wait()
    return cpu


def ms(x: float | None) -> str:
    return 'n/a' if x is None else f'{x:.2f} ms'


def rtt(r: dict) -> str:
    """The round trip at the robot interface, p50 / p99."""
    return f'{ms(r["round_trip_ms_p50"])} / {ms(r["round_trip_ms_p99"])}'


def seen(r: dict) -> str:
    """Readings to cmd_vel as a subscriber sees them, p50 / p99."""
    return f'{ms(r["latency_ms_p50"])} / {ms(r["latency_ms_p99"])}'


def latency_line(r: dict) -> str:
    return (f'round trip at the simulator p50/p99 {rtt(r)} over {r["round_trips"]} instants, '
            f'as a subscriber sees it {seen(r)} (load average {r["load_avg_1min"]:.1f})')


def granted(r: dict) -> str:
    """Whether ``--realtime`` took effect (the nodes that logged SCHED_FIFO)."""
    if not r['realtime']:
        return ''
    top = r['realtime'] + max(REALTIME_ABOVE.values())
    return (f'SCHED_FIFO {r["realtime"]}-{top} on {r["realtime_granted"]} nodes, CPU wake-up '
            f'latency held by {r["wakeup_held"]}' if r['realtime_granted'] else
            'SCHED_FIFO refused: default scheduling')


def cpu_line(r: dict) -> str:
    """CPU-s per sim-s, summed and per node."""
    return (f'{r["cpu_s_per_sim_s_total"]:.3f} CPU-s per sim-s ('
            + ', '.join(f'{k} {v:.3f}' for k, v in r['cpu_s_per_sim_s'].items()) + '); '
            'wakeups per sim-s: '
            + ', '.join(f'{k} {v:.0f}' for k, v in r['wakeups_per_sim_s'].items()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seconds', type=float, default=30.0)
    ap.add_argument('--real-time-seconds', type=float, default=60.0,
                    help='wall seconds of the latency measurements at real time (--speed 1)')
    ap.add_argument('--json', metavar='FILE')
    ap.add_argument('--cpu-only', action='store_true',
                    help='only the graph as processes: CPU per sim-second (and what else '
                         'that run gives)')
    ap.add_argument('--cpus', default='', metavar='LIST',
                    help='pin the graph to these cores (taskset -c LIST)')
    ap.add_argument('--params', default='', metavar='FILE',
                    help='a parameter file for clis run --params (with --cpu-only)')
    ap.add_argument('--foxglove', type=int, default=0, metavar='PORT',
                    help='clis run --foxglove PORT: with the live view (0 = without)')
    ap.add_argument('--realtime', type=int, default=10, metavar='PRIO',
                    help='also measure the round trip with clis run --realtime PRIO (the '
                         'sensor-to-command path under SCHED_FIFO; 0 = not)')
    args = ap.parse_args()
    os.environ.pop('ROS_DOMAIN_ID', None)
    apply_ros_env(domain_id=pick_domain_id())
    multi = measure(args.seconds, single=False, cpus=args.cpus, params=args.params,
                    foxglove=args.foxglove)
    if args.cpu_only:
        print(f'processes (cores {multi["cpus"]}, load {multi["load_avg_1min"]:.1f}): '
              f'{cpu_line(multi)}; real-time factor {multi["rtf"]:.1f}x; '
              f'{latency_line(multi)}')
        if args.json:
            Path(args.json).write_text(json.dumps({'processes': multi}, indent=1))
        return 0
    single = measure(args.seconds, single=True, cpus=args.cpus)
    events_run = measure(args.seconds, single=False, executor='events', cpus=args.cpus)
    single_run = measure(args.seconds, single=False, executor='single', cpus=args.cpus)
    # the robot's operating point: sim time = wall time, every node idle between instants
    paced = {single: measure(args.real_time_seconds, single=single, cpus=args.cpus, speed=1.0)
             for single in (False, True)}
    # opt-in: the sensor-to-command path under SCHED_FIFO (root, CAP_SYS_NICE or ulimit -r)
    fifo = {speed: measure(args.seconds if speed == 0 else args.real_time_seconds,
                           single=False, cpus=args.cpus, speed=speed, realtime=args.realtime)
            for speed in ((0.0, 1.0) if args.realtime else ())}
    events, default, lean = idle_cpu('events'), idle_cpu('single'), idle_cpu('lean')
    for r in (multi, single, events_run, single_run):
        print(f'{"one process" if r["single_process"] else "processes  "} ({r["executor"]} '
              f'executor): real-time factor '
              f'{r["rtf"]:.1f}x ({r["sim_s"]:.0f} s sim in {r["wall_s"]:.0f} s, '
              f'{r["paused_s"]:.1f} s of it paused between episodes); {latency_line(r)}; '
              f'CPU % of a core: '
              + ', '.join(f'{k} {v:.0f}' for k, v in r['cpu_percent'].items())
              + (f'; {cpu_line(r)}' if r['sim_s'] > 0 else ''))
    for alone, r in paced.items():
        print(f'{"one process" if alone else "processes  "} at real time (--speed 1): '
              f'{latency_line(r)}')
    for speed, r in fifo.items():
        # (the subscriber in this process, not real-time, is starved by the graph: not shown)
        print(f'processes with --realtime {args.realtime} ({granted(r)}), '
              f'{"at real time" if speed else "as fast as it goes"}: round trip at the '
              f'simulator p50/p99 {rtt(r)} over {r["round_trips"]} instants (load average '
              f'{r["load_avg_1min"]:.1f})' + ('' if speed else f'; real-time factor '
                                               f'{r["rtf"]:.1f}x'))
    print(f'idle module node CPU: EventsExecutor {events:.0f}%, SingleThreadedExecutor '
          f'{default:.0f}%, LeanExecutor {lean:.0f}%')
    if args.json:
        cpu = ', '.join(f'{k} {v:.0f}%' for k, v in multi['cpu_percent'].items())
        Path(args.json).write_text(json.dumps({
            'processes': multi, 'single_process': single, 'events_executor': events_run,
            'single_threaded_executor': single_run, 'idle_cpu_lean': lean,
            'real_time_processes': paced[False], 'real_time_single_process': paced[True],
            'realtime_processes': fifo.get(0.0), 'realtime_real_time_processes': fifo.get(1.0),
            'idle_cpu_events': events, 'idle_cpu_single': default, 'rows': [
                {'measure': 'Async graph real-time factor under sim time (lockstep, every '
                            'timer firing), processes | one process',
                 'value': f'{multi["rtf"]:.1f}x | {single["rtf"]:.1f}x',
                 'goal': '>= 20x (stretch 50x)'},
                {'measure': 'sensor-to-cmd_vel round trip p50 / p99 at the simulator (readings '
                            'out -> cmd_vel in), as fast as it goes: processes | one process '
                            f'(load average {multi["load_avg_1min"]:.1f} | '
                            f'{single["load_avg_1min"]:.1f})',
                 'value': f'{rtt(multi)} | {rtt(single)}', 'goal': 'p99 <= 5 ms'},
                {'measure': 'the same at real time (--speed 1): processes | one process '
                            f'(load {paced[False]["load_avg_1min"]:.1f} | '
                            f'{paced[True]["load_avg_1min"]:.1f})',
                 'value': f'{rtt(paced[False])} | {rtt(paced[True])}', 'goal': 'p99 <= 5 ms'},
                *([{'measure': f'the same with clis run --realtime {args.realtime} (opt-in: '
                               'sim, modules, arbiter under SCHED_FIFO; '
                               f'{granted(fifo[0.0])}), processes: as fast as it goes | at '
                               f'real time (load {fifo[0.0]["load_avg_1min"]:.1f} | '
                               f'{fifo[1.0]["load_avg_1min"]:.1f}); real-time factor',
                    'value': f'{rtt(fifo[0.0])} | {rtt(fifo[1.0])}; {fifo[0.0]["rtf"]:.1f}x',
                    'goal': 'p99 <= 5 ms'}] if fifo else []),
                {'measure': 'readings to cmd_vel as a subscriber sees them (one more process), '
                            'as fast as it goes | at real time, processes',
                 'value': f'{seen(multi)} | {seen(paced[False])}'},
                {'measure': 'wall time paused between episodes (learner), processes | one '
                            'process',
                 'value': f'{multi["paused_s"]:.1f} s | {single["paused_s"]:.1f} s of '
                          f'{multi["wall_s"]:.0f} s'},
                {'measure': 'CPU per node, % of one core (processes)', 'value': cpu},
                {'measure': 'CPU-s per sim-s, all processes (per node)',
                 'value': cpu_line(multi)},
                {'measure': 'CPU-s per sim-s, one process', 'value':
                 f'{single["cpu_s_per_sim_s_total"]:.3f}' if single['sim_s'] > 0 else 'n/a'},
                {'measure': 'Async graph, processes, by executor: LeanExecutor (default) | '
                            'SingleThreadedExecutor | EventsExecutor: real-time factor; round '
                            'trip p50 / p99',
                 'value': f'{multi["rtf"]:.1f}x, {rtt(multi)} | {single_run["rtf"]:.1f}x, '
                          f'{rtt(single_run)} | {events_run["rtf"]:.1f}x'},
                {'measure': 'idle module node CPU: LeanExecutor | SingleThreadedExecutor | '
                            'EventsExecutor',
                 'value': f'{lean:.0f}% | {default:.0f}% | {events:.0f}%'}]}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
