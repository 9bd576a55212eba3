"""``clis run``'s children as processes: started, watched, restarted, stopped.

:class:`Supervisor` starts each :class:`~clis_app.graph.plan.Child` as its ``ros2 run``
executable (its output to ``OUT/logs/NAME.log``), restarts a module, the arbiter or the
learner that died (the learner from its checkpoint), and stops them all in order: the robot
interface first, the learner (and the recorder, the live view) last.
:func:`run_processes` runs a whole plan that way while :class:`~clis_app.graph.progress.Monitor`
follows the learner. The exit codes of ``clis run`` are defined here.
"""

from __future__ import annotations

import argparse
import ctypes
from pathlib import Path
import signal
import subprocess
import time

from clis_app.cli import ctrl_c
from clis_app.graph.plan import Child, GraphPlan
from clis_app.graph.progress import Monitor, ProgressView

__all__ = ['EXIT_CHILD', 'EXIT_CONFIG', 'EXIT_INTERRUPTED', 'EXIT_OK', 'EXIT_STARTUP',
           'Supervisor', 'lockstep_timeouts', 'run_processes']

#: Exit codes of ``clis run``: done; a child died and could not be restarted; bad arguments
#: or a bad parameter; the graph did not come up; interrupted (Ctrl-C), after a clean stop.
EXIT_OK, EXIT_CHILD, EXIT_CONFIG, EXIT_STARTUP, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


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


def lockstep_timeouts(out: Path) -> int:
    """How often the simulator or the arbiter stopped waiting for a late node (their logs)."""
    n = 0
    for name, marker in (('sim', 'the clock runs free'), ('arbiter', 'did not propose')):
        path = out / 'logs' / f'{name}.log'
        if path.is_file():
            n += path.read_text(errors='replace').count(marker)
    return n


def run_processes(plan: GraphPlan, args: argparse.Namespace, out: Path, say,
                   tty: bool) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init(args=['clis_run', '--ros-args', '--disable-rosout-logs'],
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    # SIGINT/SIGTERM remembered (clis_app.cli.ctrl_c); a Ctrl-C since the command started
    # counts too, even one whose KeyboardInterrupt was swallowed where it was raised
    interrupted = ctrl_c.interrupted
    old = signal.signal(signal.SIGINT, lambda signum, _: ctrl_c.remember(signum))
    old_term = signal.signal(signal.SIGTERM, lambda signum, _: ctrl_c.remember(signum))
    sup = Supervisor(plan, out, args.params, args.max_restarts, say)
    monitor = Monitor(plan.namespace)
    code = EXIT_OK
    try:
        graph = [c for c in plan.children[:-1] if c.args is None]
        for child in graph:                            # everything but the robot interface
            sup.start(child)
        deadline = time.monotonic() + args.startup_timeout
        followers = [c.name for c in graph if c.follows_episodes]
        missing = monitor.up(followers)
        while missing and not interrupted():
            if (code := sup.check()) is not None:
                return code
            if time.monotonic() > deadline:
                say(f'clis run: {", ".join(missing)} did not come up within '
                    f'{args.startup_timeout} s (see {out}/logs)')
                return EXIT_STARTUP
            monitor.spin(0.1)
            missing = monitor.up(followers)
        # (the table's rows counted before the robot interface starts its first episode)
        view = ProgressView(args.episodes, args.block, args.quiet, tty, args.time_limit,
                            out / 'episodes.csv')
        for child in plan.children:                    # the robot interface (and its device)
            if child not in graph:
                sup.start(child)
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
        signal.signal(signal.SIGTERM, old_term)
    return code
