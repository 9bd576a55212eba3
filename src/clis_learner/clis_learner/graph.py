"""``clis run``: start the CLIS node graph on the simulator and learn live.

The graph is the robot interface (``cr_sim sim``; the real robot's bridge later), one node per
module of the condition (``clis_modules innate|view|place``), the arbiter and the learner, each
a separate process started exactly as ``ros2 run PKG EXE --ros-args ...`` would start it (the
executables colcon installed in ``install/PKG/lib/PKG/``), all on the loopback and on this
run's own ``ROS_DOMAIN_ID``. The simulator runs under sim time (``/clock``) as fast as the graph
keeps up (``--speed 0``, default) or ``--speed X`` times real time (1: real time); after each
episode it holds its clock until the learner has learned from it (``node.wait_for_learner``),
as the real robot wanders to its next start while the learner learns.

While it runs, one line shows the learner's progress (from ``learner/progress``): learned
episodes, successes in the last block, who acted, Pr(i | x_0), the real-time factor. At the end
(N learned episodes, or Ctrl-C) every child is stopped cleanly, simulator first and learner
last, and OUT gets the learning curve (``curve.csv``, ``curve.png``, from ``episodes.csv``).
Each child's output goes to ``OUT/logs/NAME.log``.

A child that dies is reported with the end of its log. A module or the arbiter is restarted
(it rejoins with the latest parameters, which the learner publishes transient-local); the
learner is restarted from its last checkpoint (``learner_node.resume``); the simulator is not
(its episode is lost): the run stops. At most ``--max-restarts`` restarts per child.

``--single-process`` runs every node in this process, in one executor (like a component
container); docs/benchmarks.md compares both.

Every input (arena, parameter files, checkpoint, device, output folder...) is checked before
any process starts and before anything is written: a bad one stops ``clis run`` with one line
naming the option (exit code 2). ``--resume CKPT`` continues the run of CKPT as if it had not
stopped: its episodes are numbered on from the checkpoint's (the simulator's
``node.first_episode``), every node draws an episode's randomness from (seed, episode), the
simulator's robot and clock start where the checkpoint's episode left them (its ``sim_state``,
``node.resume_state``), and into the same ``--out`` the table ``episodes.csv`` keeps the rows
up to the checkpoint's episode: a run stopped and resumed any number of times ends with the
table and the checkpoint of the run that was not, byte for byte (test_run_interrupt.py). The
learner learns ``--episodes`` episodes, not one more that ended while the graph stopped
(``learner_node.episodes``).

Exit codes: 0 done; 1 a child died and could not be restarted; 2 bad arguments or a bad
parameter (the child's message names the key); 3 the graph did not come up;
130 interrupted (Ctrl-C), after a clean stop.
"""

from __future__ import annotations

import argparse
import csv
import ctypes
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import time
from typing import Any

from clis_modules.core.modules import CONDITIONS
import numpy as np

from clis_learner import ctrl_c

__all__ = ['Child', 'GraphPlan', 'plan_graph', 'register', 'main', 'write_curve']

EXIT_OK, EXIT_CHILD, EXIT_CONFIG, EXIT_STARTUP, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
#: ``clis run --realtime`` without a value: the SCHED_FIFO priority of the sensor-to-command
#: path (low among real-time priorities: the kernel's interrupt threads run at 50)
REALTIME_PRIORITY = 10
#: Under ``--realtime PRIO``, each node's SCHED_FIFO priority above PRIO, in the order of the
#: round trip's end: the modules at PRIO, the simulator (waiting for ``cmd_vel``) one above,
#: the arbiter two above. A proposal's arrival then preempts a module's work at the same
#: instant, and the command's arrival preempts both (measured: docs/benchmarks.md).
REALTIME_ABOVE = {'sim': 1, 'arbiter': 2}
EPILOG = """examples:
  clis run --condition async --episodes 300                 # as fast as the graph keeps up
  clis run --condition view --episodes 50 --speed 5 --out results/run/view
  clis run --condition async --episodes 300 --resume results/run/async/checkpoint.npz
  clis run --condition sync --episodes 100 --params my_overrides.yaml
  sudo -E clis run --realtime ...  # sensor-to-command path under SCHED_FIFO (root or ulimit -r)
  ROS_DOMAIN_ID=7 clis run ...   # watch it: ros2 topic echo /arbiter/selection (same domain)
"""


