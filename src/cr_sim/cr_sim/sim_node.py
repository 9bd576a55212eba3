"""``ros2 run cr_sim sim``: the Cyber Rodent simulator as a ROS 2 node.

Publishes the robot interface (see :mod:`cr_sim.conversions` and the topic table of docs/robot.md),
ground-truth ``odom``, ``markers`` and ``/clock``; subscribes to ``cmd_vel``; offers the
``reset`` service (std_srvs/Trigger). The episodes (starts, ends, rewards, the clock, the
resume state, the commands and the holds) are :class:`cr_sim.core.sim_episodes.SimEpisodes`
around the simulator core (:class:`cr_sim.core.sim.Simulator`), which steps at ``episode.dt``
of sim time; the node paces it at ``node.speed_factor`` times real time (0 = as fast as
possible). Timers of nodes running with ``use_sim_time`` skip rather than replay
missed periods (docs/design.md §8), so one tick of sim time (50 ms) must stay below the shortest
module period (250 ms): it does by construction.

Gates (:mod:`cr_sim.core.gate`): with ``node.start_subscribers`` the first episode waits until
the graph's subscribers of the robot interface are matched (a message published before is
never delivered to them); with ``node.wait_for_learner`` each episode waits for the learner;
with ``node.lockstep`` each decision instant waits for its command.

World mode (``node.episodes: false``): a plain robot world for the standard path, where
another node (the robot adapter, ``ros2 run cr_bridge robot``) makes the episodes from the
robot's own sensors: one unending run from the first start, the robot driving under
``cmd_vel`` and never teleported, the goal and the time limit ending nothing; no ``episode``
or ``reward`` messages, ``reset`` does nothing, ``node.wait_for_learner`` and ``node.lockstep``
are ignored. ``/clock``, the sensors (and with ``node.standard_topics`` ``image_raw`` and
``scan``) and ``odom`` as always.

Safety: every command goes through :func:`cr_sim.core.robot.clamp_wheels` (NaN/inf -> 0,
clipped to the wheel limit); a command older than ``node.watchdog`` seconds of sim time is
replaced by a stop.
"""

from __future__ import annotations

import time

from clis_base.params import ConfigError, build, config_dir, dataclass, param, ros_parameters
from clis_base.ros.executor import make_executor
from clis_base.ros.process import (
    SHUTDOWN_RACES,
    realtime_logged,
    reraise_unless_shut_down,
    settle_heap,
)
from clis_base.ros.profiling import start_profile, stop_profile
from clis_base.ros.rclpy_private import supported as rp_supported
from clis_base.ros.ros_params import declare_from_config, print_help_and_exit_if_asked
from clis_base.trace import dump as dump_trace
from clis_base.trace import mark
import numpy as np
import rclpy
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from cr_sim import conversions as conv
from cr_sim.core.arena import load_arena
from cr_sim.core.episodes import Event
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.robot import robot_defaults
from cr_sim.core.sim import SimParams
from cr_sim.core.sim_episodes import READINGS, SimEpisodes
from cr_sim.interface import open_robot_interface, parse_counts, unmatched
from cr_sim.standard_topics import StandardTopics

START_CHOICES = ('A', 'B', 'C', 'D', 'E', 'random', 'wander', 'starts')
#: Between the instants a lockstep holds at, callbacks (a reset, a command) are served every
#: this many ticks (each serving costs a wait of the executor: :attr:`SimEpisodes.quiet`).
QUIET_SPIN = 5


