"""Ctrl-C: every `clis` command stops with one line and exit 130, and an interrupted
`clis experiment` resumed with --resume ends with the results of an uninterrupted one, byte for
byte (results, checkpoints and tables are written atomically)."""

from __future__ import annotations

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from clis_app.cli import main as clis
import numpy as np
import pytest

#: 1 condition, 1 seed, 20 episodes of at most 10 s simulated, evaluated every 5.
TINY = ['experiment', '--conditions', 'view', '--episodes', '20', '--block', '5', '--seeds', '1',
        '--eval-episodes', '1', '--eval-every', '5', '--workers', '1', '--quiet',
        '--train-start', 'starts', '--sim-set', 'episode.time_limit=10.0']


@pytest.mark.parametrize('module, name', [('experiments.report', '_main'),
                                          ('experiments.compare', '_main'),
                                          ('experiments.experiment', 'main'),
                                          ('cli.doctor', 'run_doctor')])
def test_ctrl_c_is_one_line_and_130_for_every_command(monkeypatch, capsys, tmp_path, module,
                                                      name):
    import importlib

    def interrupted(*args):
        raise KeyboardInterrupt
    monkeypatch.setattr(importlib.import_module(f'clis_app.{module}'), name, interrupted)
    argv = {'report': ['report', str(tmp_path)],
            'compare': ['compare', '--a', 'x', '--b', 'y', '--condition', 'view'],
            'experiment': ['experiment', '--out', str(tmp_path / 'x')],
            'doctor': ['doctor']}[module.rsplit('.', 1)[1]]
    capsys.readouterr()
    try:
        code = clis(argv)
    except KeyboardInterrupt:
        pytest.fail('KeyboardInterrupt escaped clis (a traceback for the user)')
    assert code == 130
    err = capsys.readouterr().err.strip()
    assert err == f'clis {argv[0]}: interrupted', err


