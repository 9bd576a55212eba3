"""``clis run`` interrupted (Ctrl-C) at random moments, :data:`INTERRUPTS` times or more, and
resumed each time into the same ``--out``: it ends with the uninterrupted run's results, byte
for byte.

A tiny run (the innate module, :data:`EPISODES` episodes of at most 4 s of sim time) is stopped
with SIGINT at random moments: while it starts, or up to a fifth of a second after one of its
next learned episodes (judged by its checkpoint), each time resumed from its checkpoint
(``--resume OUT/checkpoint.npz``, the episodes still to learn), then run to its end. Compared
with the same run uninterrupted (the graph as ``clis run`` starts it, one process per node):
``episodes.csv``, ``checkpoint.npz`` and ``curve.csv`` are the same bytes.

That holds because the simulator's robot, clock and random streams (its own, the starts' and
the agent stream the modules and the arbiter replay, announced at each start) go on from where
the checkpoint's episode left them (its ``sim_state``), the learner learns exactly
``--episodes`` episodes, and a checkpoint's bytes are its content (fixed zip entry times); the
graph in lockstep computes the same episodes on any load.

A process's start costs seconds of CPU (numba, rclpy): the interrupted runs are ``clis run
--single-process`` called in this process (``clis``'s main, stopped by a SIGINT to this
process), but for :data:`SUBPROCESS`: a real ``clis run`` of one process per node, stopped
by a SIGINT as from a terminal (test_run_resume.py resumes such a run). The runs resume from
each other's checkpoints, and the final run (in this process) ends with the bytes of the
uninterrupted one of one process per node.
"""

from __future__ import annotations

from collections.abc import Callable
import json
import os
from pathlib import Path
import random
import shutil
import signal
import subprocess
import sys
import threading
import time

from clis_app.cli import main as clis
import numpy as np
import pytest

EPISODES = 80
#: the interrupted runs' clock against wall time: an episode (<= 4 s) takes >= 0.4 s, so that the
#: test's watcher thread, which needs the GIL and a core, stops the run within a few episodes
#: (at full speed on a loaded host it may come only after the run's last episodes; the
#: uninterrupted run is at full speed: lockstep, so the clock's pace changes no result)
SPEED = 10.0
PARAMS = '/**:\n  ros__parameters:\n    episode: {time_limit: 4.0, wander_time: 1.0}\n'
INTERRUPTS = 20                    # at least, that land in `clis run` (exit code 130)
#: these interruptions stop `clis run` processes; the others one in this process
SUBPROCESS = (0,)


def argv(out: Path, params: Path, speed: float = 0.0) -> list[str]:
    """``clis run`` for the episodes OUT still has to learn (from its checkpoint, if any), its
    clock at ``speed`` times wall time (0: as fast as it goes)."""
    done = learned(out)
    return ['run', '--condition', 'innate', '--episodes', str(EPISODES - done), '--params',
            str(params), '--out', str(out), '--quiet', '--speed', str(speed),
            *(['--resume', str(out / 'checkpoint.npz')] if done else [])]


def start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'clis_app.cli', *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def learned(out: Path) -> int:
    """The episode of OUT's checkpoint (0 without one)."""
    path = out / 'checkpoint.npz'
    if not path.is_file():
        return 0
    with np.load(path, allow_pickle=False) as npz:
        return int(json.loads(str(npz['__meta__']))['extra']['episode'])


def moment(out: Path, rng: random.Random, first: bool, running: Callable[[], bool]) -> None:
    """Wait for a random moment: while the run starts, or up to 0.2 s after one of its next
    learned episodes (the first time, after one or two: a checkpoint to resume from), but never
    past the end of the episode after that one.

    The bound is in episodes, not seconds: on a fast host a fifth of a second is many episodes,
    and a run that learns them all ends before it was interrupted :data:`INTERRUPTS` times (CI
    failed so). Each interruption lets at most j + 1 <= 3 episodes be learned."""
    before = learned(out)
    j = rng.randint(1, 2) if first else rng.randint(0, 2)
    while learned(out) < before + j and running():
        time.sleep(0.005)
    deadline = time.monotonic() + (rng.uniform(0.0, 0.2) if j else rng.uniform(0.0, 1.0))
    while time.monotonic() < deadline and learned(out) <= before + j and running():
        time.sleep(0.005)


