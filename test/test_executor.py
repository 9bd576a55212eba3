"""clis_base.ros.executor.LeanExecutor keeps rclpy's executor semantics (real rclpy and
Fast DDS, one process, its own context): subscriptions, timers, guard conditions, services and
clients, QoS events, coroutine callbacks, callback groups that turn themselves off, errors, and
an entity destroyed by a callback."""

from __future__ import annotations

import threading
import time

from clis_base.ros import rclpy_private
from clis_base.ros.executor import LeanExecutor, make_executor
from clis_base.ros.graph_node import GraphNode, OnDemand
from clis_modules.core.modules import ModuleSetParams
import pytest
import rclpy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Int64
from std_srvs.srv import SetBool


@pytest.fixture
def ctx():
    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


def make(ctx, name='lean_probe'):
    node = rclpy.create_node(name, context=ctx)
    executor = LeanExecutor(context=ctx)
    executor.add_node(node)
    return node, executor


def spin_until(executor, done, timeout=10.0) -> bool:
    end = time.monotonic() + timeout
    while not done() and time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    return done()


def test_subscriptions_timers_and_guard_conditions_run_in_order_of_arrival(ctx):
    node, ex = make(ctx)
    got, ticks, guarded = [], [], []
    pub = node.create_publisher(Int64, 'lean_topic', 50)
    node.create_subscription(Int64, 'lean_topic', lambda m: got.append(m.data), 50)
    node.create_timer(0.01, lambda: ticks.append(1))
    gc = node.create_guard_condition(lambda: guarded.append(1))
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    for i in range(20):
        pub.publish(Int64(data=i))
    gc.trigger()
    assert spin_until(ex, lambda: len(got) == 20 and len(ticks) >= 3 and guarded)
    assert got == list(range(20))
    assert guarded == [1]                     # a guard condition fires once per trigger
    ex.spin_once(timeout_sec=0.05)
    assert guarded == [1]


def test_services_clients_and_futures(ctx):
    node, ex = make(ctx)
    def answer(req, resp):
        resp.success, resp.message = req.data, 'answered'
        return resp

    node.create_service(SetBool, 'lean_srv', answer)
    client = node.create_client(SetBool, 'lean_srv')
    assert spin_until(ex, client.service_is_ready)
    future = client.call_async(SetBool.Request(data=True))
    ex.spin_until_future_complete(future, timeout_sec=10.0)
    assert future.done() and future.result().success and future.result().message == 'answered'


def test_coroutine_callbacks_and_tasks_finish_across_waits(ctx):
    node, ex = make(ctx)
    done = []
    gate = rclpy.task.Future()

    async def later():
        await gate                            # not done at the first wait: stays a task
        done.append('coroutine')

    timer = node.create_timer(0.01, later)
    assert spin_until(ex, ex.has_tasks)        # the first tick left a task in progress
    timer.cancel()
    gate.set_result(True)
    assert spin_until(ex, lambda: done)


def test_a_created_task_runs_to_its_result(ctx):
    _, ex = make(ctx)
    task = ex.create_task(lambda: 7)
    assert spin_until(ex, lambda: task.done() and not ex.has_tasks())
    assert not task.cancelled() and task.result() == 7


def test_an_on_demand_group_is_waited_on_only_while_active(ctx):
    node, ex = make(ctx)
    group = OnDemand()
    got = []
    pub = node.create_publisher(Int64, 'lean_demand', 10)

    def on_msg(m):
        got.append(m.data)
        group.active = False                  # turns itself off: the second waits its turn

    node.create_subscription(Int64, 'lean_demand', on_msg, 10, callback_group=group)
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    pub.publish(Int64(data=1))
    pub.publish(Int64(data=2))
    for _ in range(10):
        ex.spin_once(timeout_sec=0.02)
    assert got == []                          # inactive: the messages wait in the queue
    group.active = True
    assert spin_until(ex, lambda: got)
    for _ in range(10):
        ex.spin_once(timeout_sec=0.02)
    assert got == [1]
    group.active = True
    assert spin_until(ex, lambda: got == [1, 2])


