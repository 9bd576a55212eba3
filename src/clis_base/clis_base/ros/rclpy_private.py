"""The one place where the project touches rclpy's private members, for one rclpy version.

The lean executor (:mod:`clis_base.ros.executor`) replaces rclpy's wait-and-dispatch step
and reads the executor's and the nodes' internals; the graph nodes take ``/clock`` on demand
through the node's time source, and every node reads the parameter overrides it was started
with (:mod:`clis_base.ros.graph_node`, :mod:`clis_base.ros.ros_params`); the simulator
waits on a wait set of its own (:class:`cr_sim.sim_node.CommandWait`). None of that is rclpy's
public API: it is written against rclpy :data:`WRITTEN_FOR` (ROS 2 Jazzy) and used only there.

On any other rclpy version (:func:`supported` is False) the callers fall back to rclpy's
public API, with the same results and only the speed lost: ``make_executor('lean')`` gives
rclpy's :class:`~rclpy.executors.SingleThreadedExecutor` and logs a warning
(:func:`clis_base.ros.executor.make_executor`), a graph node subscribes ``/clock`` as
usual instead of on demand (:func:`clock_subscription` is None), and the simulator waits for
its commands through the executor (:func:`cr_sim.sim_node.run`). The parameter overrides
(:func:`parameter_overrides`) are read wherever rclpy keeps them under that name.

To support another rclpy: check every function below against its source (``rclpy/executors.py``:
``_spin_once_impl``, ``_tasks``, ``_tasks_lock``, ``_is_shutdown``, ``_guard``, ``_sigint_gc``,
``_take_*``; ``rclpy/node.py``: ``_timers`` ..., ``_parameter_overrides``,
``_time_source``; ``rclpy/time_source.py``: ``_clock_sub``, ``clock_callback``;
``rclpy/subscription.py``: ``_callback_type``), run ``test/test_executor.py`` on it, then
change :data:`WRITTEN_FOR`.
"""

from __future__ import annotations

from collections.abc import Callable
import functools
import importlib.metadata
from typing import Any

from rclpy.executors import SingleThreadedExecutor, TimeoutObject
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.utilities import timeout_sec_to_nsec

__all__ = ['WRITTEN_FOR', 'RCLError', 'PrivateExecutor', 'clock_subscription',
           'message_only', 'new_wait_set', 'node_entities', 'parameter_overrides',
           'rclpy_version', 'set_clock', 'supported', 'wrap_executor_waits']

#: The rclpy version (``importlib.metadata.version('rclpy')``; ROS 2 Jazzy) whose private
#: members this module was written for and tested with.
WRITTEN_FOR = '7.1.5'

#: rclpy's error from its C extension (not exported by a public module).
RCLError = _rclpy.RCLError


@functools.lru_cache(maxsize=1)
def _installed_version() -> str | None:
    try:
        return importlib.metadata.version('rclpy')
    except importlib.metadata.PackageNotFoundError:
        return None


def rclpy_version() -> str | None:
    """The version of the rclpy installed (its package metadata), None if unknown."""
    return _installed_version()


def supported() -> bool:
    """Whether the installed rclpy is :data:`WRITTEN_FOR`."""
    return rclpy_version() == WRITTEN_FOR


# ----------------------------------------------------------------------- the executor

