"""Where the sensor-to-command round trip goes: a traced ``clis run``, broken down per instant.

Runs ``clis run --condition async`` with ``CLIS_TRACE`` (:mod:`clis_base.trace`: every
node marks the steps of each decision instant with ``CLOCK_MONOTONIC`` timestamps) for
``--seconds`` of wall time after ``--warmup`` seconds, stops it, and breaks the round trip of
every instant the simulator held its clock at into hops:

    sim publishes the readings + /clock  -> module woken (its /clock callback)
    -> module decides (readings taken) -> module publishes its proposal
    -> arbiter receives the last due proposal -> arbiter publishes cmd_vel -> sim receives it

grouped by the modules that decided at the instant, with p50 / p99 of each hop along the
critical path (the last due proposal), and the slowest instants listed with what else happened
then (garbage collections, the learner's update).

    python bench/trace_round_trip.py [--seconds 30] [--single-process] [--speed 1]
    python bench/trace_round_trip.py --analyse DIR       # a trace folder of an earlier run
"""

from __future__ import annotations

import argparse
from collections import defaultdict
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_graph import children as graph_children  # noqa: E402

MODULES = ('innate', 'view', 'place')


def run(seconds: float, warmup: float, single: bool, speed: float, params: list[str],
        out: Path, sched: list[str], extra_args: list[str]) -> Path:
    trace = out / 'trace'
    env = dict(os.environ, CLIS_TRACE=str(trace))
    cmd = [sys.executable, '-m', 'clis_app.cli', 'run', '--preset', 'paper',
           '--condition', 'async',
           '--episodes', '100000', '--out', str(out / 'run'), '--quiet']
    if single:
        cmd.append('--single-process')
    if speed > 0:
        cmd += ['--speed', str(speed)]
    cmd += extra_args
    rtt = out / 'round_trips.txt'
    extra = out / 'bench.yaml'
    extra.write_text(f'sim:\n  ros__parameters:\n    node:\n      round_trip_log: {str(rtt)!r}\n')
    cmd += ['--params', str(extra)]
    for p in params:
        cmd += ['--params', p]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    load = []
    time.sleep(warmup / 2)
    for spec in sched:                   # NAMES=nice:N or NAMES=fifo:PRIO, every thread
        names, how = spec.split('=')
        kind, value = how.split(':')
        for name, pid in children(proc.pid).items():
            if name in names.split(',') or (single and 'all' in names):
                for tid in os.listdir(f'/proc/{pid}/task'):
                    if kind == 'nice':
                        os.setpriority(os.PRIO_PROCESS, int(tid), int(value))
                    else:
                        os.sched_setscheduler(int(tid), os.SCHED_FIFO,
                                              os.sched_param(int(value)))
    time.sleep(warmup / 2)
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        load.append(os.getloadavg()[0])
        time.sleep(min(5.0, max(0.0, t_end - time.monotonic())))
    proc.send_signal(signal.SIGINT)
    proc.wait(60)
    (out / 'load.txt').write_text(f'{np.mean(load):.2f} {min(load):.2f} {max(load):.2f}\n')
    return trace


def children(pid: int) -> dict[str, int]:
    """The graph's processes under ``clis run`` (``pid``): executable name -> pid."""
    return {'all': pid, **graph_children(pid)}


def load_marks(trace: Path) -> dict[str, dict[float, list[int]]]:
    """event -> sim instant (rounded to the µs) -> wall ns of every occurrence."""
    marks: dict[str, dict[float, list[int]]] = defaultdict(lambda: defaultdict(list))
    for f in sorted(trace.glob('*.trace')):
        proc = f.stem.rsplit('-', 1)[0]
        for line in f.read_text().splitlines():
            w, e, t = line.split(' ')
            t = float(t)
            key = round(t, 6) if t == t else None
            if e.startswith('gc') or e == 'wake':
                e = f'{proc}:{e}'
            marks[e][key].append(int(w))
    return marks


