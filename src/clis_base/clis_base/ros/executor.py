"""A lean single-threaded executor: rclpy's, with one wait per batch of ready work.

rclpy's :class:`~rclpy.executors.SingleThreadedExecutor` (Jazzy) wraps every callback in a
:class:`~rclpy.task.Task` and a coroutine, and each callback triggers the executor's own guard
condition twice, so that the next wait returns at once and the whole wait set is rebuilt in
Python again: a message costs two or three waits. On the sensor-to-command path of the CLIS
graph (the simulator's ``/clock`` and readings -> module -> proposal -> arbiter -> ``cmd_vel``)
that overhead, not the decisions, is most of each hop (bench/bench_hops.py measures it).

:class:`LeanExecutor` keeps rclpy's semantics (callback groups' ``can_execute`` /
``beginning_execution`` / ``ending_execution``, one message per ready subscription per wait,
timers, guard conditions, services, clients, waitables such as QoS events, tasks and
coroutine callbacks, ``spin_until_future_complete``, shutdown and Ctrl-C) and changes only how
it gets there: one wait, then every ready entity's callback called directly, in rclpy's order
(waitables, then per node timers, subscriptions, guard conditions, clients, services). The wait
set object is reused while the number of entities stays the same.

It relies on rclpy's internals, reached only through :mod:`clis_base.ros.rclpy_private`:
on an rclpy other than the one that module was written for, :func:`make_executor` gives
rclpy's SingleThreadedExecutor instead (same results, slower) and logs a warning.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
import inspect
from typing import Any

from rclpy.client import Client
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.guard_condition import GuardCondition
from rclpy.service import Service
from rclpy.subscription import Subscription
from rclpy.task import Task
from rclpy.timer import Timer
from rclpy.waitable import NumberOfEntities

from clis_base.ros import rclpy_private as rp
from clis_base.trace import TRACING, mark

__all__ = ['EXECUTORS', 'LeanExecutor', 'make_executor']

#: The executors a node can spin on (``graph.executor``, the simulator's ``node.executor``)
EXECUTORS = ('lean', 'single', 'events')


class LeanExecutor(rp.PrivateExecutor):
    """Single-threaded executor that runs ready callbacks directly after one wait.

    A drop-in for :class:`~rclpy.executors.SingleThreadedExecutor` (``add_node``, ``spin``,
    ``spin_once``, ``spin_until_future_complete``, ``create_task``, ``shutdown``).
    """

    def __init__(self, *, context=None) -> None:
        super().__init__(context=context)
        self._plan: _Plan | None = None

    # --------------------------------------------------------------- tasks

    def _run_tasks(self) -> None:
        """Run or resume the tasks in progress (``create_task``, coroutine callbacks), as
        rclpy does before each wait."""
        tasks = self.pending_tasks()
        if not tasks:
            return
        for task in reversed(tasks):
            if not task.executing() and not task.done():
                task()
                if task.done() and task.exception() is not None:
                    raise task.exception()
        self.prune_tasks()

    def _run(self, work: Callable[[], Any] | Coroutine | None) -> None:
        """Run an rclpy ``_take_*`` result (an ``async def`` or None) or a coroutine to
        completion, or leave it as a task in progress if it awaits something not done yet."""
        if work is None:
            return
        task = Task(work, executor=self)
        task()
        if not task.done():
            self.add_task(task)
        elif task.exception() is not None:
            raise task.exception()

    def _call(self, callback: Callable[..., Any], *args: Any) -> None:
        """Call a callback; a coroutine it returns continues as a task."""
        result = callback(*args)
        if inspect.iscoroutine(result):
            self._run(result)

    # --------------------------------------------------------------- the wait

    def _active(self) -> tuple:
        """The entities to wait on now: every node's entities whose callback group can run
        them (an :class:`~clis_base.ros.graph_node.OnDemand` group turns on and off), in
        rclpy's order (node by node: timers, subscriptions, guard conditions, clients,
        services), then the waitables (QoS events); a tuple that is the plan's key."""
        active, waitables = [], []
        for node in self.get_nodes():
            for kind in _KINDS:
                for e in rp.node_entities(node, kind):
                    if e.callback_group.can_execute(e):
                        active.append(e)
            waitables += [w for w in node.waitables if w.callback_group.can_execute(w)]
        active += waitables
        return tuple(active)

    def _plan_for(self, key: tuple) -> _Plan:
        if self._plan is None or self._plan.key != key:
            self._plan = _Plan(key, self, self._plan)
        return self._plan

    def wait_and_dispatch(self, timeout_nsec: int) -> None:
        if self.has_tasks():
            self._run_tasks()
        plan = self._plan_for(self._active())
        entered = []
        try:
            for cm in plan.guarded:                  # in use: not destroyed while waited on
                cm.__enter__()
                entered.append(cm)
        except InvalidHandle:                        # destroyed meanwhile: plan again
            self._plan = None
            return
        else:
            ws = plan.wait_set
            ws.clear_entities()
            for add, handle in plan.adds:
                add(handle)
            for w in plan.waitables:
                w.add_to_wait_set(ws)
            ws.wait(timeout_nsec)
            if self.is_shut_down:
                return
            if not self.context.ok():
                raise ExternalShutdownException()
            ready = set()
            for kind in plan.kinds:
                ready.update(ws.get_ready_entities(kind))
            ready_waitables = [w for w in plan.waitables if w.is_ready(ws)]
        finally:
            for cm in reversed(entered):
                cm.__exit__(None, None, None)
        for w in ready_waitables:
            self._execute(w, self._waitable)
        for entity, pointer, run in plan.dispatch:
            if pointer in ready:
                self._execute(entity, run)

    def _waitable(self, w) -> None:
        self._run(self.take_waitable(w))

    def _execute(self, entity, work: Callable[[Any], None]) -> None:
        group = entity.callback_group
        if not group.beginning_execution(entity):
            return                   # e.g. an on-demand group turned off by a callback before
        try:
            work(entity)
        finally:
            group.ending_execution(entity)

    def _guard_condition(self, gc) -> None:
        self._call(gc.callback)

    def _client(self, client) -> None:
        self._run(self.take_client(client))

    def _service(self, srv) -> None:
        self._run(self.take_service(srv))

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
        if rp.message_only(sub):
            self._call(sub.callback, msg_info[0])
        else:
            self._call(sub.callback, *msg_info)


