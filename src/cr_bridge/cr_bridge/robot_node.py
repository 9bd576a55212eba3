"""``ros2 run cr_bridge robot``: a differential-drive ROS 2 robot behind the robot interface.

The second way to reach a robot, beside the Cyber Rodent's bridge: the robot is already on the
ROS graph (a simulator's, or the robot's own drivers) with the standard topics, and its
profile (``node.profile``: ``config/robots/NAME.yaml``, :mod:`cr_sim.core.profile`) says
their names, its body, how its scan stands for the Cyber Rodent's IR rays and the rules of an
episode. The node sits in the CLIS graph's namespace (``--ros-args -r __ns:=/clis``; it refuses
to start when an interface topic would be a robot topic) and:

* robot side (the profile's names under its ``topics.namespace``, absolute, each remappable:
  ``-r /odom:=/husky/odom``): subscribes ``odom`` (nav_msgs/Odometry) and ``scan``
  (sensor_msgs/LaserScan) with sensor-data QoS (best effort); publishes ``cmd_vel`` as
  geometry_msgs/Twist or TwistStamped: ``node.cmd_vel_type`` (``''``: the profile's
  ``topics.cmd_vel_type``), and with ``auto`` the type of the robot's subscriber on the graph,
  looked up until one is there (nothing is published before);
* CLIS side (relative names): takes ``camera`` (sensor_msgs/JointState of the blob detector:
  position = bearing, effort = apparent angular width, NaN = not seen) and ``wheels_cmd``
  (the arbiter's wheels); publishes every ``node.period`` the interface of ``cr_sim sim``
  (docs/robot.md#topics) but ``/clock`` (the robot's own) and ``camera`` (the detector's):
  ``ir`` and ``ir_ranges`` (the scan read as the profile's sectors), ``wheels`` (odom's twist on
  the profile's wheel base), ``odom``, ``reward``, ``episode``, ``arena`` (the profile's layout
  at its size), ``markers``; serves ``reset``.

Episodes and rewards are the bridge's own core (:class:`cr_bridge.core.episode.RobotEpisodes`)
with the profile's rules (:func:`cr_bridge.core.ros_robot.episode_rules`): the destination
reached by its apparent width (rule ``size``) or by the scan's return in its bearing (rule
``range``), a collision when a sector (or one of ``episode.collision_sectors``) reads less
than ``episode.collision_range``, the profile's time limit, and its wander to the next start
through cmd_vel (the simulator's wander at the arena's scale,
:func:`cr_bridge.core.ros_robot.scaled_wander`).

Lockstep (``node.lockstep``, for a simulated robot that holds its clock at each camera frame
until a ``cmd_vel`` stamped with it: our simulator in world mode, the Husky world's
``lockstep``): the frames are read as their inputs come, not on the timer (each once the
detector's ``camera`` and the odometry and scan of its instant are in), and each is answered by
one ``cmd_vel`` stamped with it: at once with the command in force, or, at the decision instants
``t0 + l tau_i`` of a running episode (``node.decision_periods``), by the arbiter's decision on
it (:class:`cr_bridge.core.ros_robot.Lockstep`). The frame at which the next episode is due
while the learner has not reported the last one (``node.wait_for_learner``) is held, unread
and unanswered, until it has: the robot waits there instead of wandering on for as long as
the learner takes, so the episode starts where it would on any host. The timer then only
watches the inputs' age.

Safety, in the node's clock (the robot's ``/clock`` with ``-p use_sim_time:=true``): the
bridge's command guard (:class:`cr_bridge.core.safety.CommandGuard`): a command with NaN/inf is
rejected (zero), speeds are clipped to the profile's ``v_max`` and ``omega_max`` (and
``v_wheel_max``), no ``wheels_cmd`` for ``node.watchdog`` s gives zero; odom, scan or camera
older than the profile's ``episode.stale_timeout`` publishes a zero command (once) and ends the
episode as the bridge does on a link loss (``reset``, reason ``link_lost``, the ``stale``
inputs), until they are fresh again; Ctrl-C or SIGTERM publishes a zero command and waits for
the robot to acknowledge it (``node.exit_timeout`` wall seconds at most) before the node exits.
"""