@dataclass
class Child:
    """One node of the graph, started as its ``ros2 run`` executable.

    ``restart``: ``'always'`` (stateless between episodes: modules, arbiter), ``'resume'``
    (the learner: from its checkpoint) or ``'never'`` (the robot interface).
    """

    name: str
    package: str
    executable: str
    params: dict[str, Any]
    restart: str = 'always'
    stop_last: bool = False           # stopped after the learner (the recorder)
    proc: subprocess.Popen | None = None
    restarts: int = 0
    log: Path | None = None
    #: None: a ROS node (``--ros-args`` from ``params``); else its own command-line arguments
    #: (the device emulator, which is not a ROS node)
    args: list[str] | None = None

    def argv(self, params_files: list[Path]) -> list[str]:
        """``EXE --ros-args [--params-file F]... -p KEY:=VALUE ...`` (what ``ros2 run`` runs)."""
        from ament_index_python.packages import get_package_prefix
        exe = Path(get_package_prefix(self.package)) / 'lib' / self.package / self.executable
        if self.args is not None:
            return [str(exe), *self.args]
        args = [str(exe), '--ros-args']
        for f in params_files:
            args += ['--params-file', str(f)]
        for key, value in self.params.items():
            args += ['-p', f'{key}:={_ros_literal(value)}']
        return args


