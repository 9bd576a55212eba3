"""The node graph of a ``clis run``: which children, started how, with which parameters.

:func:`plan_graph` lists the children of one run (:class:`GraphPlan`, in start order, the robot
interface last), each a :class:`Child`: its ``ros2 run`` executable and the parameters ``clis
run`` gives it. Nothing is started here (:mod:`clis_app.graph.supervise` starts them as
processes, :mod:`clis_app.graph.single` as nodes of one process).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
import subprocess
from typing import Any

__all__ = ['REALTIME_ABOVE', 'REALTIME_PRIORITY', 'Child', 'GraphPlan', 'plan_graph',
           'ros_literal']

#: ``clis run --realtime`` without a value: the SCHED_FIFO priority of the sensor-to-command
#: path (low among real-time priorities: the kernel's interrupt threads run at 50)
REALTIME_PRIORITY = 10
#: Under ``--realtime PRIO``, each node's SCHED_FIFO priority above PRIO, in the order of the
#: round trip's end: the modules at PRIO, the simulator (waiting for ``cmd_vel``) one above,
#: the arbiter two above. A proposal's arrival then preempts a module's work at the same
#: instant, and the command's arrival preempts both (measured by bench/bench_hops.py).
REALTIME_ABOVE = {'sim': 1, 'arbiter': 2}


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
    #: ROS remapping rules (``-r FROM:=TO``): a module instance's node name, ``__node:=NAME``
    remaps: dict[str, str] = field(default_factory=dict)
    #: Whether the node follows the ``episode`` events (``clis run`` waits for that
    #: subscription before the robot starts; the blob detector follows none)
    follows_episodes: bool = True

    def argv(self, params_files: list[Path]) -> list[str]:
        """``EXE --ros-args [--params-file F]... -p KEY:=VALUE ...`` (what ``ros2 run`` runs)."""
        from ament_index_python.packages import get_package_prefix
        exe = Path(get_package_prefix(self.package)) / 'lib' / self.package / self.executable
        if self.args is not None:
            return [str(exe), *self.args]
        args = [str(exe), '--ros-args']
        for key, value in self.remaps.items():
            args += ['-r', f'{key}:={value}']
        for f in params_files:
            args += ['--params-file', str(f)]
        for key, value in self.params.items():
            args += ['-p', f'{key}:={ros_literal(value)}']
        return args


def ros_literal(value: Any) -> str:
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
    #: The namespace of the CLIS graph: '' (the root), or ``/clis`` on a robot of the ROS graph
    #: (``--robot ros``), whose own topics (``odom``, ``cmd_vel``...) are at its root
    namespace: str = ''

    def by_name(self, name: str) -> Child:
        return next(c for c in self.children if c.name == name)


def plan_graph(condition: str, seed: int, out: Path, speed: float, resume: str = '',
               arena: str = '', robot: str = 'sim', device: str = 'emulator',
               record: str = '', realtime: int = 0, first_episode: int = 1,
               resume_state: str = '', learn_until: int = 0,
               clis_overrides: dict[str, Any] | None = None, profile: str = '',
               lockstep: bool = False) -> GraphPlan:
    """The nodes of ``condition``, with the parameters ``clis run`` gives each;
    ``realtime`` > 0: the sensor-to-command path (simulator, modules, arbiter) under
    ``SCHED_FIFO`` from that priority up (:data:`REALTIME_ABOVE`,
    :func:`clis_base.ros.process.realtime`); ``first_episode`` > 1: the number of
    the simulator's first episode (a resumed run), ``resume_state``: where its robot and clock
    stood (the checkpoint's ``sim_state``); ``learn_until`` > 0: the learner learns no
    episode that starts once that many are learned in all (``learner_node.episodes``);
    ``clis_overrides``: the CLIS keys of the run's ``--params`` files (dotted), which the nodes
    read too (the periods the simulator holds at, the arbiter's selection). ``robot`` 'ros':
    a robot already on the ROS graph, driven by its ``profile`` (:func:`_plan_ros`;
    ``lockstep``: the robot waits for the graph)."""
    from clis_learner.core.config import load_clis_params
    from clis_modules.core.arbiter import refuse_bonus
    from clis_modules.core.modules import condition_periods, condition_sensors
    clis = load_clis_params(overrides=clis_overrides or None, source='--params')
    refuse_bonus(clis.arbiter.bonus)
    periods = condition_periods(clis, condition)
    modules = [name for name, _ in periods]
    sensors = condition_sensors(clis, condition)
    graph = {'graph.condition': condition, 'graph.seed': seed, 'graph.arena_file': arena}
    plan = GraphPlan()
    if record:                                       # the bag recorder: up first, stops last
        # (its episode subscription, which the first episode waits for, once it has matched
        # the publishers of the modules and the arbiter: their first messages are in the bag)
        wait_for = [f'{m}/proposal' for m in modules] + ['arbiter/action', 'cmd_vel']
        plan.children.append(Child('recorder', 'clis_app', 'recorder', {
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
    for name in modules:                 # any plug-in: the generic module node, named
        plan.children.append(Child(name, 'clis_modules', 'module', {
            **graph, **priority('graph.realtime_priority', name)},
            remaps={'__node': name}))
    if robot == 'bridge':
        _plan_bridge(plan, seed, speed, arena, device, first_episode)
        return plan
    if robot == 'ros':
        # the adapter's first episode waits until DDS has matched the graph's subscribers of
        # its interface (as the simulator's: a reading sent before is lost to a module)
        nodes = len(modules) + 2 + bool(record)
        # (the modules read the IR as ir_ranges)
        readers = {t: sum(k in sensors[m] for m in modules)
                   for k, t in (('ir', 'ir_ranges'), ('wheels', 'wheels'))}
        matched = [f'episode:{nodes}', *(f'{t}:{n}' for t, n in readers.items() if n),
                   f'reward:{1 + bool(record)}', 'wheels_cmd:1', 'camera:1']
        _plan_ros(plan, seed, profile, speed, arena, [tau for _, tau in periods], lockstep,
                  first_episode, matched)
        return plan
    # the first episode waits until DDS has matched the graph's subscribers of the robot
    # interface (a message sent before is lost to them: the learner's first rewards, a
    # module's first readings): every node follows the episodes and the clock, the modules
    # that read the camera (their plug-ins' sensors) read it, the learner (and the recorder)
    # the rewards, the arbiter commands
    nodes = len(modules) + 2 + bool(record)
    cameras = sum('camera' in sensors[m] for m in modules)
    matched = [f'episode:{nodes}', f'/clock:{len(modules) + 2}',
               *([f'camera:{cameras}'] if cameras else []),
               f'reward:{1 + bool(record)}', 'wheels_cmd:1']
    plan.children.append(Child('sim', 'cr_sim', 'sim', {
        'node.seed': seed, 'node.arena_file': arena, 'node.speed_factor': float(speed),
        'node.start_subscribers': matched,
        # the arbiter's wheels as decided (cmd_vel's (v, w) is exact only to rounding)
        'node.command': 'wheels_cmd',
        'node.start': 'wander', 'node.auto_reset': True, 'node.wait_for_learner': True,
        'node.lockstep': True, 'node.lockstep_periods': [float(tau) for _, tau in periods],
        # the headless runner's readings (docs/design.md §6)
        'node.readings': 'instants',
        **({'node.first_episode': first_episode} if first_episode > 1 else {}),
        **({'node.resume_state': resume_state} if resume_state else {}),
        **priority('node.realtime_priority', 'sim')},
        restart='never'))
    return plan


def _plan_bridge(plan: GraphPlan, seed: int, speed: float, arena: str, device: str,
                 first_episode: int = 1) -> None:
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
        'node.start': 'wander', 'node.wait_for_learner': True,
        **({'node.first_episode': first_episode} if first_episode > 1 else {})},
        restart='never'))


#: The namespace of the CLIS graph on a robot of the ROS graph.
ROS_NAMESPACE = '/clis'


def hold_timeout() -> float:
    """How long our simulator as a world waits for a command [s wall]: its own
    ``node.command_timeout`` (``config/sim.yaml``), at least the robot adapter's
    ``node.learner_timeout`` (``config/bridge.yaml``: the longest it holds a frame while the
    learner learns)."""
    from clis_base.params import config_dir, ros_parameters
    sim = ros_parameters(config_dir() / 'sim.yaml', 'sim')['node']['command_timeout']
    robot = ros_parameters(config_dir() / 'bridge.yaml', 'robot')['node']['learner_timeout']
    return max(float(sim), float(robot))


def _plan_ros(plan: GraphPlan, seed: int, profile: str, speed: float = 1.0,
              arena: str = '', periods: Sequence[float] = (), lockstep: bool = False,
              first_episode: int = 1, matched: Sequence[str] = ()) -> None:
    """A robot already on the ROS graph (its ``odom``, ``scan``, ``image_raw`` and
    ``camera_info`` at the root or under its profile's namespace; ``cmd_vel`` taken): the CLIS
    graph in :data:`ROS_NAMESPACE`, with the blob detector (the robot's image to the ``camera``
    bearings) and the robot adapter (cr_bridge ``robot``: the robot interface from the robot's
    own sensors, episodes and safety) as the robot interface. The adapter and the CLIS nodes
    follow the robot's ``/clock`` (the detector stamps with its frames). The robot does not
    wait for the graph unless ``lockstep`` (a robot that holds its clock at each camera frame
    until the ``cmd_vel`` answering it: the adapter's ``node.lockstep``, at the condition's
    decision ``periods``). A profile whose robot is our simulator (its ``simulator:
    cr_sim``): the simulator too, at the root, as a plain world (``node.episodes`` false: the
    adapter makes the episodes) that publishes its camera image (``node.standard_topics``), at
    ``speed``, always in lockstep (as under ``--robot sim``), its first tick once the detector
    and the adapter have matched its topics. ``first_episode`` > 1: the adapter numbers its
    episodes from there (a run that goes on from a checkpoint). ``matched``: the adapter's
    first episode waits for these ``'TOPIC:COUNT'`` of its interface (its
    ``node.start_subscribers``)."""
    from cr_sim.core.profile import load_profile
    plan.namespace = ROS_NAMESPACE
    for child in plan.children:
        child.remaps['__ns'] = ROS_NAMESPACE
    robot = load_profile(profile)
    if robot.simulator == 'cr_sim':                  # the robot: the simulator, at the root
        lockstep = True
        top = robot.topics
        plan.children.append(Child('sim', 'cr_sim', 'sim', {
            'node.episodes': False, 'node.standard_topics': True,
            'node.speed_factor': float(speed), 'node.seed': seed, 'node.arena_file': arena,
            'node.start': 'A', 'node.lockstep': True,
            'node.command_timeout': hold_timeout(),
            'node.start_subscribers': [f'{top.image}:1', f'{top.scan}:1', f'{top.odom}:1',
                                       f'{top.cmd_vel}:1']},
            restart='never', follows_episodes=False))
    # (the detector stamps what it finds with its frame: it reads no clock, so it follows no
    # /clock either, and is not woken at every tick)
    plan.children.append(Child('detector', 'clis_modules', 'detector', {
        'profile': profile, 'overlay': False},       # the overlay only for a subscriber
        remaps={'__ns': ROS_NAMESPACE},
        follows_episodes=False))
    plan.children.append(Child('robot', 'cr_bridge', 'robot', {
        'node.profile': profile, 'node.seed': seed, 'node.wait_for_learner': True,
        'node.lockstep': bool(lockstep),
        'node.decision_periods': [float(p) for p in periods] or [0.0],
        'node.start_subscribers': list(matched),
        **({'node.first_episode': first_episode} if first_episode > 1 else {}),
        'use_sim_time': True}, remaps={'__ns': ROS_NAMESPACE}, restart='never'))


def plan_live_view(plan: Any, args: Any) -> str | None:
    """Add the live view to the children of a ``clis run`` (``--foxglove PORT``): one more
    process, up before the robot interface and stopped last (as the recorder). An error text
    for a bad port or ``--single-process``; else None."""
    from clis_app.live.layout import LAYOUT_FILE
    if not 1 <= args.foxglove <= 65535:
        return f'--foxglove {args.foxglove}: a TCP port in [1, 65535]'
    if getattr(args, 'single_process', False):
        return '--foxglove runs the live view as a process of its own: not with --single-process'
    graph = {k: v for k, v in plan.children[0].params.items() if k.startswith('graph.')}
    plan.children.insert(0, Child('foxglove', 'clis_app', 'foxglove', {
        **graph, 'foxglove.port': int(args.foxglove), 'foxglove.block': int(args.block),
        'foxglove.layout': str(Path(args.out).resolve() / LAYOUT_FILE)}, stop_last=True))
    # the simulator's first episode also waits for the view's subscription of the episode
    # events (made once it has discovered the simulator): a short run on a fast host could
    # otherwise end before the view had discovered it, and show nothing of the robot (seen in
    # a fresh-clone make test). With --foxglove-wait, also for its odom subscription, made
    # once a client watches every shown topic (foxglove.wait_for_client: _client_ready)
    recording = any(c.name == 'recorder' for c in plan.children)
    wait = bool(getattr(args, 'foxglove_wait', False))
    plan.children[0].params['foxglove.wait_for_client'] = wait
    from cr_sim.interface import parse_counts
    for child in plan.children:
        subs = child.params.get('node.start_subscribers') if child.name == 'sim' else None
        if subs:
            counts = parse_counts(tuple(subs), 'sim.node.start_subscribers')
            counts['episode'] = counts.get('episode', 0) + 1
            if wait:
                counts['odom'] = counts.get('odom', 0) + 1 + recording
            child.params['node.start_subscribers'] = [f'{t}:{n}' for t, n in counts.items()]
    return None