@dataclass(frozen=True)
class SimNodeParams:
    """ROS-side settings of the simulator node (``config/sim.yaml``, section ``node``)."""

    arena_file: str = param(doc="arena description; '' = config/arena.yaml")
    speed_factor: float = param(0.0, 1000.0, doc='sim time / wall time; 0 = as fast as possible')
    cmd_vel_stamped: bool = param(doc='cmd_vel is TwistStamped (true) or Twist (false)')
    command: str = param(choices=('cmd_vel', 'wheels_cmd'), doc="the command input: 'cmd_vel' "
                         "(a twist) or 'wheels_cmd' (sensor_msgs/JointState, the wheel "
                         'velocities as decided: exact, no round trip through (v, w); what '
                         "the arbiter sends under 'clis run')")
    watchdog: float = param(0.05, 60.0, doc='stop if no cmd_vel for this long (s, sim time)')
    start: str = param(choices=START_CHOICES, doc='where episodes start')
    auto_reset: bool = param(doc='start a new episode when one ends')
    seed: int = param(0, 2**31 - 1, doc='seed of the simulator generator')
    markers_period: float = param(0.05, 60.0, doc='robot marker period (s, sim time)')
    wait_for_learner: bool = param(doc='after an episode, hold the clock until learner/progress '
                                   'reports it learned')
    learner_timeout: float = param(0.0, 3600.0, doc='wall seconds to wait for the learner')
    start_subscribers: tuple[str, ...] = param(doc="'TOPIC:COUNT' entries: the first "
                                               'episode waits until each topic has that many '
                                               "subscribers (publishers for cmd_vel); [''] = "
                                               'none')
    graph_timeout: float = param(0.0, 3600.0, doc='wall seconds to wait for them')
    lockstep: bool = param(doc='after each instant, hold the clock until a command decided on '
                           'its readings arrives')
    command_timeout: float = param(0.0, 3600.0, doc='wall seconds to wait for that command')
    lockstep_periods: tuple[float, ...] = param(0.0, 60.0, doc='lockstep holds only at the '
                                                'instants t0 + l tau of these periods (the '
                                                "controller's decision periods); 0 = every tick")
    map_frame: str = param(doc='fixed frame of odom and markers')
    base_frame: str = param(doc='robot body frame')
    standard_topics: bool = param(doc="also publish the sensors as a robot's standard topics "
                                  "(image_raw, scan) while someone subscribes to them")
    episodes: bool = param(doc='serve episodes (starts, ends, rewards); false = a plain robot '
                           'world for the standard path: one unending run from the first '
                           'start, never teleported, the goal and the time limit end nothing, '
                           'no episode or reward messages, reset does nothing, '
                           'wait_for_learner ignored, lockstep holds at every tick')
    executor: str = param(choices=('lean', 'single'), doc="rclpy executor: 'lean' "
                          "(clis_base.ros.executor.LeanExecutor) or 'single' "
                          '(SingleThreadedExecutor)')
    realtime_priority: int = param(0, 99, doc='SCHED_FIFO priority of the node (every thread); '
                                   '0 = default scheduling; > 0 also holds the CPU wake-up '
                                   'latency at 0 us (idle cores poll). Fail-soft without the '
                                   'right to it')
    first_episode: int = param(1, 2**31 - 1, doc='number of the first episode; > 1 resumes a '
                               'run (clis run --resume, with resume_state)')
    resume_state: str = param(doc="'' or the resume_state of the end event of the episode "
                              'before first_episode (clis run --resume: from the checkpoint): '
                              'the robot starts its wander where it stood, the clock where it '
                              'went on, the random streams where they stood')
    readings: str = param(choices=READINGS, doc="'tick': IR and camera read "
                          "(their noise drawn) and published at every tick; 'instants': only "
                          'at the decision instants of lockstep_periods, as the headless '
                          'runner reads them (the wheels and the clock at every tick)')
    round_trip_log: str = param(doc="lockstep: append 'sim_time round_trip_ms' of every held "
                                "instant to this file ('' = none); p50/p99 are logged at exit")