from __future__ import annotations

import math
import time

from clis_base.params import ConfigError, build, config_dir, dataclass, param, ros_parameters
from clis_base.ros.executor import make_executor
from clis_base.ros.process import reraise_unless_shut_down, start_node
from clis_base.ros.profiling import start_profile, stop_profile
from clis_base.ros.ros_params import declare_from_config, print_help_and_exit_if_asked
from cr_sim.core.arena import load_arena
from cr_sim.core.episodes import Event
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.profile import CMD_VEL_TYPES, load_profile
from cr_sim.core.wander import WanderParams
from cr_sim.interface import open_robot_interface, parse_counts, unmatched
import numpy as np
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from cr_bridge import conversions as bconv
from cr_bridge.core.episode import RobotEpisodes, RobotSideParams
from cr_bridge.core.ros_robot import (
    INTERFACE_TOPICS,
    ROBOT_TOPICS,
    Freshness,
    Lockstep,
    RobotReader,
    choose_cmd_vel_type,
    clashes,
    episode_rules,
    finite_or_zero,
    robot_topic,
    scaled_arena,
    scaled_wander,
)
from cr_bridge.core.safety import CommandGuard
from cr_sim import conversions as conv

__all__ = ['RobotNodeParams', 'RobotNode', 'main']

#: Wall seconds between two looks at the graph for the type of cmd_vel's subscriber.
GRAPH_PERIOD = 0.2
#: Wall seconds between two tries of a frame held for the learner (lockstep).
HELD_RETRY = 0.01
#: The inputs whose age is watched.
INPUTS = ('odom', 'scan', 'camera')


@dataclass(frozen=True)
class RobotNodeParams(RobotSideParams):
    """ROS-side settings of the robot node (``config/bridge.yaml``, node ``robot``, section
    ``node``)."""

    profile: str = param(doc='the robot profile: a name in config/robots, or a file')
    cmd_vel_type: str = param(choices=('', *CMD_VEL_TYPES), doc="cmd_vel's type; '' = the "
                              "profile's topics.cmd_vel_type; 'auto' = the type of the robot's "
                              'subscriber on the graph')
    period: float = param(0.005, 1.0, doc='readings, rewards and the command in force every '
                          'period [s]')
    watchdog: float = param(0.01, 60.0, doc='no wheels_cmd for this long -> zero command [s]')
    exit_timeout: float = param(0.0, 10.0, doc='at exit, wait at most this long for the robot '
                                'to acknowledge the zero command; 0 = do not wait [s wall]')
    lockstep: bool = param(doc='the robot waits for its controller (our simulator and the '
                           'Husky world offer it): read each camera frame once the odometry '
                           'and scan of its instant are in (not on the timer) and answer it '
                           'with one cmd_vel stamped with it; at the decision instants of '
                           'decision_periods, with the decision on it')
    decision_periods: tuple[float, ...] = param(0.0, 60.0, doc="lockstep: the graph's decision "
                                                'periods tau_i [s] (clis run sets them); 0 = '
                                                'every frame of an episode waits for a decision')
    start_subscribers: tuple[str, ...] = param(doc="'TOPIC:COUNT' entries: the first episode "
                                               "waits until the interface's topics have "
                                               "matched these; '' = none")
    graph_timeout: float = param(0.0, 3600.0, doc='wall seconds to wait for them [s]')


