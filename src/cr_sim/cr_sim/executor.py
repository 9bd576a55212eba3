"""A lean single-threaded executor: rclpy's, with one wait per batch of ready work.

rclpy's :class:`~rclpy.executors.SingleThreadedExecutor` (Jazzy) wraps every callback in a
:class:`~rclpy.task.Task` and a coroutine, and each callback triggers the executor's own guard
condition twice, so that the next wait returns at once and the whole wait set is rebuilt in
Python again: a message costs two or three waits. On the sensor-to-command path of the CLIS
graph (the simulator's ``/clock`` and readings -> module -> proposal -> arbiter -> ``cmd_vel``)
that overhead, not the decisions, is most of each hop (docs/benchmarks.md).

:class:`LeanExecutor` keeps rclpy's semantics (callback groups' ``can_execute`` /
``beginning_execution`` / ``ending_execution``, one message per ready subscription per wait,
timers, guard conditions, services, clients, waitables such as QoS events, tasks and
coroutine callbacks, ``spin_until_future_complete``, shutdown and Ctrl-C) and changes only how
it gets there: one wait, then every ready entity's callback called directly, in rclpy's order
(waitables, then per node timers, subscriptions, guard conditions, clients, services). The wait
set object is reused while the number of entities stays the same.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from contextlib import ExitStack
import inspect
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor, TimeoutObject
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.task import Task
from rclpy.utilities import timeout_sec_to_nsec
from rclpy.waitable import NumberOfEntities

__all__ = ['LeanExecutor']


class LeanExecutor(SingleThreadedExecutor):
    """Single-threaded executor that runs ready callbacks directly after one wait.

    A drop-in for :class:`~rclpy.executors.SingleThreadedExecutor` (``add_node``, ``spin``,
    ``spin_once``, ``spin_until_future_complete``, ``create_task``, ``shutdown``).
    """

    def __init__(self, *, context=None) -> None:
        super().__init__(context=context)
        self._wait_set = None
        self._wait_set_size: tuple[int, ...] = ()

    # --------------------------------------------------------------- tasks

    def _run_tasks(self) -> None:
        """Run or resume the tasks in progress (``create_task``, coroutine callbacks), as
        rclpy does before each wait."""
        with self._tasks_lock:
            tasks = list(self._tasks)
        if not tasks:
            return
        for task, _, _ in reversed(tasks):
            if not task.executing() and not task.done():
                task()
                if task.done() and task.exception() is not None:
                    raise task.exception()
        with self._tasks_lock:
            self._tasks = [t for t in self._tasks if not t[0].done() and not t[0].cancelled()]

    def _run(self, work: Callable[[], Any] | Coroutine | None) -> None:
        """Run an rclpy ``_take_*`` result (an ``async def`` or None) or a coroutine to
        completion, or leave it as a task in progress if it awaits something not done yet."""
        if work is None:
            return
        task = Task(work, executor=self)
        task()
        if not task.done():
            with self._tasks_lock:
                self._tasks.append((task, None, None))
        elif task.exception() is not None:
            raise task.exception()

    def _call(self, callback: Callable[..., Any], *args: Any) -> None:
        """Call a callback; a coroutine it returns continues as a task."""
        result = callback(*args)
        if inspect.iscoroutine(result):
            self._run(result)

    # --------------------------------------------------------------- the wait

    def _spin_once_impl(self, timeout_sec=None, wait_condition=lambda: False) -> None:
        if self._is_shutdown or wait_condition():
            return
        self._run_tasks()
        timeout_nsec = timeout_sec_to_nsec(
            timeout_sec.timeout if isinstance(timeout_sec, TimeoutObject) else timeout_sec)
        nodes = self.get_nodes()
        kinds = ('timers', 'subscriptions', 'guards', 'clients', 'services')
        per_node = [(node, [[e for e in getattr(node, k) if e.callback_group.can_execute(e)]
                            for k in kinds]) for node in nodes]
        waitables = [e for node in nodes for e in node.waitables
                     if e.callback_group.can_execute(e)]
        pointer: dict[int, int] = {}           # id(entity) -> its handle's pointer
        ready_waitables = []
        with ExitStack() as stack:
            def entered(entities) -> list:
                kept = []
                for e in entities:
                    try:
                        stack.enter_context(e.handle)
                    except InvalidHandle:         # destroyed meanwhile
                        continue
                    pointer[id(e)] = e.handle.pointer
                    kept.append(e)
                return kept

            timers, subs, guards, clients, services = (
                entered(e for _, lists in per_node for e in lists[i]) for i in range(5))
            guards += entered([self._guard, self._sigint_gc])
            count = NumberOfEntities(len(subs), len(guards), len(timers), len(clients),
                                     len(services))
            kept = []
            for w in waitables:
                try:
                    stack.enter_context(w)
                except InvalidHandle:
                    continue
                count += w.get_num_entities()
                kept.append(w)
            waitables = kept
            stack.enter_context(self._context.handle)
            size = (count.num_subscriptions, count.num_guard_conditions, count.num_timers,
                    count.num_clients, count.num_services, count.num_events)
            if size != self._wait_set_size:
                self._wait_set = _rclpy.WaitSet(*size, self._context.handle)
                self._wait_set_size = size
            ws = self._wait_set
            ws.clear_entities()
            for e in subs:
                ws.add_subscription(e.handle)
            for e in clients:
                ws.add_client(e.handle)
            for e in services:
                ws.add_service(e.handle)
            for e in timers:
                ws.add_timer(e.handle)
            for e in guards:
                ws.add_guard_condition(e.handle)
            for w in waitables:
                w.add_to_wait_set(ws)

            ws.wait(timeout_nsec)
            if self._is_shutdown:
                return
            if not self._context.ok():
                raise ExternalShutdownException()
            ready = set()
            for kind in ('timer', 'subscription', 'guard_condition', 'client', 'service'):
                ready.update(ws.get_ready_entities(kind))
            for w in waitables:                 # while the wait set still holds them
                if w.is_ready(ws):
                    ready_waitables.append(w)

        for w in ready_waitables:
            self._execute(w, lambda e: self._run(self._take_waitable(e)))
        work = (self._timer, self._subscription, lambda g: self._call(g.callback),
                lambda c: self._run(self._take_client(c)),
                lambda s: self._run(self._take_service(s)))
        for _, lists in per_node:               # rclpy's order: node by node, kind by kind
            for entities, run in zip(lists, work):
                for e in entities:
                    if pointer.get(id(e)) in ready:
                        self._execute(e, run)

    def _execute(self, entity, work: Callable[[Any], None]) -> None:
        group = entity.callback_group
        if not group.beginning_execution(entity):
            return                   # e.g. an on-demand group turned off by a callback before
        try:
            work(entity)
        finally:
            group.ending_execution(entity)

    def _timer(self, tmr) -> None:
        try:
            with tmr.handle:
                # rcl reports a cancelled timer ready: check, as rclpy does
                if not tmr.handle.is_timer_ready():
                    return
                tmr.handle.call_timer()
        except InvalidHandle:
            return
        self._call(tmr.callback)

    def _subscription(self, sub) -> None:
        try:
            with sub.handle:
                msg_info = sub.handle.take_message(sub.msg_type, sub.raw)
        except InvalidHandle:
            return
        if msg_info is None:
            return
        if sub._callback_type is sub.CallbackType.MessageOnly:
            self._call(sub.callback, msg_info[0])
        else:
            self._call(sub.callback, *msg_info)