class PrivateExecutor(SingleThreadedExecutor):
    """rclpy's SingleThreadedExecutor with its wait-and-dispatch step replaced.

    Subclasses implement :meth:`wait_and_dispatch` (called by rclpy's ``spin_once``,
    ``spin``, ``spin_until_future_complete`` through ``_spin_once_impl``) and reach the
    executor's internals only through the methods below.
    """

    def _spin_once_impl(self, timeout_sec=None, wait_condition=lambda: False) -> None:
        if self._is_shutdown or wait_condition():
            return
        self.wait_and_dispatch(timeout_sec_to_nsec(
            timeout_sec.timeout if isinstance(timeout_sec, TimeoutObject) else timeout_sec))

    def wait_and_dispatch(self, timeout_nsec: int) -> None:
        """One wait of at most ``timeout_nsec`` (negative: forever), then the ready work."""
        raise NotImplementedError

    @property
    def is_shut_down(self) -> bool:
        """Whether :meth:`shutdown` was called."""
        return self._is_shutdown

    def wake_guards(self) -> tuple:
        """The executor's own guard conditions, which a wait must include: the one that
        ``create_task`` / ``add_node`` trigger, and the one Ctrl-C triggers."""
        return self._guard, self._sigint_gc

    def has_tasks(self) -> bool:
        """Whether a task is in progress (``create_task``, coroutine callbacks)."""
        return bool(self._tasks)

    def pending_tasks(self) -> list:
        """The tasks in progress, oldest first."""
        with self._tasks_lock:
            return [t for t, _, _ in self._tasks]

    def add_task(self, task) -> None:
        """Keep ``task`` (a :class:`rclpy.task.Task` not done) to resume before later waits."""
        with self._tasks_lock:
            self._tasks.append((task, None, None))

    def prune_tasks(self) -> None:
        """Forget the tasks done or cancelled."""
        with self._tasks_lock:
            self._tasks = [t for t in self._tasks if not t[0].done() and not t[0].cancelled()]

    def take_waitable(self, waitable) -> Any:
        """rclpy's work for a ready waitable (an ``async def`` or None)."""
        return self._take_waitable(waitable)

    def take_client(self, client) -> Any:
        """rclpy's work for a client with a response ready."""
        return self._take_client(client)

    def take_service(self, srv) -> Any:
        """rclpy's work for a service with a request ready."""
        return self._take_service(srv)


def node_entities(node, kind: str):
    """``node``'s entities of ``kind`` (``'timers'``, ``'subscriptions'``, ``'guards'``,
    ``'clients'``, ``'services'``) in rclpy's order: rclpy 7.1's Node keeps them in lists of
    these names with a leading underscore (the public properties iterate them)."""
    entities = getattr(node, '_' + kind, None)
    return entities if entities is not None else getattr(node, kind)


def message_only(sub) -> bool:
    """Whether subscription ``sub``'s callback takes the message alone (not with its info)."""
    return sub._callback_type is sub.CallbackType.MessageOnly


def new_wait_set(sizes: tuple[int, ...], context_handle):
    """A wait set of rclpy's C extension for ``sizes`` = (subscriptions, guard conditions,
    timers, clients, services, events) in the context of ``context_handle``."""
    return _rclpy.WaitSet(*sizes, context_handle)


def wrap_executor_waits(on_wake: Callable[[], None]) -> None:
    """Call ``on_wake()`` each time the wait of one of rclpy's own executors returns, in this
    process (a development aid: :func:`clis_base.ros.executor.trace_executor_wakeups`)."""
    import rclpy.executors as executors
    real = executors._rclpy

    class WaitSet(real.WaitSet):
        def wait(self, timeout):
            out = super().wait(timeout)
            on_wake()
            return out

    class Shim:
        def __getattr__(self, name):
            return WaitSet if name == 'WaitSet' else getattr(real, name)

    executors._rclpy = Shim()


# ----------------------------------------------------------------------- nodes

def parameter_overrides(node) -> dict:
    """The parameter overrides ``node`` was created with (``--ros-args -p``, params files),
    by name: rclpy keeps them, before any is declared, in ``Node._parameter_overrides``."""
    return dict(getattr(node, '_parameter_overrides', {}) or {})


def clock_subscription(node):
    """The ``/clock`` subscription of ``node``'s time source (under sim time), or None: None
    also on an rclpy other than :data:`WRITTEN_FOR`, where the node then takes ``/clock`` as
    any subscription (no on-demand clock)."""
    if not supported():
        return None
    return getattr(getattr(node, '_time_source', None), '_clock_sub', None)


def set_clock(node, msg) -> None:
    """Set ``node``'s clock from a ``/clock`` message taken from :func:`clock_subscription`,
    as the time source's own callback does."""
    node._time_source.clock_callback(msg)
