"""Running an experiment's runs in worker processes on this machine (``--backend process``),
with one progress line for all of them.

:func:`_run_all` starts ``--workers`` processes (forked after the compiled kernels are loaded
once), each running one run after another (:func:`~clis_app.experiments.runner.run_job`) and
saving it as it finishes; :class:`Progress` shows the state of all runs on one line with an ETA
weighed by each condition's cost. Ctrl-C stops the workers and loses only the runs in flight
(:func:`_worker_signals`). Ray's backend (:mod:`clis_app.experiments.ray_backend`) reports to
the same :class:`Progress`.
"""

from __future__ import annotations

from dataclasses import dataclass
import multiprocessing as mp
import queue
import signal
import sys
import time
from typing import Any

from clis_modules.core.plugin import parse_condition

from clis_app.experiments.runner import JobSpec, run_job, warm_up

__all__ = ['Progress', 'RunError', '_run_all', '_worker_signals', 'job_costs', 'longest_first']

#: Relative cost of an episode per condition, to start the longest runs first (measured per
#: learned run of 1000 episodes: Async 38-41 s, Sync 32, Place 22,
#: View 8, Innate 7 CPU-s; the place module's localization makes the last three the slow ones).
_COST = {'innate': 1.0, 'view': 1.0, 'place': 3.0, 'sync': 4.5, 'async': 5.5}


def _cost(condition: str) -> float:
    """:data:`_COST` of a condition; of another set of modules, the sum of its modules'
    (1 for a module not measured)."""
    if condition in _COST:
        return _COST[condition]
    try:
        return sum(_COST.get(m, 1.0) for m in parse_condition(condition).modules)
    except ValueError:
        return 1.0


def job_costs(specs: list[JobSpec]) -> list[tuple[int, float]]:
    """``(episodes, relative cost of an episode)`` of each spec, for :class:`Progress`."""
    return [(s.episodes, _cost(s.condition)) for s in specs]


def longest_first(specs: list[JobSpec]) -> list[JobSpec]:
    """``specs`` with the most expensive runs first (stable): on a few workers the last runs
    then are short ones, and no worker waits idle for a long one to finish. The order does not
    change any result (every run is seeded on its own)."""
    return sorted(specs, key=lambda s: -_cost(s.condition)
                  * (s.episodes + 5 * s.eval_episodes))           # 5 starts A-E


@dataclass
class Progress:
    """Prints one line with the state of all runs, at most every ``every`` seconds.

    ``cost``: each job's ``(episodes, relative cost of an episode)`` (:func:`_cost`), in job
    order; the ETA then weighs each run's episodes by it (the runs go longest first, so an
    ETA by episodes alone starts at about twice the time left). Without it, by episodes."""

    total_episodes: int
    runs: int
    quiet: bool = False
    every: float = 2.0
    cost: list[tuple[int, float]] | None = None

    def __post_init__(self) -> None:
        self.t0 = time.monotonic()
        self.last = 0.0
        self.done_eps: dict[int, int] = {}
        self.finished = 0
        self.note = ''
        self.tty = sys.stderr.isatty()
        self.warnings: list[str] = []

    def update(self, job: int, episodes: int, note: str) -> None:
        self.done_eps[job] = episodes
        if note.startswith('WARNING'):
            # the divergence guard's report of a run: a line of its own, even --quiet
            print(('\r' + ' ' * 160 + '\r' if self.tty else '') + note, file=sys.stderr,
                  flush=True)
            self.warnings.append(note)
            return
        self.note = note
        self.show()

    def finish(self, job: int, episodes: int, note: str) -> None:
        self.done_eps[job] = episodes
        self.finished += 1
        self.note = note
        self.show(force=True)

    def show(self, force: bool = False) -> None:
        now = time.monotonic()
        if self.quiet or (not force and now - self.last < self.every):
            return
        self.last = now
        done = sum(self.done_eps.values())
        frac = done / max(self.total_episodes, 1)
        work = frac
        if self.cost:
            total = sum(n * c for n, c in self.cost)
            work = sum(eps * self.cost[j][1] for j, eps in self.done_eps.items()) / total
        elapsed = now - self.t0
        eta = elapsed * (1 - work) / work if work > 0 else float('nan')
        bar = '#' * int(30 * frac) + '.' * (30 - int(30 * frac))
        line = (f'[{bar}] {done}/{self.total_episodes} episodes, {self.finished}/{self.runs} '
                f'runs, {elapsed / 60:.1f} min, ETA {eta / 60:.1f} min | {self.note}')
        print(('\r' + line[:160].ljust(160)) if self.tty else line, end='' if self.tty else '\n',
              file=sys.stderr, flush=True)