def make_executor(kind: str, logger=None, context=None):
    """An executor of :data:`EXECUTORS`: ``'lean'``, :class:`LeanExecutor`; ``'single'``,
    rclpy's SingleThreadedExecutor; ``'events'``, rclpy's EventsExecutor.

    ``'lean'`` on an rclpy other than :data:`~clis_base.ros.rclpy_private.WRITTEN_FOR`
    gives rclpy's SingleThreadedExecutor, with a warning to ``logger`` (default: the rclpy
    logger ``executor``). ``context``: rclpy's default one if None."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'lean':
        if rp.supported():
            return LeanExecutor(context=context)
        if logger is None:
            from rclpy.logging import get_logger
            logger = get_logger('executor')
        logger.warning(
            f"executor 'lean' is written for rclpy {rp.WRITTEN_FOR}, not "
            f"{rp.rclpy_version() or 'an unknown version'}: using rclpy's "
            'SingleThreadedExecutor (same results, slower; clis_base.ros.rclpy_private)')
    return SingleThreadedExecutor(context=context)


#: Node entity lists in rclpy's order of execution, and the wait set's name of each kind
_KINDS = ('timers', 'subscriptions', 'guards', 'clients', 'services')
_CLASSES = ((Timer, 'timers'), (Subscription, 'subscriptions'), (GuardCondition, 'guards'),
            (Client, 'clients'), (Service, 'services'))
_READY = {'timers': 'timer', 'subscriptions': 'subscription', 'guards': 'guard_condition',
          'clients': 'client', 'services': 'service'}


class _Plan:
    """What one composition of active entities needs at every wait, computed once: the
    handles to hold, the wait set (kept from the last plan while the entity counts stay the
    same), the calls that fill it, the kinds to ask for readiness, and each entity's pointer
    and runner in the order of ``key``."""

    def __init__(self, key: tuple, executor: LeanExecutor, last: _Plan | None) -> None:
        (guard, sigint_gc), context = executor.wake_guards(), executor.context
        self.key = key
        by_kind: dict[str, list] = {k: [] for k in _KINDS}
        self.waitables = []
        kinds = []
        for e in key:
            kind = next((k for cls, k in _CLASSES if isinstance(e, cls)), None)
            if kind is None:
                self.waitables.append(e)
            else:
                by_kind[kind].append(e)
                kinds.append((e, kind))
        guards = by_kind['guards'] + [guard, sigint_gc]
        count = NumberOfEntities(len(by_kind['subscriptions']), len(guards),
                                 len(by_kind['timers']), len(by_kind['clients']),
                                 len(by_kind['services']))
        for w in self.waitables:
            count += w.get_num_entities()
        self.size = (count.num_subscriptions, count.num_guard_conditions, count.num_timers,
                     count.num_clients, count.num_services, count.num_events)
        self.wait_set = (last.wait_set if last is not None and last.size == self.size
                         else rp.new_wait_set(self.size, context.handle))
        ws = self.wait_set
        self.guarded = [*(e.handle for e, _ in kinds), guard.handle, sigint_gc.handle,
                        *self.waitables, context.handle]
        adders = {'subscriptions': ws.add_subscription, 'clients': ws.add_client,
                  'services': ws.add_service, 'timers': ws.add_timer,
                  'guards': ws.add_guard_condition}
        self.adds = [(adders[k], e.handle)
                     for k in ('subscriptions', 'clients', 'services', 'timers')
                     for e in by_kind[k]]
        self.adds += [(ws.add_guard_condition, g.handle) for g in guards]
        self.kinds = [_READY[k] for k in _KINDS if by_kind[k]]
        runners = {'timers': executor._timer, 'subscriptions': executor._subscription,
                   'guards': executor._guard_condition, 'clients': executor._client,
                   'services': executor._service}
        self.dispatch = [(e, e.handle.pointer, runners[k]) for e, k in kinds]


def trace_executor_wakeups() -> None:
    """Mark ``wake`` (:func:`clis_base.trace.mark`) each time an rclpy executor's wait returns
    in this process (with ``CLIS_TRACE``): splits a hop into the wakeup itself and the
    executor's Python work up to the callback."""
    if TRACING:
        rp.wrap_executor_waits(lambda: mark('wake'))


trace_executor_wakeups()