class SimNode(Node):
    """Thin glue: parameters -> core; core state -> messages; cmd_vel -> core.

    The episodes, the clock, the commands and the holds are
    :class:`cr_sim.core.sim_episodes.SimEpisodes` (:attr:`core`)."""

    def __init__(self) -> None:
        super().__init__('sim')
        # the body (config/robot.yaml) and the simulator's sections (config/sim.yaml)
        defaults = {**robot_defaults(), **ros_parameters(config_dir() / 'sim.yaml', 'sim')}
        values = declare_from_config(self, defaults)     # errors name the ROS key (main)
        cfg = self.cfg = build(SimNodeParams, values.pop('node'), where='node')
        self.params = build(SimParams, values)
        self.arena = load_arena(cfg.arena_file or None)
        self.gate = EpisodeGate(cfg.wait_for_learner, cfg.learner_timeout, cfg.lockstep,
                                cfg.command_timeout, hold_periods=cfg.lockstep_periods,
                                graph_timeout=cfg.graph_timeout, dt=self.dt)
        self.core = SimEpisodes(
            self.arena, self.params, self.gate, seed=cfg.seed, start=cfg.start,
            first_episode=cfg.first_episode, resume_state=cfg.resume_state,
            auto_reset=cfg.auto_reset, watchdog=cfg.watchdog,
            decision_periods=cfg.lockstep_periods, readings=cfg.readings,
            episodes=cfg.episodes)
        self.sim = self.core.sim
        self.wheel_base = self.params.robot.wheel_base
        self.next_marker_t = 0.0
        self._round_trip_log = (open(cfg.round_trip_log, 'a', buffering=1 << 16)
                                if cfg.round_trip_log else None)
        open_robot_interface(self, self.arena, cfg.map_frame, cfg.cmd_vel_stamped,
                             self.gate.wait_for_learner, cfg.command)   # off in world mode
        self.blob_names = ['destination'] + [lm.name for lm in self.arena.landmarks]
        # a robot's standard topics (image_raw, scan), built only while someone subscribes
        self.standard = (StandardTopics(self, self.arena, 'cr', sensors=self.params.sensors,
                                        frame=cfg.base_frame) if cfg.standard_topics else None)
        self.ir_angles = np.deg2rad(self.params.sensors.ir_angles_deg)
        try:
            self.start_subscribers = parse_counts(cfg.start_subscribers,
                                                  'sim.node.start_subscribers')
        except ConfigError as exc:
            self.get_logger().fatal(str(exc))
            raise
        if self.core.first(ready=not unmatched(self, self.start_subscribers)):
            self._start_episode()
        self.get_logger().info(
            f'arena {cfg.arena_file or "config/arena.yaml"}, dt {self.params.episode.dt} s, '
            f'speed x{cfg.speed_factor or "max"}, cmd_vel '
            f'{"TwistStamped" if cfg.cmd_vel_stamped else "Twist"}')

    def destroy_node(self) -> None:
        summary = self.core.round_trip_summary()
        if summary is not None:
            self.get_logger().info(summary)
        if self._round_trip_log is not None:
            self._round_trip_log.close()
            self._round_trip_log = None
        super().destroy_node()

    @property
    def dt(self) -> float:
        return self.params.episode.dt

    def _on_cmd(self, msg) -> None:
        stamp = conv.cmd_stamp(msg)
        mark('sim_cmd', stamp)
        if self.core.stale(stamp):
            return                  # in lockstep: a command decided in an earlier episode
        # Clamped in the core (NaN/inf -> 0, limit): a bad command never reaches the wheels.
        try:
            u = conv.wheels_from_cmd(msg, self.wheel_base)
        except ValueError as exc:
            self.get_logger().error(f'ignored a command: {exc}', throttle_duration_sec=2.0)
            return
        held, rtt = self.core.command(u, stamp)
        if rtt is not None and self._round_trip_log is not None:
            self._round_trip_log.write(f'{held:.6f} {rtt * 1e3:.4f}\n')

    def _on_reset(self, request, response):
        if not self.core.episodes:
            response.message = 'node.episodes is false: a world has no episode to reset'
            return response
        self._publish_event(self.core.reset())
        self._start_episode()
        response.success = True
        response.message = f'episode {self.core.episode} started at {self.cfg.start}'
        return response

    def _publish_event(self, ev: Event | None) -> None:
        if ev is not None:
            self.pub_episode.publish(conv.episode_msg(ev.name, ev.t, **ev.values))

    def _start_episode(self) -> None:
        self._publish_event(self.core.start())
        self._publish_state()

    def check_hold(self) -> None:
        """Start the next episode or let the clock run once the gate opens."""
        action, said = self.core.check_hold(lambda: unmatched(self, self.start_subscribers))
        for level, text in said:            # (one call site per severity: rclpy's rule)
            if level == 'info':
                self.get_logger().info(text)
            else:
                self.get_logger().warning(text)
        if action == 'start':
            self._start_episode()
        elif action == 'resend':
            self._resend()

    def tick(self) -> None:
        """Advance the simulator by one tick and publish what the robot senses."""
        res = self.core.step()
        if res is None:    # auto_reset off: hold still until `reset`, sim time goes on
            self.pub_clock.publish(conv.clock_msg(self.core.sim_time))
            return
        if self.core.episodes:
            self.pub_reward.publish(conv.reward_msg(res.reward, self.core.book.ret,
                                                    self.core.episode, self.core.sim_time))
        self._publish_state(readings=not res.done)
        ev, start_next = self.core.finish(res)
        self._publish_event(ev)
        if start_next:
            self._start_episode()

    def _publish_state(self, readings: bool = True) -> None:
        """The robot's readings at the current instant, then ``/clock`` (so that a node whose
        timer fires on this clock tick already has the readings stamped with it); the IR and
        the camera only when the core reads them (:meth:`SimEpisodes.readings_now`)."""
        t = self.core.sim_time
        frame = self.cfg.base_frame
        obs, wheels = self.core.readings_now(readings)
        # (world mode: the robot interface's topics only for their subscribers; the CLIS graph
        # reads the robot adapter's)
        world = not self.core.episodes
        self._last = [] if obs is None else [
            (pub, make()) for pub, make in (
                (self.pub_ir, lambda: conv.ir_msg(obs.ir, self.ir_angles,
                                                  self.params.sensors.ir_range, t, frame)),
                (self.pub_ir_ranges, lambda: conv.ir_ranges_msg(obs.ir, t, frame)),
                (self.pub_camera, lambda: conv.bearings_msg(
                    self.blob_names, [obs.dest_bearing, *obs.landmark_bearings], t, frame)))
            if not world or pub.get_subscription_count()]
        if obs is not None and self.standard is not None:
            self._last += self.standard.messages(t, self.sim.pose, obs.ir)
        if not world or self.pub_wheels.get_subscription_count():
            self._last.append((self.pub_wheels, conv.wheels_msg(wheels, t, frame)))
        # display only (ground truth, never a module input): built only for a subscriber
        if self.pub_odom.get_subscription_count():
            self._last.append((self.pub_odom, conv.odom_msg(
                self.sim.pose, wheels, self.wheel_base, t, self.cfg.map_frame, frame)))
        self._last.append((self.pub_clock, conv.clock_msg(t)))
        if t >= self.next_marker_t - 1e-6:   # sim_time sums floats: 0.1 may be 0.0999999
            self.next_marker_t = t + self.cfg.markers_period
            if self.pub_markers.get_subscription_count():
                self.pub_markers.publish(conv.MarkerArray(markers=[conv.robot_marker(
                    self.sim.pose, self.params.robot.radius, t, self.cfg.map_frame)]))
        mark('sim_pub0', t)
        self._resend()
        mark('sim_pub1', t)
        self.core.published(t)

    def _resend(self) -> None:
        """Publish the readings of the current instant (again)."""
        for pub, msg in self._last:
            pub.publish(msg)


