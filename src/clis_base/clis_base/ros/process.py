"""A node process's life: its heap settled before it spins, an opt-in real-time scheduling
priority, and a clean stop told from a crash.

Before spinning, a node moves the objects alive then (rclpy, numpy, numba and their modules,
the node itself: ~75,000 objects) out of the garbage collector's reach (:func:`settle_heap`):
a full collection otherwise walks them all, a pause of 0.1-0.5 s measured in a graph node,
which lands on the decision path whenever it comes. Objects made later are collected as usual.

Real-time priority (opt-in, :func:`realtime`; ``clis run --realtime``): the nodes on the
sensor-to-command path (simulator, modules, arbiter; never the learner) may put every thread
of their process (the executor's and Fast DDS's) under ``SCHED_FIFO``, so that a wakeup on
that path takes a core at once from any normal process, however loaded the machine. Linux
allows it to root, to a process with ``CAP_SYS_NICE``, or up to the ``rtprio`` limit
(``ulimit -r``); without that right the node logs why and runs with the default scheduling
(fail-soft). The kernel keeps 5% of each second for normal processes
(``/proc/sys/kernel/sched_rt_runtime_us``), so a runaway node cannot lock the machine up.
A process granted the priority also asks the kernel for a CPU wake-up latency of 0 µs for as
long as it lives (:func:`hold_cpu_wakeup_latency`, the PM QoS request
``/dev/cpu_dma_latency`` that ``cyclictest`` makes by default): idle cores then poll instead of
halting, so the next hop's wakeup does not pay a halted core's exit (on a VM, a trip through the
hypervisor). Measured on a 2-core VM with bench/bench_hops.py, it is what brings the round trip's
p99 at the robot's pace under 5 ms; the price is idle cores that stay busy (power, and a VM's
host sees them at 100%).

Ctrl-C or SIGTERM shuts the rclpy context down from a signal handler, possibly while the
executor is building its wait set or taking a message. rclpy then raises from inside the
executor: ``RCLError`` ('failed to initialize wait set: the given context is not valid') or a
pybind11 ``RuntimeError`` ('Unable to convert call argument ... to Python object', seen in the
simulator's log at the end of a ``clis run``). After a shutdown either is a clean stop; while
the context is still valid it is a real error.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
import gc
import os
import signal
import struct
import time
from typing import Any

import rclpy

from clis_base.params import ConfigError
from clis_base.ros.rclpy_private import RCLError

__all__ = ['CPU_WAKEUP_DEVICE', 'SHUTDOWN_RACES', 'RCLError', 'hold_cpu_wakeup_latency',
           'realtime', 'realtime_logged',
           'reraise_unless_shut_down', 'settle_heap']

#: What the executor may raise when the context is shut down under it.
SHUTDOWN_RACES = (RCLError, RuntimeError)
#: Linux's PM QoS interface for the CPU wake-up latency (microseconds, a native int32).
CPU_WAKEUP_DEVICE = '/dev/cpu_dma_latency'
#: The open requests of this process: the kernel keeps a request while its file is open and
#: drops it when the process ends, however it ends.
_WAKEUP_HELD: dict[str, int] = {}


def reraise_unless_shut_down(grace: float = 1.0, context: rclpy.Context | None = None) -> None:
    """Inside an ``except SHUTDOWN_RACES:`` block: re-raise unless rclpy was shut down, or is
    being shut down: rclpy's signal handler shuts the context down from a thread of its own,
    and the executor may fail on its half-destroyed entities a moment before ``rclpy.ok()``
    turns False (seen: the simulator's ``take_message`` at a SIGINT), so the context gets
    ``grace`` seconds to finish. ``context``: rclpy's default one if None."""
    deadline = time.monotonic() + grace
    while rclpy.ok(context=context):
        if time.monotonic() >= deadline:
            raise
        time.sleep(0.01)


def settle_heap() -> None:
    """Collect the garbage of the start-up, then freeze what is alive (module docstring): the
    collector's later passes skip it (``gc.freeze``, Python >= 3.7)."""
    gc.collect()
    gc.freeze()


def _threads() -> list[int]:
    """Thread ids of this process (Linux: ``/proc/self/task``; elsewhere this thread)."""
    try:
        return sorted(int(tid) for tid in os.listdir('/proc/self/task'))
    except OSError:
        return [0]


def hold_cpu_wakeup_latency(device: str = CPU_WAKEUP_DEVICE) -> tuple[bool, str]:
    """Ask the kernel for a CPU wake-up latency of 0 µs until this process ends (module
    docstring), fail-soft: the request is the int32 0 written to ``device``, kept open.

    Returns
    -------
    (bool, str)
        Whether the request is held, and what was done or why not (root only by default; no
        such device in a container). Nothing is raised.
    """
    if device in _WAKEUP_HELD:
        return True, f'CPU wake-up latency 0 us held ({device})'
    fd = -1
    try:
        fd = os.open(device, os.O_WRONLY)
        os.write(fd, struct.pack('=i', 0))
    except OSError as exc:
        if fd >= 0:
            os.close(fd)
        return False, (f'CPU wake-up latency not held ({device}: {exc.strerror or exc}): idle '
                       'cores may halt between instants')
    _WAKEUP_HELD[device] = fd
    return True, f'CPU wake-up latency 0 us held ({device}: idle cores poll)'


def realtime(priority: int, threads: Iterable[int] | None = None,
             setter: Callable[[int, int, object], None] | None = None,
             wakeup_device: str | None = CPU_WAKEUP_DEVICE) -> tuple[bool, str]:
    """Put every thread of this process (``threads``: these) under ``SCHED_FIFO`` at
    ``priority`` (1-99; 0 = leave the scheduling alone), fail-soft (module docstring); once
    granted, hold the CPU wake-up latency at 0 µs through ``wakeup_device``
    (:func:`hold_cpu_wakeup_latency`; None: not).

    Threads started later (by a thread under ``SCHED_FIFO``) inherit it.

    Returns
    -------
    (bool, str)
        Whether every thread got the priority, and a line for the log that says what was done
        or why not (no right to it, no ``SCHED_FIFO`` on this system), and that the node runs
        with the default scheduling then; and whether the wake-up latency is held. Nothing is
        raised.
    """
    if priority <= 0:
        return False, 'default scheduling (real-time priority off)'
    policy = getattr(os, 'SCHED_FIFO', None)
    setter = setter if setter is not None else getattr(os, 'sched_setscheduler', None)
    if policy is None or setter is None:
        return False, (f'real-time priority {priority} requested, but this system has no '
                       'SCHED_FIFO: running with the default scheduling')
    tids = list(threads) if threads is not None else _threads()
    done = 0
    for tid in tids:
        try:
            setter(tid, policy, os.sched_param(priority))
            done += 1
        except ProcessLookupError:          # a thread that ended meanwhile
            continue
        except (OSError, ValueError) as exc:
            if done:                        # do not leave the process half real-time
                for other in tids:
                    try:
                        setter(other, os.SCHED_OTHER, os.sched_param(0))
                    except OSError:
                        pass
            why = ('not permitted: needs root, CAP_SYS_NICE or an rtprio limit (ulimit -r) '
                   f'of at least {priority}' if isinstance(exc, PermissionError) else str(exc))
            return False, (f'real-time priority {priority} (SCHED_FIFO) {why}: running with '
                           'the default scheduling')
    said = f'real-time priority: SCHED_FIFO {priority} on {done} threads'
    if wakeup_device is not None:
        said += '; ' + hold_cpu_wakeup_latency(wakeup_device)[1]
    return True, said


def realtime_logged(priority: int, logger) -> bool:
    """:func:`realtime` for a node's process, saying what happened on the node's ``logger``
    (info if granted, warning if not); whether it was granted."""
    ok, said = realtime(priority)
    (logger.info if ok else logger.warning)(said)
    return ok


def start_node(name: str, factory: Callable[[], Any], args: list[str] | None = None,
               flag_signals: bool = True) -> tuple[Any, list[int]]:
    """``rclpy.init``, then the node ``factory()`` makes; a bad parameter (ConfigError): one line
    ``NAME: bad parameter: ...`` and exit code 2. ``flag_signals``: Ctrl-C and SIGTERM only
    append to the returned list (the node's loop ends between two callbacks, and a robot gets
    its zero command from a live context: rclpy's own handler would shut the context down
    under the executor first); else rclpy's own handler (KeyboardInterrupt)."""
    stopping: list[int] = []
    if flag_signals:
        rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda sig, frame: stopping.append(sig))
    else:
        rclpy.init(args=args)
    try:
        node = factory()
    except ConfigError as exc:
        print(f'{name}: bad parameter: {exc}', flush=True)
        rclpy.try_shutdown()
        raise SystemExit(2) from None
    return node, stopping