def test_ctrl_c_during_an_experiment_stops_its_processes_with_one_line(tmp_path):
    """A real Ctrl-C: SIGINT to the process group of `clis experiment` while its worker
    runs."""
    out = tmp_path / 'exp'
    # far more episodes than it can learn before the test stops it, on any host
    proc = subprocess.Popen([sys.executable, '-m', 'clis_app.cli', *TINY[:3],
                             '--episodes', '100000', '--block', '5', '--eval-every', '0',
                             '--quiet', '--workers', '1', '--out', str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,         # its own group, as a terminal's
                            # a shell's Ctrl-C disposition, whatever this test process had
                            # inherited or been left with (an ignored SIGINT is inherited
                            # across exec, and Python then never raises KeyboardInterrupt)
                            preexec_fn=_default_sigint,
                            env={**os.environ,               # the code this test imports
                                 'PYTHONPATH': os.pathsep.join(p for p in sys.path if p)})
    try:
        deadline = time.monotonic() + 120
        while len(_group(proc.pid)) < 2 and proc.poll() is None:   # main and its run
            assert time.monotonic() < deadline, 'clis experiment did not start its worker'
            time.sleep(0.1)
        time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert 'Traceback' not in err and err.strip() == 'clis experiment: interrupted', err
    deadline = time.monotonic() + 60                 # a bound, not a window: exits are slow
    while _group(proc.pid) and time.monotonic() < deadline:    # on a loaded host
        time.sleep(0.1)
    assert not _group(proc.pid), 'a run process was left behind'


def _default_sigint() -> None:
    """In the child before exec: SIGINT at its default disposition and not blocked."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _group(pgid: int) -> list[int]:
    """The processes of process group ``pgid``."""
    pids = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:
            pids.append(int(stat.parent.name))
    return pids


def _interrupted_clis(argv: list[str], delay: float) -> int:
    """``clis argv`` with a SIGINT ``delay`` s after the start (130 if it came after the
    command had finished)."""
    def ctrl_c(signum, frame):
        signal.raise_signal(signal.SIGINT)
    old = signal.signal(signal.SIGALRM, ctrl_c)
    try:
        signal.setitimer(signal.ITIMER_REAL, delay)
        try:
            return clis(argv)
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
    except KeyboardInterrupt:
        return -130
    finally:
        signal.signal(signal.SIGALRM, old)


def _complete_files(out: Path) -> None:
    """Every file of ``out`` that is not a temporary one is whole."""
    for path in out.rglob('*'):
        if not path.is_file() or path.name.endswith('.tmp'):
            continue
        if path.suffix == '.json':
            json.loads(path.read_text())
        elif path.suffix == '.npz':
            with np.load(path, allow_pickle=False) as z:
                assert '__meta__' in z.files, path
        elif path.suffix == '.csv':
            lines = path.read_text().splitlines()
            assert len({line.count(',') for line in lines}) <= 2, path   # quoted commas


def test_interrupted_experiment_resumes_to_the_same_results(tmp_path, monkeypatch):
    import shutil

    from clis_base.params import config_dir
    # a copy of config/: an edit of the working tree's during the test would change the runs'
    # parameter hash, which --resume rightly refuses
    shutil.copytree(config_dir(), tmp_path / 'config')
    monkeypatch.setenv('CLIS_CONFIG_DIR', str(tmp_path / 'config'))
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        ref = tmp_path / 'ref'
        assert clis([*TINY, '--out', str(ref)]) == 0         # the modules loaded
        t0 = time.monotonic()
        assert clis([*TINY, '--out', str(ref)]) == 0         # the time of a whole command
        whole = time.monotonic() - t0
        out = tmp_path / 'out'
        rng = np.random.default_rng(23)
        interrupts = attempts = outside = 0
        codes = []
        while interrupts < 20:
            attempts += 1
            assert attempts < 80, f'only {interrupts} interrupts landed in {attempts} tries'
            delay = float(rng.uniform(0.01, whole))
            code = _interrupted_clis([*TINY, '--out', str(out), '--resume'], delay)
            codes.append((round(delay, 2), code))
            assert code in (0, 130, -130), codes
            interrupts += code != 0
            outside += code == -130
            if out.exists():
                _complete_files(out)
            if code == 0:
                # it finished before the signal: start again, so that the next tries have a
                # whole command's work to interrupt, not a resume with nothing left to do
                shutil.rmtree(out)
        # clis stopped itself (130) but for a Ctrl-C in its first milliseconds (parsing)
        assert outside <= 2, f'{outside} of {interrupts} interrupts escaped clis: {codes}'
        assert clis([*TINY, '--out', str(out), '--resume']) == 0
    finally:
        signal.signal(signal.SIGINT, previous)
    for name in ('episodes.csv', 'eval.csv'):
        assert (out / name).read_bytes() == (ref / name).read_bytes(), name


def test_a_run_process_dies_on_sigterm_whatever_the_parent_handles():
    """A run's process forked from a process whose SIGTERM handler only remembers the signal
    (``clis run``'s, once run in the same process, or rclpy's) would outlive a SIGTERM;
    ``_worker_signals`` gives SIGTERM back its default action."""
    import multiprocessing as mp

    from clis_app.experiments.pool import _worker_signals

    ctx = mp.get_context('fork')
    old = signal.signal(signal.SIGTERM, lambda signum, frame: None)    # remembered, no more
    try:
        child = ctx.Process(target=_initialised_then_waits, args=(_worker_signals,))
        child.start()
    finally:
        signal.signal(signal.SIGTERM, old)
    try:
        time.sleep(0.5)                    # not a window: the child may still be starting
        child.terminate()
        child.join(60)                     # a hang guard
        assert child.exitcode == -signal.SIGTERM, child.exitcode
    finally:
        if child.is_alive():
            child.kill()
            child.join()


def _initialised_then_waits(initializer) -> None:
    initializer()
    while True:
        time.sleep(0.1)


def _spec(tmp_path: Path, index: int = 0):
    from clis_app.experiments.runner import JobSpec
    return JobSpec(index=index, label='view', condition='view', overrides={},
                   sim_overrides={}, seed=index, episodes=1, eval_episodes=1, arena=None,
                   run_dir=str(tmp_path))


def _runs_alive() -> list:
    import multiprocessing as mp
    return [c for c in mp.active_children() if c.name.startswith('clis-run-')]


class _StopAtFirstProgress:
    def update(self, *args) -> None:
        raise KeyboardInterrupt

    finish = update


def _ignores_sigterm_and_reports(spec, q) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    q.put(('progress', spec.index, 0, 'started'))
    while True:
        time.sleep(0.1)


def _raises(spec, q) -> None:
    raise ValueError('a run that fails: boom')


def _dies(spec, q) -> None:
    os._exit(3)


def test_an_interrupt_kills_every_run_even_one_that_ignores_sigterm(tmp_path, monkeypatch):
    from clis_app.experiments import pool
    monkeypatch.setattr(pool, '_worker', _ignores_sigterm_and_reports)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        pool._run_all([_spec(tmp_path, k) for k in range(3)], 2, True,
                            _StopAtFirstProgress())
    assert _runs_alive() == []
    assert time.monotonic() - t0 < 60                  # a hang guard, not a timing


@pytest.mark.parametrize('worker, message', [(_raises, 'ValueError: a run that fails: boom'),
                                             (_dies, 'exit code 3')])
def test_a_failed_run_stops_the_others_and_says_why(tmp_path, monkeypatch, worker, message):
    from clis_app.experiments import pool
    monkeypatch.setattr(pool, '_worker', worker)
    with pytest.raises(pool.RunError, match='view seed 0') as err:
        pool._run_all([_spec(tmp_path, k) for k in range(3)], 1, True,
                            pool.Progress(total_episodes=3, runs=3, quiet=True))
    assert message in str(err.value)
    assert _runs_alive() == []


def test_the_eta_weighs_each_runs_episodes_by_their_cost(capsys, monkeypatch):
    """Longest runs go first: an ETA by episodes alone would count the cheap ones left as
    dear as the dear ones done (a study's first ETA was twice its time)."""
    from clis_app.experiments import pool
    clock = iter([100.0, 110.0])
    monkeypatch.setattr(pool.time, 'monotonic', lambda: next(clock))
    progress = pool.Progress(total_episodes=200, runs=2, cost=[(100, 5.5), (100, 1.0)])
    progress.finish(0, 100, 'async done')      # 10 s for the first (dear) half of the episodes
    line = capsys.readouterr().err
    # work done 550 of 650: 10 s * 100 / 550 = 1.8 s left (by episodes alone: 10 s)
    assert 'ETA 0.0 min' in line, line
    assert '100/200 episodes, 1/2 runs' in line