class CommandWait:
    """Wait for ``cmd_vel`` alone while lockstep holds the clock (the sensor-to-command path).

    The executor rebuilds its wait set in Python at every wait (all the node's entities: a few
    tenths of a millisecond here), right when the graph's nodes wake up for the instant just
    published and need the cores, and again after the command arrives. This waits on a wait
    set of the ``cmd_vel`` subscription alone and hands what it takes to the node's callback;
    the executor still serves the rest (progress, ``reset``, parameters) whenever a wait ends
    without a command. Only for a node that has its executor to itself (not
    ``--single-process``, where the loop must serve every node).
    """

    def __init__(self, node: SimNode) -> None:
        from clis_base.ros.rclpy_private import new_wait_set
        self.node = node
        self.sub = node.sub_cmd
        self.wait_set = new_wait_set((1, 0, 0, 0, 0, 0), node.context.handle)

    def wait(self, timeout: float) -> bool:
        """Wait up to ``timeout`` wall seconds for commands and take them all; whether one
        came."""
        came = False
        try:
            with self.sub.handle, self.node.context.handle:
                self.wait_set.clear_entities()
                self.wait_set.add_subscription(self.sub.handle)
                self.wait_set.wait(int(timeout * 1e9))
                while (taken := self.sub.handle.take_message(self.sub.msg_type,
                                                             self.sub.raw)) is not None:
                    came = True
                    self.node._on_cmd(taken[0])
        except InvalidHandle:                 # shutting down: the loop ends
            pass
        return came


