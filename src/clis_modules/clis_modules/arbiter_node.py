"""``ros2 run clis_modules arbiter``: picks the acting module by (3) and drives ``cmd_vel``.

Subscribes to the proposals of the condition's modules (``<module>/proposal``) and to the
``episode`` events; arbitrates through the same :class:`~clis_modules.core.arbiter.Selector` as
the headless runner (twist_mux style): at an episode ``start`` it waits for every module's
first proposal (at most ``arbiter.start_timeout`` s) and draws the acting module by (3) from
their values (``arbiter.selection: episode``), or redraws at every proposal (``decision``);
it executes the acting module's proposal clipped to that module's speed limit; a module whose
latest proposal is older than ``arbiter.stale_periods`` of its periods is dropped from the
selection (another one is drawn), and with none fresh the robot is commanded to stop.

Lockstep (under sim time, ``arbiter_node.lockstep``): the arbiter answers every decision
instant ``t_0 + l tau_i`` of the condition's modules: once every decision due at that instant
has been proposed (at most ``arbiter_node.lockstep_timeout`` wall seconds, then the late module
counts as missing), the Selector gets them together, as in the headless runner, and
``cmd_vel`` is sent stamped with the instant even if the command did not change; a simulator in
lockstep (``node.lockstep``, holding at the same instants) waits for it before the next tick
(:mod:`clis_modules.core.lockstep`). Between two decision instants the command cannot change
and the simulator does not wait: they get no ``cmd_vel``. In lockstep the arbiter takes
``/clock`` on demand (:meth:`~clis_base.ros.graph_node.GraphNode.clock_on_demand`): an
instant opens when a proposal stamped with it arrives, or when the clock, read at every
proposal and every 10 ms of wall time, stands at it (an instant whose due modules are all
missing), so the arbiter is not woken at every tick.

Publishes ``cmd_vel`` (geometry_msgs/TwistStamped stamped with the time of the sensor readings
the command was decided on; plain Twist with ``arbiter_node.cmd_vel_stamped:=false``) and the
same command as ``wheels_cmd`` (sensor_msgs/JointState, the wheel velocities exactly: a robot
taking ``node.command: wheels_cmd`` executes them without a round trip through (v, w), as the
headless runner does),
``~/selection`` (every draw: the acting module in ``header.frame_id``, ``Pr(i | x)`` and the
values) and ``~/action`` (every command: the acting module's proposal, not clipped, which the
learner's densities are of). Layouts in :mod:`clis_modules.conversions`.
"""

from __future__ import annotations

import math
import time

from clis_base.instants import DecisionClock
from clis_base.params import dataclass, param
from clis_base.ros.graph_node import GraphNode, run_node
from clis_base.trace import mark
from cr_sim.core.robot import load_robot_params
from cr_sim.core.sim import load_sim_params
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from sensor_msgs.msg import JointState

from clis_modules import conversions as conv
from clis_modules.core.arbiter import Command, Selector, refuse_bonus
from clis_modules.core.draws import AgentStream, selection_draws
from clis_modules.core.lockstep import TickBarrier
from clis_modules.core.modules import (
    CommonParams,
    ModuleSetParams,
    condition_periods,
    module_gamma,
    speed_limit,
)
from clis_modules.core.plugin import parse_condition
from clis_modules.module_node import END_EVENTS, LATCHED
from cr_sim import conversions as rconv

__all__ = ['ArbiterNodeParams', 'ArbiterNode', 'main']


@dataclass(frozen=True)
class ArbiterNodeParams:
    """Settings of the arbiter node (``config/graph.yaml``, section ``arbiter_node``)."""

    check_period: float = param(0.001, 10.0, doc='period of the staleness check [s, clock]')
    cmd_vel_stamped: bool = param(doc='cmd_vel is TwistStamped (true) or Twist (false)')
    base_frame: str = param(doc='frame_id of the stamped cmd_vel')
    lockstep: bool = param(doc='under sim time, answer every instant once its due decisions '
                           'are in')
    lockstep_timeout: float = param(0.001, 60.0, doc='wall seconds an instant waits for a '
                                    'due decision')
    resend_period: float = param(0.01, 60.0, doc='lockstep: wall seconds the clock stands at '
                                 'an answered instant before the command is sent again')


def module_timing(common: CommonParams, periods: list[tuple[str, float]]
                  ) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """Names, ``gamma_i`` (11), speed limits and periods of the modules ``(name, tau_i)``."""
    names = [name for name, _ in periods]
    taus = np.array([tau for _, tau in periods])
    return (names, np.array([module_gamma(common, tau) for tau in taus]),
            np.array([speed_limit(common, tau) for tau in taus]), taus)


