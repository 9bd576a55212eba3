"""``clis run``: start the CLIS node graph on the simulator and learn live.

The graph is the robot interface (``cr_sim sim``; the real robot's bridge later), one node per
module of the condition (``clis_modules module``, named after its instance), the arbiter and
the learner, each a separate process started exactly as ``ros2 run PKG EXE --ros-args ...``
would start it (the executables colcon installed in ``install/PKG/lib/PKG/``), all on the
loopback and on this run's own ``ROS_DOMAIN_ID``. The simulator runs under sim time
(``/clock``) as fast as the graph keeps up (``--speed 0``, default) or ``--speed X`` times
real time (1: real time); after each episode it holds its clock until the learner has learned
from it (``node.wait_for_learner``), as the real robot wanders to its next start while the
learner learns.

The parameters are config/clis.yaml with the ``--preset``'s file (default ``improved``, the
preset that learns; ``paper``: the rules exactly as printed) and the ``--params`` files, in that
order. While it runs, one line shows the learner's progress (from ``learner/progress``): learned
episodes, successes in the last block, who acted, Pr(i | x_0), the real-time factor; a module
whose values diverge (the learner's divergence guard, :mod:`clis_learner.core.guard`) is
reported there at once, in a line of its own, in the summary and on ``curve.png``. At the end
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
import math
import os
from pathlib import Path
import sys
import time
from typing import Any

from clis_learner.core.config import DEFAULT_PRESET, PRESET_NAMES
from clis_learner.core.episodes import keep_rows_until
from clis_modules.core.plugin import parse_condition

from clis_app.graph.curve import summary, write_curve
from clis_app.graph.plan import REALTIME_ABOVE, REALTIME_PRIORITY, plan_graph
from clis_app.graph.supervise import EXIT_CONFIG, run_processes

__all__ = ['register', 'main']

EPILOG = """examples:
  clis run --condition async --episodes 300                 # as fast as the graph keeps up
  clis run --condition async --episodes 300 --preset paper  # the paper's rules as printed
  clis run --condition view --episodes 50 --speed 5 --out results/run/view
  clis run --condition async --episodes 300 --resume results/run/async/checkpoint.npz
  clis run --condition sync --episodes 100 --params my_overrides.yaml
  sudo -E clis run --realtime ...  # sensor-to-command path under SCHED_FIFO (root or ulimit -r)
  ROS_DOMAIN_ID=7 clis run ...   # watch it: ros2 topic echo /arbiter/selection (same domain)