def pct(x, q) -> float:
    return float(np.percentile(x, q)) if len(x) else float('nan')


def analyse(trace: Path, rtt_file: Path | None = None, worst: int = 12) -> str:
    m = load_marks(trace)
    first = {e: {t: min(ws) for t, ws in d.items()} for e, d in m.items()}
    held = {}
    if rtt_file is not None and rtt_file.is_file():
        for line in rtt_file.read_text().splitlines():
            t, ms = line.split()
            held[round(float(t), 6)] = float(ms)
    pub0, cmd = first.get('sim_pub0', {}), first.get('sim_cmd', {})
    if not held:                          # the instants that got their command
        held = {t: (cmd[t] - pub0[t]) / 1e6 for t in cmd if t in pub0}
    traced = sorted(t for t in held if t in pub0 and t in cmd)
    # what else happened: gc passes (start, end) and the learner's updates
    busy = []
    for e, d in m.items():
        if e.endswith('_start') and ':gc' in e:
            starts = sorted(w for ws in d.values() for w in ws)
            ends = sorted(w for ws in m[e.replace('_start', '_end')].values() for w in ws)
            busy += [(s, x, e.replace('_start', '')) for s, x in zip(starts, ends)]
    learn0 = sorted(w for ws in m.get('learner_learn0', {}).values() for w in ws)
    learn1 = sorted(w for ws in m.get('learner_closed1', {}).values() for w in ws)
    busy += [(s, x, 'learner update') for s, x in zip(learn0, learn1)]
    rows = []
    for t in traced:
        due = [k for k in MODULES if t in first.get(f'{k}_pub', {})]
        if not due:
            continue
        crit = max(due, key=lambda k: first.get(f'arb_prop_{k}', {}).get(t, first[f'{k}_pub'][t]))
        p0, p1 = pub0[t], first['sim_pub1'][t]
        clk = first.get(f'{crit}_clock', {}).get(t, np.nan)
        dec = first[f'{crit}_decide'].get(t, np.nan)
        mp = first[f'{crit}_pub'][t]
        ap = first.get(f'arb_prop_{crit}', {}).get(t, np.nan)
        ac = first.get('arb_cmd', {}).get(t, np.nan)
        sc = cmd[t]
        hops = np.array([p1 - p0, clk - p1, dec - clk, mp - dec, ap - mp, ac - ap, sc - ac,
                         sc - p1]) / 1e6
        rows.append((t, '+'.join(due), crit, hops, held[t]))
    names = ['sim publish', '-> module /clock cb', '-> decide', 'decide+publish',
             '-> arbiter', 'arbiter', '-> sim', 'total']
    out = [f'{len(rows)} held instants traced (of {len(held)} round trips logged); '
           f'round trip p50 {pct([r[4] for r in rows], 50):.2f} ms, '
           f'p99 {pct([r[4] for r in rows], 99):.2f} ms']
    out.append('hops along the critical path (the last due proposal), ms p50/p99:')
    out.append(f'{"modules deciding":24s} {"n":>5s}  ' + '  '.join(f'{n:>16s}' for n in names))
    groups = defaultdict(list)
    for r in rows:
        groups[r[1]].append(r)
    groups['all'] = rows
    for g, rs in sorted(groups.items(), key=lambda kv: -len(kv[1])):
        h = np.array([r[3] for r in rs])
        cells = [f'{pct(h[:, i], 50):6.2f} /{pct(h[:, i], 99):7.2f}' for i in range(len(names))]
        out.append(f'{g:24s} {len(rs):5d}  ' + '  '.join(f'{c:>16s}' for c in cells))
    # the wakeup of every module at every held instant (due or not)
    out.append('module /clock callback after the sim published, at held instants, ms p50/p99 '
               '(due | not due):')
    for k in MODULES:
        d, nd = [], []
        for t, due, *_ in rows:
            c = first.get(f'{k}_clock', {}).get(t)
            if c is not None:
                (d if k in due.split('+') else nd).append((c - first['sim_pub1'][t]) / 1e6)
        out.append(f'  {k}: {pct(d, 50):.2f}/{pct(d, 99):.2f} | '
                   f'{pct(nd, 50):.2f}/{pct(nd, 99):.2f}')
    # each hop into the wakeup (the executor's wait returns) and the Python work after it
    out.append('a hop = wakeup (the wait returns) + the executor up to the callback, ms p50/p99:')
    for proc, event, start in [(k, f'{k}_clock', 'sim_pub1') for k in MODULES] + [
            ('arbiter', 'arb_prop_*', '*_pub'), ('sim', 'sim_cmd', 'arb_cmd')]:
        wakes = np.array(sorted(w for ws in m.get(f'{proc}:wake', {}).values() for w in ws))
        if not wakes.size:
            continue
        a, b = [], []
        for t, _, crit, *_ in rows:
            ev = event.replace('*', crit)
            st = start.replace('*', crit)
            c, s0 = first.get(ev, {}).get(t), first.get(st, {}).get(t)
            if c is None or s0 is None:
                continue
            i = np.searchsorted(wakes, c, side='right') - 1
            if i < 0 or wakes[i] < s0:
                continue                     # no wakeup between: it was awake already
            a.append((wakes[i] - s0) / 1e6)
            b.append((c - wakes[i]) / 1e6)
        out.append(f'  {proc:8s} {event:12s} wakeup {pct(a, 50):.2f}/{pct(a, 99):.2f}, '
                   f'executor {pct(b, 50):.2f}/{pct(b, 99):.2f} ({len(a)} of {len(rows)})')
    out.append(f'slowest {worst} instants (ms: ' + ', '.join(names) + '), overlapping events:')
    for t, due, crit, h, _ in sorted(rows, key=lambda r: -r[4])[:worst]:
        p0 = pub0[t]
        sc = cmd[t]
        what = sorted({f'{n} {(x - s) / 1e6:.1f} ms' for s, x, n in busy if s < sc and x > p0})
        out.append(f'  t={t:.2f} {due:20s} crit {crit:6s} ' + ' '.join(f'{v:5.2f}' for v in h)
                   + (f'  [{"; ".join(what)}]' if what else ''))
    return '\n'.join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--seconds', type=float, default=30.0)
    ap.add_argument('--warmup', type=float, default=15.0)
    ap.add_argument('--single-process', action='store_true')
    ap.add_argument('--speed', type=float, default=0.0)
    ap.add_argument('--params', action='append', default=[])
    ap.add_argument('--out', default='')
    ap.add_argument('--realtime', type=int, default=0, metavar='PRIO',
                    help='clis run --realtime PRIO')
    ap.add_argument('--sched', action='append', default=[],
                    help='NAMES=nice:N or NAMES=fifo:PRIO: set the scheduling of those '
                         'children (every thread) after half the warm-up (experiments)')
    ap.add_argument('--analyse', metavar='DIR')
    args = ap.parse_args()
    if args.analyse:
        d = Path(args.analyse)
        print(analyse(d / 'trace' if (d / 'trace').is_dir() else d, d / 'round_trips.txt'))
        return 0
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_learner'))
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_app'))
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'cr_sim'))
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'src' / 'clis_base'))
    from clis_app.graph.ros_env import apply_ros_env, pick_domain_id
    os.environ.pop('ROS_DOMAIN_ID', None)
    apply_ros_env(domain_id=pick_domain_id())
    out = Path(args.out or tempfile.mkdtemp(prefix='trace_rtt_'))
    out.mkdir(parents=True, exist_ok=True)
    trace = run(args.seconds, args.warmup, args.single_process, args.speed, args.params, out,
                args.sched, ['--realtime', str(args.realtime)] if args.realtime else [])
    print(f'{out}: load average {(out / "load.txt").read_text().strip()} (mean min max)')
    print(analyse(trace, out / 'round_trips.txt'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