def _ros_literal(value: Any) -> str:
    """A ``-p`` value ROS parses back to the same type (floats keep their point)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return value if value else "''"
    return str(value)


@dataclass
class GraphPlan:
    """The children of one run, in start order (the robot interface last)."""

    children: list[Child] = field(default_factory=list)

    def by_name(self, name: str) -> Child:
        return next(c for c in self.children if c.name == name)


def plan_graph(condition: str, seed: int, out: Path, speed: float, resume: str = '',
               arena: str = '', robot: str = 'sim', device: str = 'emulator',
               record: str = '', realtime: int = 0, first_episode: int = 1,
               resume_state: str = '', learn_until: int = 0) -> GraphPlan:
    """The nodes of ``condition``, with the parameters ``clis run`` gives each;
    ``realtime`` > 0: the sensor-to-command path (simulator, modules, arbiter) under
    ``SCHED_FIFO`` from that priority up (:data:`REALTIME_ABOVE`,
    :func:`cr_sim.lifecycle.realtime`); ``first_episode`` > 1: the number of the simulator's
    first episode (a resumed run), ``resume_state``: where its robot and clock stood (the
    checkpoint's ``sim_state``); ``learn_until`` > 0: the learner learns no episode that
    starts once that many are learned in all (``learner_node.episodes``)."""
    from clis_modules.core.modules import condition_periods

    from clis_learner.core.config import load_clis_params
    periods = condition_periods(load_clis_params(), condition)
    modules = [name for name, _ in periods]
    graph = {'graph.condition': condition, 'graph.seed': seed, 'graph.arena_file': arena}
    plan = GraphPlan()
    if record:                                       # the bag recorder: up first, stops last
        # (its episode subscription, which the first episode waits for, once it has matched
        # the publishers of the modules and the arbiter: their first messages are in the bag)
        wait_for = [f'{m}/proposal' for m in modules] + ['arbiter/action', 'cmd_vel']
        plan.children.append(Child('recorder', 'clis_learner', 'recorder', {
            **graph, 'recorder.path': record, 'recorder.on_exists': 'number',
            'recorder.wait_for': ','.join(wait_for)}, stop_last=True))
    plan.children.append(Child('learner', 'clis_learner', 'learner', {
        **graph, 'learner_node.out_dir': str(out), 'learner_node.resume': resume,
        **({'learner_node.episodes': learn_until} if learn_until > 0 else {})},
        restart='resume'))

    def priority(key: str, node: str) -> dict:
        """``key``: ``node``'s SCHED_FIFO priority under ``--realtime`` (none without)."""
        return {key: realtime + REALTIME_ABOVE.get(node, 0)} if realtime else {}
    plan.children.append(Child('arbiter', 'clis_modules', 'arbiter', {
        **graph, **priority('graph.realtime_priority', 'arbiter')}))
    for name in modules:
        plan.children.append(Child(name, 'clis_modules', name, {
            **graph, **priority('graph.realtime_priority', name)}))
    if robot == 'bridge':
        _plan_bridge(plan, seed, speed, arena, device)
        return plan
    # the first episode waits until DDS has matched the graph's subscribers of the robot
    # interface (a message sent before is lost to them: the learner's first rewards, a
    # module's first readings): every node follows the episodes and the clock, the modules
    # read the camera, the learner (and the recorder) the rewards, the arbiter commands
    nodes = len(modules) + 2 + bool(record)
    matched = [f'episode:{nodes}', f'/clock:{len(modules) + 2}', f'camera:{len(modules)}',
               f'reward:{1 + bool(record)}', 'cmd_vel:1']
    plan.children.append(Child('sim', 'cr_sim', 'sim', {
        'node.seed': seed, 'node.arena_file': arena, 'node.speed_factor': float(speed),
        'node.start_subscribers': matched,
        'node.start': 'wander', 'node.auto_reset': True, 'node.wait_for_learner': True,
        'node.lockstep': True, 'node.lockstep_periods': [float(tau) for _, tau in periods],
        **({'node.first_episode': first_episode} if first_episode > 1 else {}),
        **({'node.resume_state': resume_state} if resume_state else {}),
        **priority('node.realtime_priority', 'sim')},
        restart='never'))
    return plan


def _plan_bridge(plan: GraphPlan, seed: int, speed: float, arena: str, device: str) -> None:
    """The real robot's bridge as the robot interface (cr_bridge), and with ``device ==
    'emulator'`` the device emulator on a free loopback UDP port, started just before it.
    The robot's clock does not wait (no lockstep): the graph runs at the device's speed."""
    if device == 'emulator':
        import socket
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(('127.0.0.1', 0))
            device = f'udp://127.0.0.1:{s.getsockname()[1]}'
        plan.children.append(Child('emulator', 'cr_bridge', 'emulator', {}, restart='never',
                                   args=['--link', device, '--speed', repr(float(speed)),
                                         '--seed', str(seed), '--start', 'A',
                                         '--arena', arena]))
    plan.children.append(Child('bridge', 'cr_bridge', 'bridge', {
        'node.device': device, 'node.seed': seed, 'node.arena_file': arena,
        'node.start': 'wander', 'node.wait_for_learner': True}, restart='never'))


# ---------------------------------------------------------------------------- the curve

def write_curve(out: Path, block: int) -> tuple[Path, Path] | None:
    """``OUT/curve.csv`` and ``OUT/curve.png`` from ``OUT/episodes.csv`` (learned episodes):
    successes per block and the share of time each module acted. None without episodes."""
    from clis_learner import figures
    from clis_learner.core.runner import JobResult
    path = out / 'episodes.csv'
    if not path.is_file():
        return None
    with open(path, newline='') as fh:
        rows = [_numbers(r) for r in csv.DictReader(fh)]
    if not rows:
        return None
    names = [k[len('share_'):] for k in rows[0] if k.startswith('share_')]
    block = max(1, min(block, len(rows)))
    result = JobResult(spec={'label': str(rows[0].get('condition', 'graph'))}, modules=names,
                       block=block, episodes=rows, evals=[], place_map=None, arena={},
                       seconds=0.0)
    successes = result.success_curve()
    shares = result.selection_shares()
    csv_path = out / 'curve.csv'
    tmp = csv_path.with_suffix('.csv.tmp')
    with open(tmp, 'w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(['episodes', f'successes_per_{block}', *[f'share_{n}' for n in names]])
        for k, s in enumerate(successes):
            w.writerow([(k + 1) * block, int(s), *[round(float(x), 4) for x in shares[k]]])
    os.replace(tmp, csv_path)
    png = out / 'curve.png'
    figures.run_curve(result, png)
    if len(names) > 1:
        figures.run_selection(result, out / 'selection.png')
    return csv_path, png


def _numbers(row: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in row.items():
        try:
            out[k] = float(v)
        except (TypeError, ValueError):
            out[k] = v
    return out


# ---------------------------------------------------------------------------- supervision

def _die_with_parent() -> None:
    """In the child: SIGTERM when ``clis run`` dies, so that no node outlives it."""
    try:
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


class Supervisor:
    """Starts, watches, restarts and stops the children of a :class:`GraphPlan`."""

    def __init__(self, plan: GraphPlan, out: Path, params_files: list[Path],
                 max_restarts: int, say) -> None:
        self.plan, self.out, self.params_files = plan, out, params_files
        self.max_restarts, self.say = max_restarts, say
        (out / 'logs').mkdir(parents=True, exist_ok=True)

    def start(self, child: Child) -> None:
        child.log = self.out / 'logs' / f'{child.name}.log'
        fh = open(child.log, 'a')
        child.proc = subprocess.Popen(child.argv(self.params_files), stdout=fh,
                                      stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                      start_new_session=True, preexec_fn=_die_with_parent)
        fh.close()

    def tail(self, child: Child, lines: int = 6) -> str:
        try:
            text = child.log.read_text(errors='replace').splitlines()
        except OSError:
            return ''
        return '\n'.join('    ' + s for s in text[-lines:])

    def check(self) -> int | None:
        """Handle dead children; an exit code if the run cannot go on."""
        for child in self.plan.children:
            code = child.proc.poll() if child.proc is not None else None
            if code is None:
                continue
            self.say(f'\n{child.name} exited with code {code}; its log ends with:\n'
                     f'{self.tail(child)}')
            if code == EXIT_CONFIG:
                return EXIT_CONFIG
            if child.restart == 'never' or child.restarts >= self.max_restarts:
                why = ('the robot interface' if child.restart == 'never'
                       else 'too many restarts')
                self.say(f'{child.name}: not restarted ({why})')
                return EXIT_CHILD
            if child.restart == 'resume':
                ckpt = self.out / 'checkpoint.npz'
                if ckpt.is_file():
                    child.params['learner_node.resume'] = str(ckpt)
            child.restarts += 1
            self.say(f'{child.name}: restarting ({child.restarts}/{self.max_restarts})'
                     + (f' from {child.params["learner_node.resume"]}'
                        if child.restart == 'resume' and child.params.get('learner_node.resume')
                        else ''))
            self.start(child)
        return None

    def stop(self, timeout: float = 10.0) -> None:
        """SIGINT the robot interface, then the modules and arbiter, the learner last."""
        children = [c for c in self.plan.children if not c.stop_last]
        order = [c for c in children if c.restart == 'never'] + \
                [c for c in children if c.restart == 'always'] + \
                [c for c in children if c.restart == 'resume']
        last = [c for c in self.plan.children if c.stop_last]
        for group in (order[:1], order[1:-1], order[-1:], last):
            live = [c for c in group if c.proc is not None and c.proc.poll() is None]
            for c in live:
                c.proc.send_signal(signal.SIGINT)
            deadline = time.monotonic() + timeout
            for c in live:
                try:
                    c.proc.wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    self.say(f'{c.name} did not stop within {timeout} s: killed')
                    c.proc.kill()
                    c.proc.wait()


class Monitor:
    """An rclpy node of ``clis run``: the learner's progress and the graph's discovery."""

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        import rclpy
        from rclpy.qos import DurabilityPolicy, QoSProfile

        from cr_sim import conversions as rconv
        self.rconv = rconv
        self.node = rclpy.create_node('clis_run')
        self.rows: list[dict[str, str]] = []
        self.node.create_subscription(
            DiagnosticArray, 'learner/progress', self._on_progress,
            QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL))

    def _on_progress(self, msg) -> None:
        t, event, values = self.rconv.event_from_msg(msg)
        if values.get('event') == 'ready':             # the learner is up
            return
        values['t_end'] = values.get('t_end', str(t))
        if self.rows and self.rows[-1].get('episode') == values.get('episode') \
                and self.rows[-1].get('version') == values.get('version'):
            return                                     # the latched copy of one seen
        self.rows.append(values)

    def up(self, nodes: list[str]) -> list[str]:
        """Which of ``nodes`` are not up yet: not discovered, or without their ``episode``
        subscription (created last but one by each graph node, after its other inputs)."""
        seen = dict(self.node.get_node_names_and_namespaces())
        missing = []
        for n in nodes:
            try:
                topics = ([t for t, _ in self.node.get_subscriber_names_and_types_by_node(
                    n, seen[n])] if n in seen else [])
            except Exception:                           # noqa: BLE001 vanished meanwhile
                topics = []
            if not any(t.rsplit('/', 1)[-1] == 'episode' for t in topics):
                missing.append(n)
        return missing

    def spin(self, timeout: float) -> None:
        import rclpy
        rclpy.spin_once(self.node, timeout_sec=timeout)


class ProgressView:
    """The one-line progress of a run, from the learner's progress rows."""

    def __init__(self, target: int, block: int, quiet: bool, tty: bool,
                 time_limit: float = 0.0) -> None:
        self.target, self.block, self.quiet, self.tty = target, block, quiet, tty
        self.time_limit = time_limit * 60.0
        self.t_start = time.monotonic()
        self.shown = 0
        self.learned = 0

    @property
    def out_of_time(self) -> bool:
        return self.time_limit > 0 and time.monotonic() - self.t_start >= self.time_limit

    def update(self, rows: list[dict[str, str]]) -> bool:
        """Show the newest row; True once ``target`` episodes are learned (or the time limit
        is reached)."""
        if len(rows) <= self.shown:
            return self.out_of_time
        self.shown = len(rows)
        done = [r for r in rows if r.get('learned') == '1']
        self.learned = len(done)
        if not self.quiet:
            line = self.line(rows[-1], done, time.monotonic() - self.t_start)
            print(('\r\033[K' + line[:200]) if self.tty else line, end='' if self.tty else '\n',
                  file=sys.stderr, flush=True)
        return self.learned >= self.target or self.out_of_time

    def line(self, last: dict[str, str], done: list[dict[str, str]], wall: float) -> str:
        recent = done[-self.block:]
        succ = sum(int(float(r.get('reached', 0))) for r in recent)
        probs = ' '.join(f'{k[2:]}={float(v):.2f}' for k, v in last.items()
                         if k.startswith('p_') and v not in ('nan', ''))
        # sim time starts at 0 with the simulator
        rtf = float(last.get('t_end', 'nan')) / wall if wall > 0 else math.nan
        eta = wall * (self.target - self.learned) / self.learned if self.learned else math.nan
        what = 'reached' if last.get('reached') == '1' else last.get('event', '?')
        return (f'episode {self.learned}/{self.target} | {succ}/{len(recent)} reached in the '
                f'last {len(recent)} | ep {last.get("episode")}: {what} '
                f'{float(last.get("duration", "nan")):.1f} s, acted {last.get("behaviour", "-")}'
                f'{" | P(i|x0) " + probs if probs else ""} | x{rtf:.0f} real time | '
                f'{wall / 60:.1f} min, ETA {eta / 60:.1f} min')

    def summary(self) -> str:
        return (f'{self.learned} episodes learned in '
                f'{(time.monotonic() - self.t_start) / 60:.1f} min')


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'run', help='run the CLIS node graph on the simulator and learn live',
        description=__doc__, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--condition', default='async', choices=CONDITIONS,
                   help='which modules run (default: %(default)s)')
    p.add_argument('--episodes', type=int, default=100,
                   help='learned episodes before stopping (default: %(default)s)')
    p.add_argument('--speed', type=float, default=0.0,
                   help='sim time / wall time; 0 = as fast as the graph keeps up (default), '
                        '1 = real time')
    # one name per flag: --real-time (--speed 1) read as --realtime (a priority) by a dash
    p.add_argument('--real-time', nargs=0, action=_Removed, help=argparse.SUPPRESS,
                   default=argparse.SUPPRESS,
                   instead='--speed 1 (--realtime PRIO is the SCHED_FIFO priority)')
    p.add_argument('--seed', type=int, default=0, help='seed of the run (default 0)')
    p.add_argument('--params', type=Path, action='append', default=[], metavar='FILE',
                   help='a ROS parameter file given to every node (--params-file), e.g. to '
                        'override config/clis.yaml keys under "/**: ros__parameters:"')
    p.add_argument('--resume', type=Path, help='start the learner from this checkpoint')
    p.add_argument('--out', type=Path, help='output folder (default results/run/CONDITION-'
                   'seedS-DATE)')
    p.add_argument('--arena', type=str, default='', help='arena file (default config/arena.yaml)')
    p.add_argument('--robot', choices=('sim', 'bridge'), default='sim',
                   help="the robot interface: the simulator (default) or the real robot's "
                        "bridge (cr_bridge), which runs on the robot's clock: real time")
    p.add_argument('--device', default='emulator', metavar='URL',
                   help="with --robot bridge: 'emulator' (default: cr_bridge's device emulator "
                        'on the loopback; --speed X runs its clock X times wall time) or the '
                        "robot's link (udp://HOST:PORT, a serial device, a pyserial URL)")
    p.add_argument('--block', type=int, default=50,
                   help='episodes per point of the learning curve (default 50, the paper)')
    p.add_argument('--time-limit', type=float, default=0.0, metavar='MIN',
                   help='stop cleanly after this many minutes of learning even if fewer '
                        'episodes were learned (0 = no limit; `make run` uses 5)')
    p.add_argument('--max-restarts', type=int, default=3,
                   help='restarts per child before giving up (default 3)')
    p.add_argument('--startup-timeout', type=float, default=60.0,
                   help='seconds for the nodes to come up (default 60)')
    p.add_argument('--single-process', action='store_true',
                   help='all nodes in this process, one executor (a component container)')
    p.add_argument('--record', type=Path, metavar='BAG',
                   help='record every topic of the run into this bag folder (MCAP, e.g. '
                        'bags/NAME; see clis bag info / replay / learn)')
    p.add_argument('--foxglove', type=int, nargs='?', const=8765, metavar='PORT',
                   help='serve the topics live to the Foxglove app on ws://127.0.0.1:PORT '
                        '(default 8765; docs/foxglove.md)')
    p.add_argument('--foxglove-wait', action='store_true',
                   help='with --foxglove: the first episode waits until a client subscribes '
                        'to every shown topic that has a publisher (the simulator starts '
                        'anyway after its graph_timeout), so that a short run is seen from '
                        'its start')
    p.add_argument('--realtime', type=int, nargs='?', const=REALTIME_PRIORITY, default=0,
                   metavar='PRIO',
                   help='run the sensor-to-command path (modules, simulator, arbiter; not the '
                        f'learner) under SCHED_FIFO priority PRIO, PRIO+1, PRIO+2 (PRIO in '
                        f'1-97, default {REALTIME_PRIORITY}), with idle cores polling '
                        '(/dev/cpu_dma_latency held at 0): needs root, CAP_SYS_NICE or ulimit '
                        '-r, else each node warns and runs with the default scheduling')
    p.add_argument('--quiet', action='store_true', help='no progress line')
    p.set_defaults(func=main)
    _one_line_errors(p)


class _Removed(argparse.Action):
    """A removed flag: using it is an error naming the one to use ``instead``."""

    def __init__(self, *args, instead: str = '', **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.instead = instead

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        parser.error(f'{option_string} was removed: use {self.instead}')


def _one_line_errors(parser: argparse.ArgumentParser) -> None:
    """A bad argument ends ``clis run`` with one line naming the option (exit code 2),
    not argparse's usage block."""
    def error(message: str):
        parser.exit(EXIT_CONFIG, f'{parser.prog}: {message} (see {parser.prog} --help)\n')
    parser.error = error


def _check_args(args: argparse.Namespace) -> str | None:
    """Every option checked before anything starts or is written: the first error, one line
    naming the option, or None. Sets ``args.first_episode`` (1, or the episode after the
    checkpoint's), ``args.sim_state`` (the checkpoint's ``sim_state``, or '') and
    ``args.version`` (the checkpoint's, or 0)."""
    if args.episodes < 1:
        return f'--episodes {args.episodes}: must be at least 1'
    if not 0.0 <= args.speed <= 1000.0:
        return f'--speed {args.speed}: must be in [0, 1000] (0 = as fast as possible)'
    if not 0 <= args.seed < 2**31:
        return f'--seed {args.seed}: must be in [0, 2^31)'
    if args.block < 1:
        return f'--block {args.block}: must be at least 1'
    if not math.isfinite(args.time_limit) or args.time_limit < 0:
        return f'--time-limit {args.time_limit}: must be >= 0 minutes'
    if args.max_restarts < 0:
        return f'--max-restarts {args.max_restarts}: must be >= 0'
    if not 0 < args.startup_timeout < math.inf:
        return f'--startup-timeout {args.startup_timeout}: must be > 0 seconds'
    top = 99 - max(REALTIME_ABOVE.values())
    if not 0 <= args.realtime <= top:
        return (f'--realtime {args.realtime}: must be in [1, {top}] (SCHED_FIFO priority of the '
                f'modules; the simulator and the arbiter run above it; 0 = off)')
    if args.robot == 'bridge':
        if args.single_process:
            return '--single-process runs the simulator only: not with --robot bridge'
        if args.speed == 0:
            args.speed = 1.0              # the robot's clock does not wait: real time
        if args.device != 'emulator':
            if args.speed != 1.0:
                return f'--speed {args.speed}: a real robot runs at real time (only the ' \
                       'emulator runs faster)'
            if error := _check_device(args.device):
                return f'--device {args.device}: {error}'
    for opt, path in (('--out', args.out), ('--record', args.record)):
        if path is not None and path.exists() and not path.is_dir():
            return f'{opt} {path}: exists and is not a folder'
    from cr_sim.core.arena import load_arena
    from cr_sim.core.params import ConfigError

    from clis_learner.core.config import check_params_file, load_clis_params
    try:
        arena = load_arena(args.arena or None)
    except (ConfigError, OSError) as exc:
        return f'--arena {args.arena}: {_strip(exc, args.arena)}'
    clis_keys: dict[str, Any] = {}
    for f in args.params:
        try:
            flat = check_params_file(f)
        except (ConfigError, OSError) as exc:
            return f'--params {f}: {_strip(exc, f)}'
        try:
            _check_param_values(flat, args.robot)
        except (ConfigError, ValueError) as exc:
            return f'--params {f}: {exc}'
        clis_keys.update(flat)
    args.first_episode, args.sim_state, args.version = 1, '', 0
    if args.resume is None:
        return None
    from clis_modules.core.modules import arena_map, make_modules

    from clis_learner.core.checkpoint import CheckpointError, load_checkpoint
    from clis_learner.core.config import params_hash
    clis = load_clis_params(overrides={k: v for k, v in clis_keys.items()
                                       if k in _clis_keys()} or None)
    try:
        meta = load_checkpoint(args.resume, make_modules(clis, args.condition,
                                                         *arena_map(arena)),
                               params_hash(clis))
    except CheckpointError as exc:
        return f'--resume {args.resume}: {_strip(exc, args.resume)}' + (
            f' (the learner of --condition {args.condition} with these parameters cannot '
            'start from it)' if args.resume.is_file() else '')
    extra = meta.get('extra', {})
    for key in ('condition', 'seed'):
        if key in extra and extra[key] != getattr(args, key):
            return f'--resume {args.resume}: a checkpoint of --{key} {extra[key]}, not ' \
                   f'{getattr(args, key)}'
    args.first_episode = int(extra.get('episode', 0)) + 1
    args.sim_state = str(extra.get('sim_state', ''))
    args.version = int(extra.get('version', 0))
    return None


def _check_param_values(flat: dict[str, Any], robot: str) -> None:
    """The values of a ``--params`` file for the nodes' own sections (``config/graph.yaml``,
    the robot interface's ``node`` and sections of ``sim.yaml`` / ``bridge.yaml``), checked as
    each node will (the CLIS keys are checked by the config loader): ConfigError naming the
    key and its range."""
    from clis_modules.arbiter_node import ArbiterNodeParams
    from clis_modules.graph_node import GraphParams
    from clis_modules.module_node import ModuleNodeParams
    from cr_bridge.bridge_node import BridgeNodeParams
    from cr_bridge.core.episode import ContactParams
    from cr_sim.core.params import (
        ConfigError,
        build,
        config_dir,
        flatten,
        ros_parameters,
        unflatten,
    )
    from cr_sim.core.sim import IGNORED_SECTIONS, load_sim_params
    from cr_sim.sim_node import SimNodeParams

    from clis_learner.learner_node import LearnerNodeParams
    from clis_learner.recorder_node import RecorderParams
    files = {'graph.yaml': ('/**', {'graph': GraphParams, 'module': ModuleNodeParams,
                                    'arbiter_node': ArbiterNodeParams,
                                    'learner_node': LearnerNodeParams,
                                    'recorder': RecorderParams})}
    if robot == 'bridge':
        files['bridge.yaml'] = ('bridge', {'node': BridgeNodeParams, 'contact': ContactParams})
    else:
        files['sim.yaml'] = ('sim', {'node': SimNodeParams})
    for name, (node, sections) in files.items():
        data = ros_parameters(config_dir() / name, node)
        for section, cls in sections.items():
            values = flatten(data[section])
            given = {k[len(section) + 1:]: v for k, v in flat.items()
                     if k.startswith(section + '.') and k[len(section) + 1:] in values}
            if given:
                build(cls, unflatten({**values, **given}), where=section)
    sim = flatten({k: v for k, v in ros_parameters(config_dir() / 'sim.yaml', 'sim').items()
                   if k not in IGNORED_SECTIONS})
    given = {k: v for k, v in flat.items() if k in sim}
    if given:
        try:
            load_sim_params(overrides=given)
        except ConfigError as exc:
            raise ConfigError(_strip(exc, config_dir() / 'sim.yaml').removeprefix('sim.')) \
                from None


def _clis_keys() -> set[str]:
    from cr_sim.core.params import config_dir, flatten, ros_parameters

    from clis_learner.core.config import CLIS_NODE
    return set(flatten(ros_parameters(config_dir() / 'clis.yaml', CLIS_NODE)))


def _strip(exc: Exception, path: Any) -> str:
    """An error's text without a leading ``PATH: `` (the option's line names the path)."""
    return str(exc).removeprefix(f'{path}: ')


def _check_device(url: str) -> str | None:
    """Why the robot's link ``url`` is malformed (None if it is not): udp://HOST:PORT, a
    serial device that exists, or a pyserial URL (SCHEME://...)."""
    from urllib.parse import urlsplit
    if url.startswith('udp://'):
        from cr_bridge.transport import parse_udp
        try:
            parse_udp(url)
        except ValueError:
            return 'expected udp://HOST:PORT'
        return None
    if '://' in url:
        scheme = urlsplit(url).scheme
        if scheme not in ('socket', 'rfc2217', 'loop', 'spy', 'alt', 'hwgrep', 'cp2110'):
            return f'unknown link scheme {scheme!r} (udp, socket, rfc2217, loop...)'
        return None
    if not Path(url).exists():
        return 'no such serial device'
    return None


def _keep_rows_until(path: Path, episode: int) -> int:
    """Drop the rows of ``episodes.csv`` after ``episode`` (written after the checkpoint a run
    resumes from: they are run again); how many were dropped."""
    if not path.is_file():
        return 0
    with open(path, newline='') as fh:
        rows = list(csv.reader(fh))
    if not rows or 'episode' not in rows[0]:
        return 0
    col = rows[0].index('episode')
    keep = [rows[0]] + [r for r in rows[1:] if r and float(r[col]) <= episode]
    if len(keep) == len(rows):
        return 0
    tmp = path.with_suffix('.csv.tmp')
    with open(tmp, 'w', newline='') as fh:
        csv.writer(fh).writerows(keep)
    os.replace(tmp, path)
    return len(rows) - len(keep)


def main(args: argparse.Namespace) -> int:
    error = _check_args(args)
    if error:                                     # one line (a YAML error spans several)
        error = ' '.join(s.strip() for s in error.splitlines() if s.strip())
        print(f'clis run: {error}', file=sys.stderr)
        return EXIT_CONFIG
    if args.out is None:
        args.out = Path('results/run') / (f'{args.condition}-seed{args.seed}-'
                                          f'{time.strftime("%Y%m%d-%H%M%S")}')
    out = args.out.resolve()
    if (out / 'episodes.csv').is_file() and args.resume is None:
        print(f'clis run: --out {out} already holds a run: continue it with --resume '
              f'{out / "checkpoint.npz"}, or choose another --out', file=sys.stderr)
        return EXIT_CONFIG
    # the graph's nodes (and this process's monitor) pass their data through shared memory
    from clis_learner.ros_env import use_graph_profile
    use_graph_profile()
    plan = plan_graph(args.condition, args.seed, out, args.speed,
                      str(args.resume.resolve()) if args.resume else '', args.arena,
                      args.robot, args.device,
                      str(args.record.resolve()) if args.record else '', args.realtime,
                      args.first_episode, args.sim_state, args.version + args.episodes)
    if args.foxglove_wait and args.foxglove is None:
        print('clis run: --foxglove-wait waits for a client of the live view: add --foxglove '
              '[PORT]', file=sys.stderr)
        return EXIT_CONFIG
    if args.foxglove is not None:                    # the live view (docs/foxglove.md)
        from clis_learner.foxglove_node import plan_live_view
        if error := plan_live_view(plan, args):
            print(f'clis run: {error}', file=sys.stderr)
            return EXIT_CONFIG
    out.mkdir(parents=True, exist_ok=True)              # every input checked: now write
    tty = sys.stderr.isatty() and not args.quiet

    def say(text: str) -> None:
        print(('\r\033[K' if tty else '') + text, file=sys.stderr, flush=True)

    if args.first_episode > 1 and (n := _keep_rows_until(out / 'episodes.csv',
                                                         args.first_episode - 1)):
        say(f"clis run: {n} rows of episodes.csv after the checkpoint's episode "
            f'{args.first_episode - 1} dropped (run again)')

    say(f'clis run: {args.condition}, seed {args.seed}, {args.episodes} episodes, '
        + (f'from episode {args.first_episode}, ' if args.first_episode > 1 else '')
        + (f'robot bridge ({args.device}), ' if args.robot == 'bridge' else '') +
        f'speed {"max" if args.speed == 0 else f"x{args.speed:g}"}, ROS_DOMAIN_ID '
        f'{os.environ.get("ROS_DOMAIN_ID")}, out {out}')
    if args.single_process:
        from clis_learner.graph_single import run_single
        code = run_single(plan, args, out, say)
    else:
        code = _run_processes(plan, args, out, say, tty)
    curve = write_curve(out, args.block)
    if curve is not None:
        say(summary(out, args.block))
        say(f'learning curve: {curve[0]}, {curve[1]}')
    return code


def summary(out: Path, block: int) -> str:
    """A few lines on the run from ``OUT/episodes.csv``: successes early and late, who acted."""
    with open(out / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    n = len(rows)
    k = max(1, min(block, n // 2 or 1))
    first = sum(int(float(r['reached'])) for r in rows[:k])
    last = sum(int(float(r['reached'])) for r in rows[-k:])
    names = [c[len('share_'):] for c in rows[0] if c.startswith('share_')]
    shares = ', '.join(f'{m} {np.mean([float(r[f"share_{m}"]) for r in rows[-k:]]):.0%}'
                       for m in names)
    lost = sum(r.get('complete', '1') == '0' for r in rows)
    return (f'summary: {n} episodes learned; reached {first}/{k} in the first {k}, '
            f'{last}/{k} in the last {k}; who acted in the last {k}: {shares}'
            + (f'; WARNING: {lost} episodes lost reward messages (see logs/learner.log)'
               if lost else ''))


def lockstep_timeouts(out: Path) -> int:
    """How often the simulator or the arbiter stopped waiting for a late node (their logs)."""
    n = 0
    for name, marker in (('sim', 'the clock runs free'), ('arbiter', 'did not propose')):
        path = out / 'logs' / f'{name}.log'
        if path.is_file():
            n += path.read_text(errors='replace').count(marker)
    return n


def _run_processes(plan: GraphPlan, args: argparse.Namespace, out: Path, say,
                   tty: bool) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init(args=['clis_run', '--ros-args', '--disable-rosout-logs'],
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    # SIGINT/SIGTERM remembered (clis_learner.ctrl_c); a Ctrl-C since the command started
    # counts too, even one whose KeyboardInterrupt was swallowed where it was raised
    interrupted = ctrl_c.interrupted
    old = signal.signal(signal.SIGINT, lambda signum, _: ctrl_c.remember(signum))
    signal.signal(signal.SIGTERM, lambda signum, _: ctrl_c.remember(signum))
    sup = Supervisor(plan, out, args.params, args.max_restarts, say)
    monitor = Monitor()
    code = EXIT_OK
    try:
        graph = [c for c in plan.children[:-1] if c.args is None]
        for child in graph:                            # everything but the robot interface
            sup.start(child)
        deadline = time.monotonic() + args.startup_timeout
        missing = monitor.up([c.name for c in graph])
        while missing and not interrupted():
            if (code := sup.check()) is not None:
                return code
            if time.monotonic() > deadline:
                say(f'clis run: {", ".join(missing)} did not come up within '
                    f'{args.startup_timeout} s (see {out}/logs)')
                return EXIT_STARTUP
            monitor.spin(0.1)
            missing = monitor.up([c.name for c in graph])
        for child in plan.children:                    # the robot interface (and its device)
            if child not in graph:
                sup.start(child)
        view = ProgressView(args.episodes, args.block, args.quiet, tty, args.time_limit)
        while not interrupted():
            monitor.spin(0.1)
            if (code := sup.check()) is not None:
                return code
            if view.update(monitor.rows):
                break
        if interrupted():
            code = EXIT_INTERRUPTED
            say('clis run: interrupted, stopping the graph')
        else:
            say(f'clis run: {view.summary()}')
        if n := lockstep_timeouts(out):
            say(f'clis run: warning: {n} lockstep timeouts (a node was late; the run then '
                f'differs from the headless runner): see {out}/logs')
    except ExternalShutdownException:
        code = EXIT_INTERRUPTED
    finally:
        sup.stop()
        monitor.node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGINT, old)
    return code
