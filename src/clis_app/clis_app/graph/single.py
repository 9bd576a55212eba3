"""``clis run --single-process``: every node of the graph in one process and one executor.

Like a ROS 2 component container: the same node classes as the ``ros2 run`` executables, with
the same parameters (one ``--ros-args`` list, each node declaring only its own keys), served by
one ``SingleThreadedExecutor`` that the simulator's pacing loop (:func:`cr_sim.sim_node.run`)
spins. Messages between the nodes still go through Fast DDS (rclpy has no intra-process path).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import signal
import sys

__all__ = ['run_single']


def run_single(plan, args: argparse.Namespace, out: Path, say) -> int:
    """Run ``plan`` (a :class:`clis_app.graph.plan.GraphPlan`) in this process; an exit
    code."""
    from clis_base.params import ConfigError
    from clis_base.ros.executor import make_executor
    from clis_base.ros.process import realtime, settle_heap
    from clis_base.trace import dump as dump_trace
    from clis_learner.learner_node import LearnerNode
    from clis_modules.arbiter_node import ArbiterNode
    from clis_modules.module_node import ModuleNode
    from cr_sim.sim_node import SimNode, run
    import rclpy
    from rclpy.clock import Clock, ClockType

    from clis_app.bags.recorder_node import RecorderNode
    from clis_app.cli import ctrl_c
    from clis_app.graph.plan import ros_literal
    from clis_app.graph.progress import Monitor, ProgressView
    from clis_app.graph.supervise import EXIT_CONFIG, EXIT_INTERRUPTED, EXIT_OK

    ros_args = ['clis_run', '--ros-args']
    for f in args.params:
        ros_args += ['--params-file', str(f)]
    for child in plan.children:
        for key, value in child.params.items():
            ros_args += ['-p', f'{key}:={ros_literal(value)}']
    rclpy.init(args=ros_args)
    # a Ctrl-C is remembered (clis_app.cli.ctrl_c, since the command started): one that lands
    # in rclpy's C++ (taking a message) comes out as another error (pybind11's RuntimeError),
    # which is then an interruption too, not a crash; one swallowed where it was raised still
    # stops the run (the wall timer below)
    signal.signal(signal.SIGINT, ctrl_c.handler)
    interrupted = ctrl_c.interrupted
    factories = {'learner': LearnerNode, 'arbiter': ArbiterNode, 'sim': SimNode,
                 'recorder': RecorderNode}
    nodes = []
    try:
        for child in plan.children:
            factory = factories.get(child.name)
            nodes.append(factory() if factory else ModuleNode(child.name))
    except BaseException as exc:                 # a bad parameter, or Ctrl-C
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if interrupted():
            raise KeyboardInterrupt from None
        if isinstance(exc, (ConfigError, ValueError)):
            say(f'clis run: bad parameter: {exc}')
            return EXIT_CONFIG
        raise
    state = {'code': EXIT_OK}
    monitor = view = None
    try:                                         # (a Ctrl-C from here on: a clean stop)
        executor = make_executor(next(n.graph.executor for n in nodes if hasattr(n, 'graph')))
        monitor = Monitor()
        view = ProgressView(args.episodes, args.block, args.quiet,
                            sys.stderr.isatty() and not args.quiet, args.time_limit,
                            out / 'episodes.csv')

        def on_wall() -> None:
            if interrupted():
                # a Ctrl-C whose KeyboardInterrupt was swallowed where it was raised (a gc
                # callback, a __del__: "Exception ignored in ..."): the run still stops (seen
                # in the test process, where hypothesis has a gc callback: the run went on to
                # its last episode)
                state['code'] = EXIT_INTERRUPTED
                rclpy.try_shutdown()
            elif view.update(monitor.rows):
                rclpy.try_shutdown()             # ends the simulator's loop

        monitor.node.create_timer(0.2, on_wall, clock=Clock(clock_type=ClockType.STEADY_TIME))
        for node in [*nodes, monitor.node]:
            executor.add_node(node)
        settle_heap()
        if nodes[-1].cfg.realtime_priority:      # one process: the learner's thread too
            ok, said = realtime(nodes[-1].cfg.realtime_priority)
            say(f'clis run: {said}')
        run(nodes[-1], executor)                 # the simulator is the plan's last child
    except KeyboardInterrupt:
        state['code'] = EXIT_INTERRUPTED
    except Exception as exc:  # noqa: BLE001 - reported, then the graph is stopped
        if interrupted():
            state['code'] = EXIT_INTERRUPTED
        elif rclpy.ok():
            raise
        del exc
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        for node in nodes:
            close = getattr(node, 'close', None)
            if callable(close):
                close()
            node.destroy_node()
        if monitor is not None:
            monitor.node.destroy_node()
        rclpy.try_shutdown()
        dump_trace('graph')
        signal.signal(signal.SIGINT, signal.default_int_handler)
    say(f'clis run: {"interrupted" if state["code"] else view.summary()}')
    return state['code']
