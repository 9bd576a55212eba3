"""The opt-in real-time priority of the sensor-to-command path (``clis run --realtime``,
:func:`clis_base.ros.process.realtime`): it is off unless asked, it fails soft with a
message that says why (no right to it), it never leaves a process half real-time, a granted
priority holds the CPU wake-up latency at 0 us for the process's life, and ``clis run`` gives
it to the simulator, the modules and the arbiter only."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from clis_app.graph.plan import plan_graph
from clis_base.ros import process as lifecycle
from clis_base.ros.process import realtime
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

    ok, said = realtime(5, threads=[1, 2, 3], setter=setter, wakeup_device=None)
    assert ok and 'SCHED_FIFO 5 on 2 threads' in said and 'wake-up' not in said


def test_a_granted_priority_holds_the_cpu_wakeup_latency_while_the_process_lives(tmp_path):
    device = tmp_path / 'cpu_dma_latency'
    device.write_bytes(b'')
    ok, said = realtime(5, threads=[1], setter=lambda *a: None, wakeup_device=str(device))
    try:
        assert ok and 'SCHED_FIFO 5 on 1 threads' in said and '0 us held' in said
        assert device.read_bytes() == (0).to_bytes(4, sys.byteorder), 'the int32 0 written'
        fd = lifecycle._WAKEUP_HELD[str(device)]
        assert os.readlink(f'/proc/self/fd/{fd}') == str(device), 'kept open: the request'
        # asked again (the single process's nodes): the same request, not a second one
        assert lifecycle.hold_cpu_wakeup_latency(str(device))[0]
        assert len([d for d in lifecycle._WAKEUP_HELD if d == str(device)]) == 1
    finally:
        os.close(lifecycle._WAKEUP_HELD.pop(str(device)))


def test_a_wakeup_latency_that_cannot_be_held_leaves_the_priority_and_says_why(tmp_path):
    missing = tmp_path / 'no_such_device'
    ok, said = realtime(5, threads=[1], setter=lambda *a: None, wakeup_device=str(missing))
    assert ok and 'SCHED_FIFO 5' in said
    assert 'not held' in said and 'No such file' in said and str(missing) not in \
        lifecycle._WAKEUP_HELD
    refused, said = realtime(5, threads=[1], setter=lambda *a: (_ for _ in ()).throw(
        PermissionError(1, 'Operation not permitted')), wakeup_device=str(missing))
    assert not refused and 'wake-up' not in said, 'no request without the priority'


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='SCHED_FIFO: Linux')
def test_a_process_without_the_right_runs_on_with_the_default_scheduling():
    """For real: a process that may not (an unprivileged user, or ``ulimit -r`` 0) gets a
    warning line and keeps its scheduling; one that may (root here) gets SCHED_FIFO."""
    code = textwrap.dedent("""
        import os, sys
        from clis_base.ros.process import realtime  # (nobody may not read the venv)
        if os.geteuid() == 0 and sys.argv[1] == 'drop':
            os.setgid(65534); os.setuid(65534)          # nobody: no CAP_SYS_NICE
        ok, said = realtime(10)
        held = any(os.path.realpath(f'/proc/self/fd/{fd}') == '/dev/cpu_dma_latency'
                   for fd in os.listdir('/proc/self/fd'))
        print(ok, os.sched_getscheduler(0) == os.SCHED_FIFO, held, said)
    """)
    if os.geteuid() == 0:
        out = subprocess.run([sys.executable, '-c', code, 'drop'], capture_output=True,
                             text=True, timeout=60, env=dict(os.environ))
        assert out.returncode == 0, out.stderr
        ok, fifo, held, said = out.stdout.split(' ', 3)
        assert (ok, fifo, held) == ('False', 'False', 'False') and 'not permitted' in said
        out = subprocess.run([sys.executable, '-c', code, 'keep'], capture_output=True,
                             text=True, timeout=60)
        # root: SCHED_FIFO, and the wake-up latency request held where the kernel has it
        device = os.path.exists('/dev/cpu_dma_latency')
        assert out.stdout.split(' ', 3)[:3] == ['True', 'True', str(device)], \
            out.stdout + out.stderr
    else:
        out = subprocess.run(['sh', '-c', f'ulimit -r 0 2>/dev/null; exec "{sys.executable}" '
                              f'-c "$0" keep', code], capture_output=True, text=True, timeout=60)
        ok, fifo, held, said = out.stdout.split(' ', 3)
        assert (ok, fifo, held) == ('False', 'False', 'False') and 'default scheduling' in said


def test_clis_run_gives_it_to_the_sensor_to_command_path_only(tmp_path):
    plan = plan_graph('async', 0, tmp_path, 0.0, realtime=10)
    got = {c.name: c.params.get('graph.realtime_priority', c.params.get(
        'node.realtime_priority', 0)) for c in plan.children}
    # along the round trip's end: the modules, then the simulator, then the arbiter above
    assert got == {'learner': 0, 'arbiter': 12, 'innate': 10, 'view': 10, 'place': 10,
                   'sim': 11}
    plan = plan_graph('async', 0, tmp_path, 0.0)
    assert not any('realtime' in k for c in plan.children for k in c.params)


def test_a_shutdown_race_is_a_clean_stop_and_a_real_error_is_raised():
    """:func:`reraise_unless_shut_down`: an executor error while rclpy's signal thread is
    still shutting the context down is a clean stop; the same error in a running context is
    raised."""
    import threading

    from clis_base.ros.process import reraise_unless_shut_down
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