class RobotNode(Node):
    """Thin glue: robot topics -> cores -> the interface; wheels_cmd -> guard -> cmd_vel."""

    def __init__(self) -> None:
        super().__init__('robot')
        # the node's keys (config/bridge.yaml, node robot); the simulator's rewards and wander
        # (config/sim.yaml): the same dotted keys as the sim node
        defaults = ros_parameters(config_dir() / 'bridge.yaml', 'robot')
        sim = ros_parameters(config_dir() / 'sim.yaml', 'sim')
        defaults['episode'] = {k: sim['episode'][k] for k in ('reward_goal', 'reward_collision')}
        defaults['wander'] = sim['wander']
        values = declare_from_config(self, defaults)     # errors name the ROS key (main)
        self.cfg = build(RobotNodeParams, values['node'], where='node')
        wander = build(WanderParams, values['wander'], where='wander')
        self.profile = profile = load_profile(self.cfg.profile)
        rules = episode_rules(profile, self.cfg.period, float(values['episode']['reward_goal']),
                              float(values['episode']['reward_collision']))
        arena = load_arena(profile.arena.path(), robot_radius=0.0)
        scale = profile.arena.scale(arena.size)
        self.arena = scaled_arena(arena, scale)
        body = profile.body
        wander = scaled_wander(wander, scale, body.v_max)
        self.wheel_base = body.wheel_base
        self.guard = CommandGuard(body.v_wheel_max or math.inf, self.cfg.watchdog,
                                  body.wheel_base, body.v_max, body.omega_max)
        self.gate = EpisodeGate(self.cfg.wait_for_learner, self.cfg.learner_timeout,
                                graph_timeout=self.cfg.graph_timeout)
        self.start_counts = parse_counts(self.cfg.start_subscribers, 'node.start_subscribers')
        self.reader = RobotReader(profile, rules.rule)
        self.ir_angles = self.reader.sectors.angles
        self.episodes = RobotEpisodes(rules.episode, wander, rules.contact, rules.goal_radius,
                                      self.ir_angles, self.gate,
                                      np.random.default_rng([self.cfg.seed, 1]), self.cfg.start,
                                      goal_width=rules.goal_width,
                                      first_episode=self.cfg.first_episode)
        self.blob_names = ['destination'] + [lm.name for lm in self.arena.landmarks]
        self.fresh = Freshness(INPUTS, profile.episode.stale_timeout)
        self.lock = (Lockstep(self.cfg.decision_periods, self.cfg.period) if self.cfg.lockstep
                     else None)
        self.state = 'waiting'                  # 'running', 'stale'
        self.t = -math.inf                      # the last reading's time
        self.scan = None
        self.odom: tuple[np.ndarray, float, float] | None = None
        self.blobs: tuple[np.ndarray, np.ndarray] | None = None
        self.wander_u: np.ndarray | None = None
        self.next_marker_t = 0.0
        self.pub_cmd = None
        self.cmd_vel_kind: str | None = None
        self._told: set[str] = set()            # what was logged once

        # the robot's side: absolute names (remappable), sensor-data QoS
        names = {k: robot_topic(profile.topics, k) for k in ROBOT_TOPICS}
        self.sub_odom = self.create_subscription(conv.Odometry, names['odom'], self._on_odom,
                                                 qos_profile_sensor_data)
        self.sub_scan = self.create_subscription(conv.LaserScan, names['scan'], self._on_scan,
                                                 qos_profile_sensor_data)
        self.cmd_vel_topic = self.resolve_topic_name(names['cmd_vel'])
        robot = {'odom': self.sub_odom.topic_name, 'scan': self.sub_scan.topic_name,
                 'cmd_vel': self.cmd_vel_topic}
        clash = clashes(robot, [self.resolve_topic_name(n) for n in INTERFACE_TOPICS])
        if clash:
            raise ConfigError(f'robot topics {", ".join(clash)} are topics of the interface: '
                              'run the node in a namespace of its own (--ros-args -r '
                              '__ns:=/clis) or remap them')
        # the CLIS side
        open_robot_interface(self, self.arena, self.cfg.map_frame, True,
                             self.cfg.wait_for_learner, command='wheels_cmd',
                             publish_clock=False, publish_camera=False)
        self.sub_camera = self.create_subscription(conv.JointState, 'camera', self._on_camera,
                                                   qos_profile_sensor_data)
        self.setting = self.cfg.cmd_vel_type or profile.topics.cmd_vel_type
        self.graph_timer = None
        if not self._look_for_cmd_vel_type():
            self.graph_timer = self.create_timer(GRAPH_PERIOD, self._look_for_cmd_vel_type,
                                                 clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.timer = self.create_timer(self.cfg.period, self._tick)
        self.held: float | None = None          # lockstep: a frame held for the learner
        self.answer: tuple | None = None        # the last command sent and its stamp
        if self.lock is not None:           # the robot's clock stands while a frame is held
            self.held_timer = self.create_timer(HELD_RETRY, self._retry_held,
                                                clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'profile {self.cfg.profile}: odom {robot["odom"]}, scan {robot["scan"]}, cmd_vel '
            f'{self.cmd_vel_topic} ({self.setting}); stale timeout '
            f'{profile.episode.stale_timeout} s, start {self.cfg.start}; wander at the '
            f'arena scale x{scale:g}: {wander.speed:g} m/s'
            + (', lockstep' if self.lock is not None else ''))

    # ------------------------------------------------------------------ helpers

    def now_s(self) -> float:
        """The node's clock [s] (the robot's /clock under use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _once(self, key: str, text: str, error: bool = False) -> None:
        if key not in self._told:
            self._told.add(key)
            (self.get_logger().error if error else self.get_logger().info)(text)

    # ------------------------------------------------------------------ cmd_vel's type

    def _look_for_cmd_vel_type(self) -> bool:
        """Choose cmd_vel's type (the parameter, or the robot's subscriber on the graph) and
        make its publisher; True once done."""
        if self.pub_cmd is not None:
            return True
        types = [] if self.setting != 'auto' else [
            info.topic_type for info in self.get_subscriptions_info_by_topic(self.cmd_vel_topic)]
        kind, why = choose_cmd_vel_type(self.setting, types)
        if kind is None:
            if why:
                self._once(why, f'cmd_vel {self.cmd_vel_topic}: {why}; waiting for one type '
                           '(set node.cmd_vel_type to skip)', error=True)
            else:
                self._once('wait', f'waiting for a subscriber on {self.cmd_vel_topic} to learn '
                           'its type (Twist or TwistStamped); set cmd_vel_type to skip '
                           '(-p node.cmd_vel_type:=Twist or TwistStamped)')
            return False
        self.cmd_vel_kind = kind
        self.pub_cmd = self.create_publisher(bconv.CMD_VEL_CLASSES[kind], self.cmd_vel_topic, 10)
        if self.graph_timer is not None:
            self.graph_timer.cancel()
        self.get_logger().info(f'cmd_vel {self.cmd_vel_topic}: {kind}'
                               + (" (its subscriber's)" if self.setting == 'auto' else ''))
        return True

    # ------------------------------------------------------------------ inputs

    def _seen(self, name: str, stamp: float) -> None:
        """``name`` read at ``stamp``, the sim time it describes (its arrival time when the
        robot does not stamp it): a reading that waited in a queue is as old as its stamp."""
        now = self.now_s()
        if self.lock is not None:           # the robot waits: the frame's time is its stamp
            self.fresh.seen(name, stamp)
            self._frame()
        else:
            self.fresh.seen(name, stamp if 0.0 < stamp <= now else now)

    def _on_odom(self, msg) -> None:
        t, pose, v, w = bconv.odom_from_msg(msg)
        if self.lock is not None and t < self._stamp('camera') - 1e-6:
            return                          # lockstep: an older one overtaken (resent)
        self.odom = (pose, v, w)
        self._seen('odom', t)

    def _on_scan(self, msg) -> None:
        scan = bconv.scan_from_msg(msg)
        if self.lock is not None and scan.t < self._stamp('camera') - 1e-6:
            return
        self.scan = scan
        self._seen('scan', scan.t)

    def _on_camera(self, msg) -> None:
        t, bearings, widths = bconv.blobs_from_msg(msg, self.blob_names)
        if self.lock is not None and t <= self.t:
            # lockstep: a frame read already, resent by a robot still held there: the answer
            # to it was lost (sent before the robot's subscription matched): send it again
            if self.answer is not None and abs(t - self.answer[1]) < 1e-9:
                self._publish_cmd(*self.answer)
            return
        self.blobs = (bearings, widths)
        self._seen('camera', t)

    def _stamp(self, name: str) -> float:
        """Lockstep: the latest stamp of input ``name`` (-inf before the first)."""
        t = self.fresh.last[name]
        return -math.inf if t is None else t

    def _frame(self) -> None:
        """Lockstep: read the frame whose camera, odometry and scan are all in."""
        t = self.lock.frame(self._stamp('camera'), self._stamp('odom'), self._stamp('scan'),
                            self.t)
        if t is not None:
            self._reading(t)

    def _retry_held(self) -> None:
        """Lockstep: step the frame held for the learner again (it starts the episode once
        the learner has reported)."""
        if self.held is not None and self.state == 'running':
            self._reading(self.held)

    def _on_cmd(self, msg) -> None:
        if self.state != 'running':
            return                          # stale inputs: nothing is commanded
        now = self.now_s()
        if self.lock is None and (stale := self.fresh.stale(now)):
            self._stale(stale, now)         # a command between two checks of the timer
            return
        try:
            u = conv.wheels_from_cmd(msg, self.wheel_base)
        except ValueError as exc:
            self.get_logger().warning(f'rejected a wheels_cmd: {exc}', throttle_duration_sec=1.0)
            u = np.full(2, math.nan)
        if not self.guard.command(u, now):
            self.get_logger().warning(f'rejected a non-finite wheels_cmd {u.tolist()}: zero '
                                      'command', throttle_duration_sec=1.0)
        # lockstep: stamped with the frame read last, which it answers (a command stamped with
        # the clock could release a frame the adapter has not read yet)
        self._drive(self.t if self.lock is not None else now)

    def _on_reset(self, request, response):
        ev, response.message = self.episodes.end_by_service(self.t, time.monotonic())
        if ev is not None:
            self._publish_event(ev)
        self.guard.stop()
        response.success = True
        return response

    # ------------------------------------------------------------------ the period

    def _tick(self) -> None:
        now = self.now_s()
        # (lockstep: the frames are read before their /clock arrives; the clock of a robot
        # that restarted goes back by more than the inputs' timeout)
        back = 1e-9 if self.lock is None else self.fresh.timeout
        if now < self.t - back and (self.lock is None or now > 0.0):
            self._clock_went_back(now)
            return
        if self.lock is not None:
            # the frames are read as they come (_frame); the timer watches their age only, from
            # the newest input (the next frame's odometry may come before its /clock)
            newest = max([now, *(t for t in self.fresh.last.values() if t is not None)])
            stale = self.fresh.stale(newest) if now > self.t else ()
            if stale and self.state == 'running':
                self._stale(stale, now)
            return
        if now <= self.t:
            return
        self._reading(now)

    def _reading(self, now: float) -> None:
        """The readings, rewards and events of instant ``now``, and the command in force."""
        stale = self.fresh.stale(now)
        if stale:
            if self.state == 'running':
                self._stale(stale, now)
            elif self.state == 'waiting':
                self._once('inputs', 'waiting for ' + ', '.join(self.fresh.never() or stale))
            return
        if self.state != 'running':
            self.get_logger().info(f'odom, scan and camera fresh at t = {now:.3f} s: running')
            self.state = 'running'
        self.t = now
        pose, v, w = self.odom
        r = self.reader.reading(now, self.scan, v, w, *self.blobs)
        wall = time.monotonic()
        running = self.episodes.running
        ready = self.episodes.book.started_any or not unmatched(self, self.start_counts)
        step = self.episodes.step(r, wall, hold=self.lock is not None, ready=ready)
        if step.warning:
            lacking = unmatched(self, self.start_counts)
            self.get_logger().warning(step.warning + (f' (not matched: {", ".join(lacking)})'
                                                      if lacking else ''))
        if step.held:                       # the learner's turn: this frame stays unanswered
            self.held = now
            return
        self.held = None
        if running and step.reward is not None:
            self.pub_reward.publish(conv.reward_msg(step.reward, self.episodes.ret,
                                                    self.episodes.episode, now))
        for ev in step.events:
            if ev.name == 'start':
                self.guard.stop()            # a command of the last episode is void
                self._publish_event(ev)
        self._publish_readings(r, pose)
        for ev in step.events:
            if ev.name != 'start':
                self.guard.stop()
                self._publish_event(ev)
        self.wander_u = step.wander
        if self.lock is not None and self.lock.waits(now, self.episodes.book.t0,
                                                     self.episodes.running):
            return                          # the arbiter's decision on it answers it
        self._drive(now)

    def _stale(self, stale: tuple[str, ...], now: float) -> None:
        """Stop, end the episode as on a link loss, and wait for fresh inputs."""
        self.state = 'stale'
        self.guard.stop()
        self.wander_u = None
        self._publish_cmd(np.zeros(2), now)
        ev = self.episodes.end(self.t, time.monotonic(), 'link_lost')
        if ev is not None:
            ev.values['stale'] = ','.join(stale)
            self._publish_event(ev)
        self.get_logger().error(f'{", ".join(stale)} older than '
                                f'{self.fresh.timeout} s at t = {now:.3f} s: zero command; '
                                'waiting for fresh inputs')

    def _clock_went_back(self, now: float) -> None:
        """The robot's clock jumped back (its simulator was reset): stop, end the episode,
        start over from the new time."""
        self.get_logger().warning(f'the clock went back from {self.t:.3f} s to {now:.3f} s: '
                                  'the episode ends; readings start over')
        if self.state == 'running':
            self._stale(('clock',), now)
        self.t = -math.inf
        self.fresh.forget()
        self.next_marker_t = 0.0

    # ------------------------------------------------------------------ outputs

    def _drive(self, now: float) -> None:
        """Send the command in force (the wander's between episodes, else the guarded
        wheels_cmd's)."""
        if self.state != 'running':
            return
        u = self.guard.limit(self.wander_u) if self.wander_u is not None \
            else self.guard.output(now)
        self._publish_cmd(u, now)

    def _publish_cmd(self, u, t: float) -> None:
        self.answer = (u, t)
        if self.pub_cmd is None:
            return
        self.pub_cmd.publish(conv.cmd_from_wheels(finite_or_zero(u), self.wheel_base, t,
                                                  self.cfg.base_frame,
                                                  self.cmd_vel_kind == 'TwistStamped'))

    def _publish_event(self, ev: Event) -> None:
        self.pub_episode.publish(conv.episode_msg(ev.name, ev.t, **ev.values))

    def _publish_readings(self, r, pose: np.ndarray) -> None:
        t, frame = r.t, self.cfg.base_frame
        self.pub_ir.publish(conv.ir_msg(r.ir, self.ir_angles, self.profile.scan.range_max, t,
                                        frame))
        self.pub_ir_ranges.publish(conv.ir_ranges_msg(r.ir, t, frame))
        self.pub_wheels.publish(conv.wheels_msg(r.wheels, t, frame))
        # display only (no module reads them): built only for a subscriber
        if self.pub_odom.get_subscription_count():
            self.pub_odom.publish(conv.odom_msg(pose, r.wheels, self.wheel_base, t,
                                                self.cfg.map_frame, frame))
        if t >= self.next_marker_t - 1e-6 and self.pub_markers.get_subscription_count():
            self.next_marker_t = t + self.cfg.markers_period
            self.pub_markers.publish(conv.MarkerArray(markers=[conv.robot_marker(
                pose, self.profile.body.radius, t, self.cfg.map_frame)]))

    def stop_robot(self) -> None:
        """A zero command, acknowledged by the robot's reliable subscribers (at most
        ``node.exit_timeout`` wall seconds): the last thing the node sends."""
        if self.pub_cmd is None:
            return
        self._publish_cmd(np.zeros(2), self.now_s())
        wait = self.cfg.exit_timeout
        if wait > 0.0 and not self.pub_cmd.wait_for_all_acked(Duration(seconds=wait)):
            self.get_logger().warning(f'the zero command on {self.cmd_vel_topic} was not '
                                      f'acknowledged within {wait} s')
        time.sleep(min(0.05, wait))         # best-effort subscribers do not acknowledge


def main(args: list[str] | None = None) -> None:
    print_help_and_exit_if_asked(__doc__, args)
    # Ctrl-C and SIGTERM only raise a flag: the robot gets its zero command from a live
    # context
    node, stopping = start_node('robot', RobotNode, args)
    executor = make_executor('lean', node.get_logger())
    executor.add_node(node)
    profiler = start_profile()
    try:
        while rclpy.ok() and not stopping:
            executor.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:                   # noqa: BLE001 - taking after a shutdown signal
        reraise_unless_shut_down()
    finally:
        stop_profile(profiler, 'robot')
        if rclpy.ok():
            node.stop_robot()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