"""


def _condition(text: str) -> str:
    """``--condition``: a condition (:func:`clis_modules.core.plugin.parse_condition`)."""
    try:
        parse_condition(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'run', help='run the CLIS node graph on the simulator and learn live',
        description=__doc__, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--condition', default='async', type=_condition,
                   help='which modules run: TIMING:MODULE+MODULE... (async:innate+view+place+'
                        'wall) or innate, view, place, sync, async (default: %(default)s)')
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
    p.add_argument('--preset', default=DEFAULT_PRESET, choices=PRESET_NAMES(),
                   help='parameter preset, as clis experiment --preset: config/clis.yaml with '
                        'config/clis_PRESET.yaml given to every node before the --params files '
                        '(default %(default)s: the one that learns); paper = the rules exactly '
                        'as printed, whose values diverge in most runs (docs/results.md)')
    p.add_argument('--params', type=Path, action='append', default=[], metavar='FILE',
                   help='a ROS parameter file given to every node (--params-file), e.g. to '
                        'override config/clis.yaml keys under "/**: ros__parameters:"')
    p.add_argument('--resume', type=Path, help='start the learner from this checkpoint')
    p.add_argument('--out', type=Path, help='output folder (default results/run/PRESET-'
                   'CONDITION-seedS-DATE)')
    p.add_argument('--arena', type=str, default='', help='arena file (default config/arena.yaml)')
    p.add_argument('--robot', choices=('sim', 'bridge', 'ros'), default='sim',
                   help="the robot interface: the simulator (default), the Cyber Rodent's "
                        "bridge (cr_bridge), which runs on the robot's clock: real time, or "
                        "'ros': a robot already on the ROS graph (odom, scan, image_raw, "
                        'cmd_vel), driven by its --profile; the CLIS graph then runs in the '
                        'namespace /clis (docs/robots.md)')
    p.add_argument('--profile', default='', metavar='NAME',
                   help='with --robot ros: the robot profile, a name of config/robots (cr, '
                        'turtlebot4, husky) or a file')
    p.add_argument('--lockstep', action='store_true',
                   help='with --robot ros: the robot waits for the graph, holding its clock '
                        'at each camera frame until the cmd_vel that answers it (a simulator '
                        "that offers it: the Husky world's -p lockstep:=true); each decision is "
                        'then made on the frame of its instant, however loaded the host. Our '
                        'simulator (profile cr) always does')
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
    if args.robot == 'ros':
        if not args.profile:
            return '--robot ros drives a robot by its profile: add --profile NAME (cr, ' \
                   'turtlebot4, husky, or a file)'
        from clis_base.params import ConfigError
        from cr_sim.core.profile import load_profile
        try:
            robot = load_profile(args.profile)
        except ConfigError as exc:
            return f'--profile {args.profile}: {exc}'
        if args.single_process:
            return '--single-process runs the simulator only: not with --robot ros'
        if robot.simulator == 'cr_sim':
            args.lockstep = True              # our simulator waits for the graph, as ever
        elif args.speed != 0:
            return f"--speed {args.speed}: the robot's own clock sets the pace with --robot ros"
        if args.arena:
            return f"--arena {args.arena}: with --robot ros the arena is the profile's " \
                   '(its arena section)'
    elif args.profile:
        return f'--profile {args.profile}: only with --robot ros'
    elif args.lockstep:
        return '--lockstep: only with --robot ros (the simulator of --robot sim always waits ' \
               'for the graph)'
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
    from clis_base.params import ConfigError
    from clis_learner.core.config import check_params_file, load_clis_params
    from cr_sim.core.arena import load_arena
    try:
        arena = load_arena(args.arena or None)
    except (ConfigError, OSError) as exc:
        return f'--arena {args.arena}: {_strip(exc, args.arena)}'
    clis_keys: dict[str, Any] = {}
    from clis_learner.core.config import preset_path
    preset = preset_path(args.preset)           # checked by argparse's choices
    if preset is not None and preset not in args.params:
        args.params.insert(0, preset)           # the --params files override the preset
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
    # the CLIS keys of the --params files: the plan (periods, selection) is theirs too
    args.clis_overrides = {k: v for k, v in clis_keys.items() if k in _clis_keys()}
    args.first_episode, args.sim_state, args.version = 1, '', 0
    if args.resume is None:
        return None
    from clis_learner.core.checkpoint import CheckpointError, load_checkpoint
    from clis_learner.core.config import params_hash
    from clis_modules.core.modules import arena_map, make_modules
    overrides = dict(args.clis_overrides)
    if args.robot == 'ros':                 # the learner's keys and arena are the robot's
        from clis_base.params import flatten

        from clis_app.graph.robot_ros import robot_arena, robot_params
        overrides.update(flatten(robot_params(args.profile, args.clis_overrides)))
        arena = robot_arena(args.profile)
    clis = load_clis_params(overrides=overrides or None)
    try:
        meta = load_checkpoint(args.resume, make_modules(clis, args.condition,
                                                         *arena_map(arena)),
                               params_hash(clis))
    except CheckpointError as exc:
        return f'--resume {args.resume}: {_strip(exc, args.resume)}' + (
            f' (the learner of --condition {args.condition} with these parameters, --preset '
            f'{args.preset}, cannot start from it)' if args.resume.is_file() else '')
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
    the robot interface's ``node`` and sections of ``sim.yaml`` / ``bridge.yaml``, the body of
    ``robot.yaml``), checked as
    each node will (the CLIS keys are checked by the config loader): ConfigError naming the
    key and its range."""
    from clis_base.params import (
        ConfigError,
        build,
        config_dir,
        flatten,
        ros_parameters,
        unflatten,
    )
    from clis_base.ros.graph_node import GraphParams
    from clis_learner.learner_node import LearnerNodeParams
    from clis_modules.arbiter_node import ArbiterNodeParams
    from clis_modules.module_node import ModuleNodeParams
    from cr_bridge.bridge_node import BridgeNodeParams
    from cr_bridge.core.episode import ContactParams
    from cr_sim.core.robot import robot_defaults
    from cr_sim.core.sim import IGNORED_SECTIONS, load_sim_params
    from cr_sim.sim_node import SimNodeParams

    from clis_app.bags.recorder_node import RecorderParams
    files = {'graph.yaml': ('/**', {'graph': GraphParams, 'module': ModuleNodeParams,
                                    'arbiter_node': ArbiterNodeParams,
                                    'learner_node': LearnerNodeParams,
                                    'recorder': RecorderParams})}
    if robot == 'bridge':
        files['bridge.yaml'] = ('bridge', {'node': BridgeNodeParams, 'contact': ContactParams})
    elif robot == 'ros':
        from cr_bridge.robot_node import RobotNodeParams
        files['bridge.yaml'] = ('robot', {'node': RobotNodeParams})
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
    sim = flatten({**robot_defaults(),
                   **{k: v for k, v in ros_parameters(config_dir() / 'sim.yaml', 'sim').items()
                      if k not in IGNORED_SECTIONS}})
    given = {k: v for k, v in flat.items() if k in sim}
    if given:
        try:
            load_sim_params(overrides=given)
        except ConfigError as exc:
            raise ConfigError(_strip(exc, config_dir() / 'sim.yaml').removeprefix('sim.')) \
                from None