def run(node: SimNode, executor: SingleThreadedExecutor) -> None:
    """Pace the simulator at ``speed_factor`` x real time while serving callbacks."""
    period = node.dt / node.cfg.speed_factor if node.cfg.speed_factor > 0 else 0.0
    next_wall = time.monotonic()
    ticks = 0
    # (a wait set of its own: rclpy's private API, for the rclpy it was written for only)
    fast = CommandWait(node) if list(executor.get_nodes()) == [node] and rp_supported() \
        else None
    while rclpy.ok():
        if node.core.holding:             # the clock stands still (learner gate, lockstep)
            waiting_cmd = fast is not None and node.gate.state == 'command'
            if not (waiting_cmd and fast.wait(0.005)):
                executor.spin_once(timeout_sec=0.0 if waiting_cmd else 0.005)
            node.check_hold()
            if period == 0:
                next_wall = time.monotonic()
            # paced (speed > 0): the schedule goes on across the hold, so that a clock held at
            # every instant (lockstep) is still capped at speed x wall time; a long hold (the
            # learner) falls more than 1 s behind and restarts the schedule below
            if node.core.holding or period > 0:
                continue
            # released by the command just taken: the next tick at once (the graph's
            # callbacks of this instant all ran before that command)
        elif not node.core.quiet or ticks % QUIET_SPIN == 0:
            executor.spin_once(timeout_sec=0.0)
        ticks += 1
        now = time.monotonic()
        if now < next_wall:
            executor.spin_once(timeout_sec=next_wall - now)
            continue
        node.tick()
        next_wall = next_wall + period if period > 0 else now
        if period > 0 and time.monotonic() - next_wall > 1.0:
            next_wall = time.monotonic()  # fell far behind: do not try to catch up in a burst


def main(args: list[str] | None = None) -> None:
    print_help_and_exit_if_asked(__doc__, args)
    rclpy.init(args=args)
    try:
        node = SimNode()
    except ConfigError as exc:
        print(f'sim: bad parameter: {exc}')
        rclpy.try_shutdown()
        raise SystemExit(2) from None
    executor = make_executor(node.cfg.executor, node.get_logger())
    executor.add_node(node)
    settle_heap()
    if node.cfg.realtime_priority:
        realtime_logged(node.cfg.realtime_priority, node.get_logger())
    profiler = start_profile()
    try:
        run(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SHUTDOWN_RACES:
        reraise_unless_shut_down()          # a shutdown racing the executor is a clean stop
    finally:
        stop_profile(profiler, 'sim')
        dump_trace('sim')
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