class ArbiterNode(GraphNode):
    """Thin glue around a :class:`Selector` (module docstring)."""

    def __init__(self) -> None:
        super().__init__('arbiter', 'arbiter_node', ArbiterNodeParams, clis_cls=ModuleSetParams,
                         check_condition=parse_condition)
        refuse_bonus(self.clis.arbiter.bonus)
        common = self.clis.common
        names, gammas, v_max, taus = module_timing(
            common, condition_periods(self.clis, self.graph.condition))
        self.names = names
        # the selections' draws: the headless runner's agent stream (seed, 2), replayed over
        # the condition's decision instants (clis_base.agent_stream); off them (real time, a
        # timeout) from (seed, 3)
        self.clock_periods = [float(tau) for tau in taus]
        self.clock = DecisionClock(self.clock_periods, load_sim_params().episode.dt)
        self.stream = AgentStream(np.random.default_rng([self.graph.seed, 2]), len(names),
                                  self.clis.arbiter.selection, self.clock,
                                  fallback=np.random.default_rng([self.graph.seed, 3]))
        self.selector = Selector(names, gammas, v_max, taus, self.clis.arbiter, common.beta,
                                 selection_draws(self.stream))
        self.t0: float | None = None
        self.wheel_base = load_robot_params().wheel_base
        cmd_type = TwistStamped if self.cfg.cmd_vel_stamped else Twist
        self.pub_cmd = self.create_publisher(cmd_type, 'cmd_vel', rconv.STREAM_DEPTH)
        self.pub_selection = self.create_publisher(JointState, '~/selection', rconv.STREAM_DEPTH)
        self.pub_action = self.create_publisher(JointState, '~/action', rconv.STREAM_DEPTH)
        # the same command as the wheels themselves (a robot taking node.command: wheels_cmd)
        self.pub_wheels_cmd = self.create_publisher(JointState, 'wheels_cmd',
                                                    rconv.STREAM_DEPTH)
        for name in names:
            self.create_subscription(
                JointState, f'{name}/proposal', self._on_proposal, self.graph.proposal_qos(),
                event_callbacks=SubscriptionEventCallbacks(
                    liveliness=lambda e, n=name: self._on_liveliness(n, e.alive_count)))
        self.create_subscription(DiagnosticArray, 'episode', self._on_episode, LATCHED)
        self.barrier = None
        self.u_exec = np.zeros(2)                    # the command in force
        self.sent = None              # (cmd_vel, stamp, wall time, wheels_cmd) sent last
        self._advancing = False
        if self.cfg.lockstep and self.sim_time:
            self.barrier = TickBarrier(names, taus, self.cfg.lockstep_timeout, self.clock.dt)
            self.clock_on_demand()
            self.on_clock_advance(self._on_tick)
            self.create_timer(0.01, self._advance, clock=Clock(clock_type=ClockType.STEADY_TIME))
        else:
            self.create_timer(self.cfg.check_period, self._on_check)
        self.defer_housekeeping()
        self.get_logger().info(
            f'arbiter: condition {self.graph.condition}, modules {", ".join(names)}, '
            f'selection per {self.selector.mode}, beta {common.beta}'
            f'{", lockstep" if self.barrier else ""}')

    def _on_episode(self, msg: DiagnosticArray) -> None:
        t, event, values = rconv.episode_from_msg(msg)
        if event == 'start':
            dt = float(values.get('dt', self.clock.dt))
            if dt != self.clock.dt:
                self.clock = self.stream.clock = DecisionClock(self.clock_periods, dt)
            if 'agent_state' in values:              # the stream where the simulator says
                self.stream.set_state(values['agent_state'])
            else:
                self.stream.begin_episode()
            self.t0 = t
            self.selector.begin_episode(t)
            if self.barrier is not None:
                self.barrier.begin_episode(t, dt)
                self.barrier.on_tick(t, time.monotonic())     # the clock may be there already
                self._advance()
        elif event in END_EVENTS and self.selector.running:
            if self.t0 is not None and (k := self.clock.tick(t, self.t0)) is not None:
                self.stream.end_episode(k)
            self.t0 = None
            if self.barrier is not None:
                self.barrier.end_episode()
            self._publish(self.selector.end_episode(t))     # after all of its actions

    def _on_proposal(self, msg: JointState) -> None:
        try:
            p = conv.proposal_from_msg(msg)
        except ValueError as exc:
            self.get_logger().error(f'ignored proposal: {exc}')
            return
        if p.module not in self.selector.index:
            self.get_logger().error(f'ignored proposal of unknown module {p.module!r}')
            return
        if not (np.all(np.isfinite(p.u)) and np.isfinite(p.value)):
            self.get_logger().error(f'ignored non-finite proposal of {p.module}')
            return
        mark('arb_prop_' + p.module, p.t)
        if self.barrier is not None:
            if self._clock_sub is not None:
                self.take_clock()                    # (may open the instant: _on_tick)
            # a proposal of instant t: the clock has reached it
            if self.barrier.is_instant(p.t):
                self.barrier.on_tick(p.t, time.monotonic())
            self.barrier.on_proposal(p)
            self._advance()
        else:
            self._instant(p.t)
            self._publish(self.selector.on_proposals([p], self.now_s()))

    def _on_liveliness(self, name: str, alive: int) -> None:
        """No live publisher of ``name``'s proposals (its process died): stop waiting for it
        at once (it rejoins with its next proposal). Live again (a lease that lapsed while
        the machine was busy, e.g. at start-up, or a restarted module): wait for it again."""
        if alive == 0:
            self.get_logger().warning(f'{name} is gone (liveliness lost): not waiting for it')
            if self.barrier is not None:
                self.barrier.lost(name)
                self._advance()
        elif self.barrier is not None and self.barrier.index[name] in self.barrier.missing:
            self.get_logger().info(f'{name} is alive again: waiting for its decisions')
            self.barrier.alive(name)

    def _on_check(self) -> None:
        self._publish(self.selector.check(self.now_s()))

    def _on_tick(self, t: float) -> None:
        if self.barrier.is_instant(t):               # between two the clock does not wait
            self.barrier.on_tick(t, time.monotonic())
            if not self._advancing:
                self._advance()

    def _advance(self) -> None:
        """Answer the instants whose due decisions are in (lockstep); send the last answer
        again while the clock stands at its instant (the simulator did not get it)."""
        self._advancing = True
        try:
            self._answer()
        finally:
            self._advancing = False

    def _answer(self) -> None:
        if self._clock_sub is not None:
            self.take_clock()                        # (may open an instant: _on_tick)
        now = time.monotonic()
        if self.sent is not None and self.barrier.running \
                and now - self.sent[2] >= self.cfg.resend_period \
                and self.now_s() <= self.sent[1] + 1e-6:
            self.pub_cmd.publish(self.sent[0])
            self.pub_wheels_cmd.publish(self.sent[3])
            self.sent = (*self.sent[:2], now, self.sent[3])
        missing = set(self.barrier.missing)
        oldest = self.barrier.open[0][0] if self.barrier.open else math.nan
        answered = self.barrier.ready(now)
        if late := self.barrier.missing - missing:
            self.get_logger().warning(
                f'lockstep: {", ".join(self.names[i] for i in sorted(late))} did not propose '
                f'for t = {oldest:.3f} s within {self.cfg.lockstep_timeout} s (episode start '
                f'{self.barrier.t0:.3f}): answering without it until it does')
        for t, ps in answered:
            self._instant(t)
            cmd = self.selector.on_proposals(ps, t) if ps else None
            if cmd is None:
                cmd = self.selector.check(t)
            if cmd is not None:
                self._publish(cmd)
            else:                                    # the command in force, for this instant
                self._send(self.u_exec, t)

    def _instant(self, t: float) -> None:
        """The agent stream's draws of instant ``t`` (of the running episode), for the
        selection the arbiter may draw there."""
        if self.t0 is not None and (k := self.clock.tick(t, self.t0)) is not None:
            self.stream.instant(k)

    def _send(self, u_exec: np.ndarray, t: float) -> None:
        self.u_exec = u_exec
        msg = rconv.cmd_from_wheels(u_exec, self.wheel_base, t, self.cfg.base_frame,
                                    self.cfg.cmd_vel_stamped)
        wheels = rconv.wheels_cmd_msg(u_exec, t, self.cfg.base_frame)
        self.pub_cmd.publish(msg)
        self.pub_wheels_cmd.publish(wheels)
        mark('arb_cmd', t)
        self.sent = (msg, t, time.monotonic(), wheels)

    def _publish(self, cmd: Command | None) -> None:
        if cmd is None:
            return
        acting = self.names[cmd.module] if cmd.module >= 0 else ''
        self._send(cmd.u_exec, cmd.t)
        self.pub_action.publish(conv.action_msg(cmd.t, cmd.u, acting))
        if cmd.drawn:
            self.pub_selection.publish(conv.selection_msg(
                self.names, self.selector.probs, self.selector.values, acting, cmd.t))


def main(args: list[str] | None = None) -> None:
    run_node(ArbiterNode, 'arbiter', __doc__, args)


if __name__ == '__main__':
    main()