def interrupted_process(out: Path, params: Path, rng: random.Random, first: bool) -> int:
    """``clis run`` (one process per node) stopped by a SIGINT: its exit code."""
    proc = start(argv(out, params, SPEED))
    moment(out, rng, first, lambda: proc.poll() is None)
    proc.send_signal(signal.SIGINT)
    text, _ = proc.communicate(timeout=300)
    assert proc.returncode in (0, 130), text
    assert 'Traceback' not in text, text
    return proc.returncode


def interrupted_here(out: Path, params: Path, rng: random.Random, first: bool) -> int:
    """``clis run --single-process`` in this process, stopped by a SIGINT to it: its exit
    code (-130: the SIGINT came before ``clis`` handles it, or after it returned)."""
    done = threading.Event()

    def ctrl_c() -> None:
        moment(out, rng, first, lambda: not done.is_set())
        if not done.is_set():
            os.kill(os.getpid(), signal.SIGINT)
    watcher = threading.Thread(target=ctrl_c, daemon=True)
    watcher.start()
    try:
        try:
            return clis([*argv(out, params, SPEED), '--single-process'])
        finally:
            done.set()
            watcher.join()
    except KeyboardInterrupt:
        return -130


@pytest.fixture
def sandbox(tmp_path, monkeypatch):
    """A copy of config/ (an edit of the working tree's during the test would change the
    parameter hash, which --resume rightly refuses); the environment and SIGINT's handler
    restored after the in-process runs (the graph's DDS profile)."""
    shutil.copytree(Path(os.environ['CLIS_CONFIG_DIR']), tmp_path / 'config')
    monkeypatch.setenv('CLIS_CONFIG_DIR', str(tmp_path / 'config'))
    env = dict(os.environ)
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield tmp_path
    signal.signal(signal.SIGINT, handler)
    os.environ.clear()
    os.environ.update(env)


def test_run_interrupted_20_times_ends_with_the_uninterrupted_results_byte_for_byte(sandbox):
    params = sandbox / 'short.yaml'
    params.write_text(PARAMS)
    ref = sandbox / 'ref'
    proc = start(argv(ref, params))
    text, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, text
    assert learned(ref) == EPISODES

    out = sandbox / 'run'
    rng = random.Random(23)
    codes = []                                    # (learned before, exit code)
    while sum(code == 130 for _, code in codes) < INTERRUPTS:
        assert len(codes) < 2 * INTERRUPTS, codes
        assert learned(out) < EPISODES, f'the run ended before {INTERRUPTS} interruptions: ' \
                                        f'{codes}'
        before = learned(out)
        first = not codes
        interrupt = interrupted_process if len(codes) in SUBPROCESS else interrupted_here
        codes.append((before, interrupt(out, params, rng, first)))
        assert codes[-1][1] in (0, 130, -130), codes
    assert sum(code == -130 for _, code in codes) <= 3, codes   # (parsing the arguments)
    resumed = sum(before > 0 for before, code in codes if code == 130)
    assert clis([*argv(out, params), '--single-process']) == 0  # to the end
    print(f'{len(codes)} interruptions, {resumed} of them of runs resumed from a checkpoint: '
          f'{codes}')
    assert resumed >= INTERRUPTS - 1, codes

    for name in ('episodes.csv', 'checkpoint.npz', 'curve.csv'):
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name


def test_a_ctrl_c_swallowed_while_clis_run_starts_still_stops_it(sandbox, monkeypatch):
    """A Ctrl-C whose KeyboardInterrupt is lost before the graph's handler is installed (it
    landed in a gc callback while ``clis run`` imported its modules: the run then learned all
    its episodes and exited 0) still stops the run: ``clis`` remembers it from its start
    (``clis_app.cli.ctrl_c``)."""
    import clis_app.graph.run as graph_cli
    params = sandbox / 'short.yaml'
    params.write_text(PARAMS)
    out = sandbox / 'run'
    plan_graph = graph_cli.plan_graph

    def swallowing(*args, **kwargs):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)                  # the handler runs here and raises
        except KeyboardInterrupt:
            pass                             # lost, as in a gc callback
        return plan_graph(*args, **kwargs)
    monkeypatch.setattr(graph_cli, 'plan_graph', swallowing)
    args = argv(out, params, SPEED)
    args[args.index('--episodes') + 1] = '40'
    assert clis([*args, '--single-process']) == 130
    assert learned(out) < 40