def _clis_keys() -> set[str]:
    from clis_base.params import config_dir, flatten, ros_parameters
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


def main(args: argparse.Namespace) -> int:
    error = _check_args(args)
    if error:                                     # one line (a YAML error spans several)
        error = ' '.join(s.strip() for s in error.splitlines() if s.strip())
        print(f'clis run: {error}', file=sys.stderr)
        return EXIT_CONFIG
    if args.out is None:
        slug = args.condition.replace(':', '-').replace('+', '_')
        args.out = Path('results/run') / (f'{args.preset}-{slug}-seed{args.seed}-'
                                          f'{time.strftime("%Y%m%d-%H%M%S")}')
    out = args.out.resolve()
    if (out / 'episodes.csv').is_file() and args.resume is None:
        print(f'clis run: --out {out} already holds a run: continue it with --resume '
              f'{out / "checkpoint.npz"}, or choose another --out', file=sys.stderr)
        return EXIT_CONFIG
    # the graph's nodes (and this process's monitor) pass their data through shared memory
    from clis_app.graph.ros_env import use_graph_profile
    use_graph_profile()
    if args.robot == 'ros':              # the layout and the features at the robot's size
        from clis_app.graph.robot_ros import robot_files
        args.arena, robot_params = robot_files(args.profile, out, write=False,
                                               overrides=args.clis_overrides)
    try:
        plan = plan_graph(args.condition, args.seed, out, args.speed,
                          str(args.resume.resolve()) if args.resume else '', args.arena,
                          args.robot, args.device,
                          str(args.record.resolve()) if args.record else '', args.realtime,
                          args.first_episode, args.sim_state, args.version + args.episodes,
                          args.clis_overrides, args.profile, getattr(args, 'lockstep', False))
    except ValueError as exc:                        # a module no plug-in or section names
        print(f'clis run: --condition {args.condition}: {exc}', file=sys.stderr)
        return EXIT_CONFIG
    if args.foxglove_wait and args.foxglove is None:
        print('clis run: --foxglove-wait waits for a client of the live view: add --foxglove '
              '[PORT]', file=sys.stderr)
        return EXIT_CONFIG
    if args.foxglove is not None:                    # the live view (docs/foxglove.md)
        from clis_app.graph.plan import plan_live_view
        if error := plan_live_view(plan, args):
            print(f'clis run: {error}', file=sys.stderr)
            return EXIT_CONFIG
    out.mkdir(parents=True, exist_ok=True)              # every input checked: now write
    if args.robot == 'ros' and robot_params is not None:
        robot_files(args.profile, out, overrides=args.clis_overrides)
        args.params = [*args.params, robot_params]
    tty = sys.stderr.isatty() and not args.quiet

    def say(text: str) -> None:
        print(('\r\033[K' if tty else '') + text, file=sys.stderr, flush=True)

    if args.first_episode > 1 and (n := keep_rows_until(out / 'episodes.csv',
                                                         args.first_episode - 1)):
        say(f"clis run: {n} rows of episodes.csv after the checkpoint's episode "
            f'{args.first_episode - 1} dropped (run again)')

    say(f'clis run: {args.condition}, {args.preset} preset, seed {args.seed}, '
        f'{args.episodes} episodes, '
        + (f'from episode {args.first_episode}, ' if args.first_episode > 1 else '')
        + (f'robot bridge ({args.device}), ' if args.robot == 'bridge' else '')
        + (f'robot {args.profile} on the ROS graph (CLIS in /clis), ' if args.robot == 'ros'
           else '') +
        f'speed {"max" if args.speed == 0 else f"x{args.speed:g}"}, ROS_DOMAIN_ID '
        f'{os.environ.get("ROS_DOMAIN_ID")}, out {out}')
    if args.single_process:
        from clis_app.graph.single import run_single
        code = run_single(plan, args, out, say)
    else:
        code = run_processes(plan, args, out, say, tty)
    curve = write_curve(out, args.block, args.preset)
    if curve is not None:
        say(summary(out, args.block, args.preset))
        say(f'learning curve: {curve[0]}, {curve[1]}')
    return code