def test_qos_events_reach_their_callback(ctx):
    node, ex = make(ctx)
    events = []
    node.create_subscription(
        Int64, 'lean_qos', lambda m: None,
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        event_callbacks=SubscriptionEventCallbacks(
            incompatible_qos=lambda e: events.append(e.total_count)))
    node.create_publisher(Int64, 'lean_qos',
                          QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    assert spin_until(ex, lambda: events)
    assert events == [1]


def test_a_callback_error_is_raised_and_a_destroyed_entity_is_skipped(ctx):
    node, ex = make(ctx)
    pub = node.create_publisher(Int64, 'lean_err', 10)
    subs, calls, other = [], [], []

    def destroy_self(m):
        calls.append(m.data)
        node.destroy_subscription(subs[0])

    subs.append(node.create_subscription(Int64, 'lean_err', destroy_self, 10))
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    pub.publish(Int64(data=1))
    assert spin_until(ex, lambda: subs[0] not in list(node.subscriptions))
    assert calls == [1]
    # another reader of the topic gets the next message; the destroyed one is not called
    node.create_subscription(Int64, 'lean_err', lambda m: other.append(m.data), 10)
    assert spin_until(ex, lambda: pub.get_subscription_count() == 1)
    pub.publish(Int64(data=2))
    assert spin_until(ex, lambda: other == [2]), other
    assert calls == [1], 'a destroyed subscription was called'
    # destroyed by another callback while its own message waits (both ready at one wait):
    # skipped, no error
    pub2 = node.create_publisher(Int64, 'lean_err2', 10)
    victim, killer_calls, victim_calls = [], [], []

    def kill(m):
        killer_calls.append(m.data)
        if victim:
            node.destroy_subscription(victim.pop())
            killer_calls.append('destroyed')

    node.create_subscription(Int64, 'lean_err2', kill, 10)
    victim.append(node.create_subscription(
        Int64, 'lean_err2', lambda m: victim_calls.append('destroyed' in killer_calls), 10))
    assert spin_until(ex, lambda: pub2.get_subscription_count() == 2)
    pub2.publish(Int64(data=3))
    assert spin_until(ex, lambda: killer_calls == [3, 'destroyed']), killer_calls
    pub2.publish(Int64(data=4))
    assert spin_until(ex, lambda: killer_calls[-1] == 4), killer_calls
    assert True not in victim_calls, 'called after it was destroyed'

    def fail():
        raise RuntimeError('callback failed')

    node.create_timer(0.01, fail)
    with pytest.raises(RuntimeError, match='callback failed'):
        spin_until(ex, lambda: False, timeout=2.0)


def test_spin_ends_when_the_context_shuts_down(ctx):
    node, ex = make(ctx)
    node.create_timer(0.05, lambda: rclpy.try_shutdown(context=ctx))
    ended = []

    def spin() -> None:
        try:
            ex.spin()
        except rclpy.executors.ExternalShutdownException:
            pass
        ended.append(True)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    thread.join(120.0)                                  # a hang guard, not a window
    assert ended == [True], 'spin went on after the context shut down'


class _Log:
    def __init__(self) -> None:
        self.warnings: list[str] = []

    def warning(self, text: str) -> None:
        self.warnings.append(text)


def test_the_lean_executor_is_made_for_the_rclpy_it_was_written_for(ctx):
    assert rclpy_private.rclpy_version() == rclpy_private.WRITTEN_FOR, (
        'the installed rclpy is not the one clis_base.ros.rclpy_private was written for: '
        'check its private members, then update WRITTEN_FOR')
    log = _Log()
    assert type(make_executor('lean', logger=log, context=ctx)) is LeanExecutor
    assert not log.warnings


@pytest.mark.parametrize('version', ['7.1.6', '8.0.0', None])
def test_on_another_rclpy_the_executor_falls_back_to_rclpys_with_a_warning(ctx, monkeypatch,
                                                                         version):
    monkeypatch.setattr(rclpy_private, 'rclpy_version', lambda: version)
    assert not rclpy_private.supported()
    log = _Log()
    executor = make_executor('lean', logger=log, context=ctx)
    assert type(executor) is SingleThreadedExecutor
    assert len(log.warnings) == 1 and rclpy_private.WRITTEN_FOR in log.warnings[0]
    assert type(make_executor('single', logger=log, context=ctx)) is SingleThreadedExecutor
    assert len(log.warnings) == 1                 # only 'lean' needs the private API


def test_on_another_rclpy_a_graph_node_takes_its_clock_as_any_subscription(ctx, monkeypatch):
    monkeypatch.setattr(rclpy_private, 'rclpy_version', lambda: '0.0.0')
    node = GraphNode('fallback_probe', clis_cls=ModuleSetParams, context=ctx)
    try:
        assert node.sim_time
        node.clock_on_demand()
        assert node._clock_sub is None             # /clock stays an ordinary subscription
        assert rclpy_private.clock_subscription(node) is None
    finally:
        node.destroy_node()
