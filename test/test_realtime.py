"""The opt-in real-time priority of the sensor-to-command path (``clis run --realtime``,
:func:`cr_sim.lifecycle.realtime`): it is off unless asked, it fails soft with a message that
says why (no right to it), it never leaves a process half real-time, and ``clis run`` gives it
to the simulator, the modules and the arbiter only."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from clis_learner.graph import plan_graph
from cr_sim.lifecycle import realtime
import pytest


def test_off_unless_asked():
    ok, said = realtime(0, setter=lambda *a: pytest.fail('set the scheduling'))
    assert not ok and 'off' in said


def test_refused_is_a_message_not_an_exception_and_undoes_the_threads_already_set():
    calls = []

    def setter(tid, policy, param):
        calls.append((tid, policy, param.sched_priority))
        if tid == 3 and policy == os.SCHED_FIFO:
            raise PermissionError(1, 'Operation not permitted')

    ok, said = realtime(20, threads=[1, 2, 3, 4], setter=setter)
    assert not ok
    assert 'not permitted' in said and 'ulimit -r' in said and 'default scheduling' in said
    assert calls[:3] == [(1, os.SCHED_FIFO, 20), (2, os.SCHED_FIFO, 20), (3, os.SCHED_FIFO, 20)]
    # every thread back to the default policy
    assert sorted(t for t, p, _ in calls[3:] if p == os.SCHED_OTHER) == [1, 2, 3, 4]


def test_a_thread_that_ended_meanwhile_is_skipped():
    def setter(tid, policy, param):
        if tid == 2:
            raise ProcessLookupError(3, 'No such process')

    ok, said = realtime(5, threads=[1, 2, 3], setter=setter)
    assert ok and 'SCHED_FIFO 5 on 2 threads' in said


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='SCHED_FIFO: Linux')
def test_a_process_without_the_right_runs_on_with_the_default_scheduling():
    """For real: a process that may not (an unprivileged user, or ``ulimit -r`` 0) gets a
    warning line and keeps its scheduling; one that may (root here) gets SCHED_FIFO."""
    code = textwrap.dedent("""
        import os, sys
        from cr_sim.lifecycle import realtime           # (nobody may not read the venv)
        if os.geteuid() == 0 and sys.argv[1] == 'drop':
            os.setgid(65534); os.setuid(65534)          # nobody: no CAP_SYS_NICE
        ok, said = realtime(10)
        print(ok, os.sched_getscheduler(0) == os.SCHED_FIFO, said)
    """)
    if os.geteuid() == 0:
        out = subprocess.run([sys.executable, '-c', code, 'drop'], capture_output=True,
                             text=True, timeout=60, env=dict(os.environ))
        assert out.returncode == 0, out.stderr
        ok, fifo, said = out.stdout.split(' ', 2)
        assert (ok, fifo) == ('False', 'False') and 'not permitted' in said
        out = subprocess.run([sys.executable, '-c', code, 'keep'], capture_output=True,
                             text=True, timeout=60)
        assert out.stdout.split(' ', 2)[:2] == ['True', 'True'], out.stdout + out.stderr
    else:
        out = subprocess.run(['sh', '-c', f'ulimit -r 0 2>/dev/null; exec "{sys.executable}" '
                              f'-c "$0" keep', code], capture_output=True, text=True, timeout=60)
        ok, fifo, said = out.stdout.split(' ', 2)
        assert (ok, fifo) == ('False', 'False') and 'default scheduling' in said


def test_clis_run_gives_it_to_the_sensor_to_command_path_only(tmp_path):
    plan = plan_graph('async', 0, tmp_path, 0.0, realtime=10)
    got = {c.name: c.params.get('graph.realtime_priority', c.params.get(
        'node.realtime_priority', 0)) for c in plan.children}
    assert got == {'learner': 0, 'arbiter': 10, 'innate': 10, 'view': 10, 'place': 10,
                   'sim': 10}
    plan = plan_graph('async', 0, tmp_path, 0.0)
    assert not any('realtime' in k for c in plan.children for k in c.params)


def test_a_shutdown_race_is_a_clean_stop_and_a_real_error_is_raised():
    """:func:`reraise_unless_shut_down`: an executor error while rclpy's signal thread is
    still shutting the context down is a clean stop; the same error in a running context is
    raised."""
    import threading

    from cr_sim.lifecycle import reraise_unless_shut_down
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    threading.Timer(0.1, context.shutdown).start()     # the signal thread, a moment later
    try:
        raise RuntimeError('Unable to convert call argument')
    except RuntimeError:
        reraise_unless_shut_down(context=context)        # waits for it: a clean stop
    assert not context.ok()

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(RuntimeError, match='a real error'):
            try:
                raise RuntimeError('a real error')
            except RuntimeError:
                reraise_unless_shut_down(grace=0.05, context=context)
    finally:
        context.shutdown()