def _worker(spec: JobSpec, q) -> str:
    def report(episodes: int, note: str) -> None:
        q.put(('progress', spec.index, episodes, note))
    result = run_job(spec, progress=report)
    path = result.save()
    q.put(('done', spec.index, spec.episodes, f'{spec.label} seed {spec.seed} done'))
    return str(path)


class RunError(RuntimeError):
    """A run's process raised (the message holds its traceback) or died without finishing."""


def _run_all(todo: list[JobSpec], workers: int, quiet: bool,
             progress: Progress | None = None) -> None:
    """Run ``todo`` in up to ``workers`` processes at once, one process per run, each run saved
    as it finishes; ``progress`` (default: a :class:`Progress` line) gets each run's progress
    and its end, after its result file is written.

    On an exception here (a Ctrl-C, a run that failed) every run process still alive is
    killed before it propagates: its run is lost, never half-written (results are written
    atomically). A process per run, not a ``multiprocessing.Pool``: a pool's termination
    acquires its task queue's lock, which an idle worker holds while it waits for a task, so
    a worker killed at that moment (one that survived SIGTERM, say) left the termination
    waiting forever. Here nothing the parent waits on is shared with a process it kills."""
    if progress is None:
        progress = Progress(total_episodes=sum(s.episodes for s in todo), runs=len(todo),
                            quiet=quiet, cost=job_costs(todo))
    ctx = mp.get_context('fork' if sys.platform.startswith('linux') else 'spawn')
    if ctx.get_start_method() == 'fork':
        warm_up(todo[0])          # compiled kernels loaded once, inherited by every run
    q = ctx.Queue()               # (kind, index, episodes, note) from the runs
    remap = {s.index: k for k, s in enumerate(todo)}
    waiting = list(todo)
    running: dict[int, Any] = {}
    finished: set[int] = set()

    def handle(kind: str, index: int, episodes: int, note: str) -> None:
        if kind == 'error':
            spec = todo[remap[index]]
            raise RunError(f'{spec.label} seed {spec.seed} failed:\n{note}')
        if kind == 'done':
            finished.add(index)
            progress.finish(remap[index], episodes, note)
        else:
            progress.update(remap[index], episodes, note)

    try:
        while waiting or running:
            while waiting and len(running) < workers:
                spec = waiting.pop(0)
                proc = ctx.Process(target=_run_process, args=(spec, q),
                                   name=f'clis-run-{spec.index}', daemon=True)
                # a Ctrl-C between the start and the bookkeeping would leave it unkilled
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
                try:
                    proc.start()
                    running[spec.index] = proc
                finally:
                    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
            try:
                handle(*q.get(timeout=0.5))
            except queue.Empty:
                pass
            for index, proc in list(running.items()):
                if proc.exitcode is None:
                    continue
                proc.join()
                del running[index]
                while index not in finished:           # its last messages, already sent
                    try:
                        handle(*q.get(timeout=1.0 if proc.exitcode == 0 else 0.1))
                    except queue.Empty:
                        spec = todo[remap[index]]
                        raise RunError(f'{spec.label} seed {spec.seed}: its process ended '
                                       f'(exit code {proc.exitcode}) without its result; '
                                       'rerun with --resume') from None
    finally:
        _kill(running.values())


def _run_process(spec: JobSpec, q: Any) -> None:
    """A run's process: Ctrl-C is the parent's to handle; an exception goes to the parent."""
    _worker_signals()
    try:
        _worker(spec, q)
    except BaseException:
        import traceback
        q.put(('error', spec.index, 0, traceback.format_exc()))
        q.close()
        q.join_thread()
        raise SystemExit(1) from None


def _kill(processes: Any) -> None:
    """SIGKILL every process of ``processes`` still alive and reap it (no handler of theirs
    can delay it)."""
    processes = list(processes)
    for proc in processes:
        if proc.exitcode is None:
            proc.kill()
    for proc in processes:
        proc.join()


def _worker_signals() -> None:
    """In a run's process: Ctrl-C (SIGINT to the whole process group) is left to the main
    process, which stops the runs and prints one line instead of a traceback per process;
    SIGTERM gets its default action back, whatever handler the forking process had installed
    (``clis run``'s, once run in the same process, or rclpy's, which only remember it)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
