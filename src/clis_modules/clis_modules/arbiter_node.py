"""``ros2 run clis_modules arbiter``: picks the acting module by (3) and drives ``cmd_vel``.

Subscribes to the proposals of the condition's modules (``<module>/proposal``) and to the
``episode`` events; arbitrates through the same :class:`~clis_modules.core.arbiter.Selector` as
the headless runner (twist_mux style): at an episode ``start`` it waits for every module's
first proposal (at most ``arbiter.start_timeout`` s) and draws the acting module by (3) from
their values (``arbiter.selection: episode``), or redraws at every proposal (``decision``);
it executes the acting module's proposal clipped to that module's speed limit; a module whose
latest proposal is older than ``arbiter.stale_periods`` of its periods is dropped from the
selection (another one is drawn), and with none fresh the robot is commanded to stop.

Publishes ``cmd_vel`` (geometry_msgs/TwistStamped stamped with the time of the sensor readings
the command was decided on; plain Twist with ``arbiter_node.cmd_vel_stamped:=false``),
``~/selection`` (every draw: the acting module in ``header.frame_id``, ``Pr(i | x)`` and the
values) and ``~/action`` (every command: the acting module's proposal, not clipped, which the
learner's densities are of). Layouts in :mod:`clis_modules.conversions`.
"""

from __future__ import annotations

from cr_sim.core.params import dataclass, param
from cr_sim.core.sim import load_sim_params
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped
import numpy as np
from sensor_msgs.msg import JointState

from clis_modules import conversions as conv
from clis_modules.core.arbiter import Command, Selector
from clis_modules.core.modules import (
    CommonParams,
    condition_periods,
    module_gamma,
    speed_limit,
)
from clis_modules.graph_node import GraphNode, run_node
from clis_modules.module_node import END_EVENTS, LATCHED
from cr_sim import conversions as rconv

__all__ = ['ArbiterNodeParams', 'ArbiterNode', 'main']


@dataclass(frozen=True)
class ArbiterNodeParams:
    """Settings of the arbiter node (``config/graph.yaml``, section ``arbiter_node``)."""

    check_period: float = param(0.001, 10.0, doc='period of the staleness check [s, clock]')
    cmd_vel_stamped: bool = param(doc='cmd_vel is TwistStamped (true) or Twist (false)')
    base_frame: str = param(doc='frame_id of the stamped cmd_vel')


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
        super().__init__('arbiter', 'arbiter_node', ArbiterNodeParams)
        common = self.clis.common
        names, gammas, v_max, taus = module_timing(
            common, condition_periods(self.clis, self.graph.condition))
        self.names = names
        self.selector = Selector(names, gammas, v_max, taus, self.clis.arbiter, common.beta,
                                 np.random.default_rng([self.graph.seed, 3]))
        self.wheel_base = load_sim_params().robot.wheel_base
        cmd_type = TwistStamped if self.cfg.cmd_vel_stamped else Twist
        self.pub_cmd = self.create_publisher(cmd_type, 'cmd_vel', 10)
        self.pub_selection = self.create_publisher(JointState, '~/selection', 10)
        self.pub_action = self.create_publisher(JointState, '~/action', 10)
        for name in names:
            self.create_subscription(JointState, f'{name}/proposal', self._on_proposal, 10)
        self.create_subscription(DiagnosticArray, 'episode', self._on_episode, LATCHED)
        self.create_timer(self.cfg.check_period, self._on_check)
        self.get_logger().info(
            f'arbiter: condition {self.graph.condition}, modules {", ".join(names)}, '
            f'selection per {self.selector.mode}, beta {common.beta}')

    def _on_episode(self, msg: DiagnosticArray) -> None:
        t, event, _ = rconv.episode_from_msg(msg)
        if event == 'start':
            self.selector.begin_episode(t)
        elif event in END_EVENTS and self.selector.running:
            self._publish(self.selector.end_episode())

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
        self._publish(self.selector.on_proposals([p], self.now_s()))

    def _on_check(self) -> None:
        self._publish(self.selector.check(self.now_s()))

    def _publish(self, cmd: Command | None) -> None:
        if cmd is None:
            return
        acting = self.names[cmd.module] if cmd.module >= 0 else ''
        self.pub_cmd.publish(rconv.cmd_from_wheels(cmd.u_exec, self.wheel_base, cmd.t,
                                                   self.cfg.base_frame,
                                                   self.cfg.cmd_vel_stamped))
        self.pub_action.publish(conv.action_msg(cmd.t, cmd.u, acting))
        if cmd.drawn:
            self.pub_selection.publish(conv.selection_msg(
                self.names, self.selector.probs, self.selector.values, acting, cmd.t))


def main(args: list[str] | None = None) -> None:
    run_node(ArbiterNode, 'arbiter', __doc__, args)


if __name__ == '__main__':
    main()
