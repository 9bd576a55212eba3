"""``ros2 run cr_bridge bridge``: the real Cyber Rodent behind the simulator's robot interface.

Talks to the robot (or to ``cr_bridge emulator``) over the wire protocol of
``src/cr_bridge/PROTOCOL.md`` (``node.device``: UDP on the loopback, a serial line, a pty) and
publishes exactly the interface of ``cr_sim sim`` (docs/robot.md#topics; message layouts
from :mod:`cr_sim.conversions`): ``ir``, ``camera``, ``wheels``, ``reward``, ``episode``,
``odom``, ``arena``, ``markers``, ``/clock``; takes ``cmd_vel``; offers ``reset``. Plus
``diagnostics`` (diagnostic_msgs/DiagnosticArray): the link state and the safety counters.

Time: ``/clock`` and every stamp are the robot's own clock (the device time of its sensor
frames, starting at 0): the graph's nodes follow it with ``use_sim_time`` as they follow the
simulator's, but the robot does not wait for anyone (no lockstep): it runs at wall speed (or at
the emulator's ``--speed``).

Episodes (:class:`cr_bridge.core.episode.RobotEpisodes`): destination reached from the camera,
collisions from the bump switch (accelerometer, IR optional), rewards and time limit with the
simulator's numbers, and the simulator's wander policy between episodes; their numbering, start
and end events, returns and learner gate are the simulator's own
(:class:`cr_sim.core.episodes.EpisodeBook`).

Safety (:class:`cr_bridge.core.safety.CommandGuard`): a command with NaN/inf is rejected (the
wheels stop), wheel speeds are clipped to ``robot.v_wheel_max`` (1.3 m/s), ``node.watchdog``
wall seconds without ``cmd_vel`` set the wheels to zero, every command carries a device-side
timeout too; when no valid frame arrived for ``node.link_timeout`` s (or the line broke) the
bridge stops, ends the episode (``reset``, reason ``link_lost``), reports it on
``diagnostics`` and reconnects with exponential backoff. Malformed and out-of-sequence frames
are counted and dropped; no byte sequence on the line can crash it.
"""

from __future__ import annotations

from collections.abc import Callable
import math
import time

from clis_base.params import build, config_dir, dataclass, param, ros_parameters
from clis_base.ros.process import reraise_unless_shut_down, start_node
from clis_base.ros.ros_params import declare_from_config, print_help_and_exit_if_asked
from cr_sim.core.arena import load_arena
from cr_sim.core.episodes import Event
from cr_sim.core.gate import EpisodeGate
from cr_sim.core.robot import clamp_wheels, integrate_arc, robot_defaults, wheels_to_twist
from cr_sim.core.sim import IGNORED_SECTIONS, SimParams
from cr_sim.interface import open_robot_interface
import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from cr_bridge import conversions as bconv
from cr_bridge.core import protocol as proto
from cr_bridge.core.episode import (
    ContactParams,
    Reading,
    RobotEpisodes,
    RobotSideParams,
)
from cr_bridge.core.safety import Backoff, CommandGuard, DeviceClock
from cr_bridge.transport import LinkError, open_link
from cr_sim import conversions as conv

__all__ = ['BridgeNodeParams', 'BridgeNode', 'run', 'main']


@dataclass(frozen=True)
class BridgeNodeParams(RobotSideParams):
    """ROS-side settings of the bridge (``config/bridge.yaml``, section ``node``)."""

    device: str = param(doc='udp://HOST:PORT, a serial device path, or a pyserial URL')
    allow_network: bool = param(doc='allow a device address off this machine')
    baudrate: int = param(300, 4_000_000, doc='serial line speed')
    watchdog: float = param(0.01, 0.3, doc='wall seconds without cmd_vel before the wheels '
                            'are set to zero')
    device_timeout: float = param(0.02, 2.0, doc='device-side command timeout sent with each '
                                  'wheel command [s]')
    send_period: float = param(0.005, 1.0, doc='wall seconds between repeats of the command')
    link_timeout: float = param(0.05, 30.0, doc='wall seconds without a valid frame = link lost')
    backoff_initial: float = param(0.01, 10.0, doc='first reconnect delay [s wall]')
    backoff_max: float = param(0.01, 60.0, doc='longest reconnect delay [s wall]')
    heartbeat_period: float = param(0.01, 10.0, doc='heartbeat to the device [s wall]')
    diagnostics_period: float = param(0.05, 60.0, doc='diagnostics period [s wall]')
    arena_file: str = param(doc="arena description; '' = config/arena.yaml")
    cmd_vel_stamped: bool = param(doc='cmd_vel is TwistStamped (true) or Twist (false)')


class BridgeNode(Node):
    """Thin glue: link + parser -> cores -> messages; cmd_vel -> guard -> wheel frames."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__('bridge')
        self.now = clock        # wall seconds; a test drives the watchdog and link timers
        # the robot's own keys (config/bridge.yaml), its body (config/robot.yaml) and the
        # simulator's sensors, episode and wander sections (config/sim.yaml): the same dotted
        # keys as the sim node
        defaults = ros_parameters(config_dir() / 'bridge.yaml', 'bridge')
        defaults.update(robot_defaults())
        sim = ros_parameters(config_dir() / 'sim.yaml', 'sim')
        defaults.update({k: v for k, v in sim.items() if k not in IGNORED_SECTIONS})
        values = declare_from_config(self, defaults)     # errors name the ROS key (main)
        self.cfg = build(BridgeNodeParams, values.pop('node'), where='node')
        contact = build(ContactParams, values.pop('contact'), where='contact')
        self.params = build(SimParams, values)
        self.arena = load_arena(self.cfg.arena_file or None)
        robot, sensors = self.params.robot, self.params.sensors
        self.wheel_base = robot.wheel_base
        self.ir_angles = np.deg2rad(sensors.ir_angles_deg)
        self.guard = CommandGuard(robot.v_wheel_max, self.cfg.watchdog)
        self.gate = EpisodeGate(self.cfg.wait_for_learner, self.cfg.learner_timeout)
        self.episodes = RobotEpisodes(self.params.episode, self.params.wander, contact,
                                      self.arena.destination.goal_radius, self.ir_angles,
                                      self.gate, np.random.default_rng([self.cfg.seed, 1]),
                                      self.cfg.start, first_episode=self.cfg.first_episode)
        self.backoff = Backoff(self.cfg.backoff_initial, self.cfg.backoff_max)
        self.clock = DeviceClock(self.params.episode.dt)
        self.blob_names = ['destination'] + [lm.name for lm in self.arena.landmarks]
        self.link = None
        self.parser = self._new_parser()
        self.state = 'connecting'           # 'connected', 'lost'
        self.reason = ''
        self.reconnect_at = 0.0
        self.reconnects = 0
        self.opened_at = 0.0
        self.last_rx = -math.inf
        self.seq = 0
        self.t = 0.0                        # bridge time of the last sensor frame
        self.t_prev: float | None = None
        self.wander_u: np.ndarray | None = None
        self.sent_u: np.ndarray | None = None
        self.next_send = 0.0
        self.next_heartbeat = 0.0
        self.next_diag = 0.0
        self.next_marker_t = 0.0
        self.device_errors: dict[str, int] = {}
        self.device_status = 0
        self.true_pose: np.ndarray | None = None
        start = self.arena.starts[0]
        self.pose = np.array((start.x, start.y, start.heading))   # dead reckoning
        self.stats_total = proto.ParserStats()  # over all connections
        self.t_wall0 = self.now()

        open_robot_interface(self, self.arena, self.cfg.map_frame, self.cfg.cmd_vel_stamped,
                             self.cfg.wait_for_learner)
        self.pub_diag = self.create_publisher(conv.DiagnosticArray, 'diagnostics', 10)
        self.get_logger().info(
            f'device {self.cfg.device}, watchdog {self.cfg.watchdog} s, link timeout '
            f'{self.cfg.link_timeout} s, start {self.cfg.start}')

    # ------------------------------------------------------------------ inputs

    def _new_parser(self) -> proto.FrameParser:
        return proto.FrameParser(accept=frozenset({proto.MsgType.SENSORS, proto.MsgType.HEARTBEAT,
                                                   proto.MsgType.ERROR,
                                                   proto.MsgType.TRUE_POSE}))

    def _on_cmd(self, msg) -> None:
        u = conv.wheels_from_cmd(msg, self.wheel_base)
        if not self.guard.command(u, self.now()):
            self.get_logger().warning(f'rejected a non-finite cmd_vel {u.tolist()}: wheels '
                                      'stopped', throttle_duration_sec=1.0)
        self._send_wheels(self.now(), force=True)

    def _on_reset(self, request, response):
        ev, response.message = self.episodes.end_by_service(self.t, self.now())
        if ev is not None:
            self._publish_event(ev)
        self.guard.stop()
        response.success = True
        return response

    # ------------------------------------------------------------------ the link

    def poll(self, timeout: float) -> None:
        """Read the link for at most ``timeout`` s, handle its frames, send what is due."""
        now = self.now()
        if self.link is None:
            if now >= self.reconnect_at:
                self._connect(now)
            else:
                time.sleep(min(timeout, self.reconnect_at - now))
            self._diagnostics(now)
            return
        try:
            data = self.link.read(timeout)
        except LinkError as exc:
            self._lost(str(exc), self.now())
            return
        now = self.now()
        if data:
            for frame in self.parser.feed(data):
                self._on_frame(frame, now)
        if now - max(self.last_rx, self.opened_at) > self.cfg.link_timeout:
            self._lost(f'no valid frame for {self.cfg.link_timeout} s', now)
            return
        self._send_wheels(now)
        if now >= self.next_heartbeat:
            self.next_heartbeat = now + self.cfg.heartbeat_period
            self._write(proto.Heartbeat(now - self.t_wall0, 1 if self.state == 'connected'
                                        else 0))
        self._diagnostics(now)

    def _connect(self, now: float) -> None:
        try:
            self.link = open_link(self.cfg.device, self.cfg.allow_network, self.cfg.baudrate)
        except LinkError as exc:
            self.reason = str(exc)
            self.reconnect_at = now + self.backoff.failure()
            self.get_logger().warning(f'cannot open the device: {exc}; retrying in '
                                      f'{self.reconnect_at - now:.2f} s',
                                      throttle_duration_sec=5.0)
            return
        self._merge_stats()
        self.parser = self._new_parser()
        self.opened_at = now
        self.next_heartbeat = now
        self.get_logger().info(f'opened {self.cfg.device}')

    def _merge_stats(self) -> None:
        for k in self.stats_total.__dataclass_fields__:
            setattr(self.stats_total, k, getattr(self.stats_total, k) + getattr(self.parser.stats,
                                                                                k))
        self.parser.stats = proto.ParserStats()

    def _lost(self, why: str, now: float) -> None:
        """Stop, end the episode, report, and schedule a reconnect."""
        was = self.state
        self.guard.stop()
        self.wander_u = None
        if self.link is not None:
            try:
                self.link.write(self._frame(proto.WheelCommand(0.0, 0.0, self.cfg.device_timeout)))
            except LinkError:
                pass
            self.link.close()
            self.link = None
        ev = self.episodes.end(self.t, now, 'link_lost')
        if ev is not None:
            self._publish_event(ev)
        self.state, self.reason = 'lost', why
        self.reconnect_at = now + self.backoff.failure()
        if was == 'connected':
            self.reconnects += 1
            self.get_logger().error(f'link lost: {why}: wheels stopped; reconnecting')
        self.next_diag = 0.0
        self._diagnostics(now)

    def _frame(self, payload) -> bytes:
        data = proto.encode(payload, self.seq)
        self.seq = (self.seq + 1) & 0xFFFF
        return data

    def _write(self, payload) -> None:
        if self.link is None:
            return
        try:
            self.link.write(self._frame(payload))
        except LinkError as exc:
            self._lost(str(exc), self.now())

    def _send_wheels(self, now: float, force: bool = False) -> None:
        """Send the command in force when it changed or ``send_period`` passed."""
        if self.link is None or self.state != 'connected':
            return
        if self.wander_u is not None:
            u = clamp_wheels(self.wander_u, self.guard.v_max)
        else:
            u = self.guard.output(now)
        if force or now >= self.next_send or self.sent_u is None \
                or not np.array_equal(u, self.sent_u):
            self.sent_u = u
            self.next_send = now + self.cfg.send_period
            self._write(proto.WheelCommand(float(u[0]), float(u[1]), self.cfg.device_timeout))

    def _on_frame(self, frame: proto.Frame, now: float) -> None:
        self.last_rx = now
        if self.state != 'connected':
            self.state, self.reason = 'connected', ''
            self.backoff.success()
            self.get_logger().info(f'connected to {self.cfg.device}')
            self.next_diag = 0.0
        p = frame.payload
        if frame.type is proto.MsgType.SENSORS:
            self._on_sensors(p, now)
        elif frame.type is proto.MsgType.TRUE_POSE:
            self.true_pose = np.array((p.x, p.y, p.theta))
        elif frame.type is proto.MsgType.HEARTBEAT:
            self.device_status = p.status
        elif frame.type is proto.MsgType.ERROR:
            try:
                name = proto.ErrorCode(p.code).name
            except ValueError:
                name = f'code_{p.code}'
            self.device_errors[name] = self.device_errors.get(name, 0) + 1
            self.get_logger().warning(f'device error {name} (seq {p.ref_seq})',
                                      throttle_duration_sec=2.0)

    # ------------------------------------------------------------------ outputs

    def _on_sensors(self, s: proto.SensorFrame, now: float) -> None:
        n_blob = len(self.blob_names)
        if len(s.ir) != len(self.ir_angles) or len(s.bearings) != n_blob:
            self.parser.stats.bad_length += 1      # not this robot's configuration
            return
        t = self.clock(s.t)
        wheels = np.asarray(s.wheels, float)
        if self.t_prev is not None:               # dead reckoning between frames
            v, w = wheels_to_twist(wheels[0], wheels[1], self.wheel_base)
            x, y, th = integrate_arc(*self.pose, v, w, t - self.t_prev)
            self.pose = np.array((x, y, math.remainder(th, 2 * math.pi)))
        self.t_prev = self.t = t
        if self.true_pose is not None:
            self.pose = self.true_pose
        r = Reading(t, np.asarray(s.ir, float), s.bearings[0], s.distances[0],
                    np.asarray(s.bearings[1:], float), wheels, s.bump, s.accel)
        running = self.episodes.running
        step = self.episodes.step(r, now)
        if running and step.reward is not None:
            self.pub_reward.publish(conv.reward_msg(step.reward, self.episodes.ret,
                                                    self.episodes.episode, t))
        starts = [ev for ev in step.events if ev.name == 'start']
        for ev in starts:
            self.guard.stop()                     # a command of the last episode is void
            self._publish_event(ev)
        self._publish_readings(r)
        for ev in step.events:
            if ev.name != 'start':
                self.guard.stop()
                self._publish_event(ev)
        self.wander_u = step.wander
        self._send_wheels(now, force=True)

    def _publish_event(self, ev: Event) -> None:
        self.pub_episode.publish(conv.episode_msg(ev.name, ev.t, **ev.values))

    def _publish_readings(self, r: Reading) -> None:
        t, frame = r.t, self.cfg.base_frame
        self.pub_ir.publish(conv.ir_msg(r.ir, self.ir_angles, self.params.sensors.ir_range, t,
                                        frame))
        self.pub_ir_ranges.publish(conv.ir_ranges_msg(r.ir, t, frame))
        self.pub_camera.publish(conv.bearings_msg(
            self.blob_names, [r.dest_bearing, *r.landmark_bearings], t, frame))
        self.pub_wheels.publish(conv.wheels_msg(r.wheels, t, frame))
        self.pub_odom.publish(conv.odom_msg(self.pose, r.wheels, self.wheel_base, t,
                                            self.cfg.map_frame, frame))
        if t >= self.next_marker_t - 1e-6:
            self.next_marker_t = t + self.cfg.markers_period
            self.pub_markers.publish(conv.MarkerArray(markers=[conv.robot_marker(
                self.pose, self.params.robot.radius, t, self.cfg.map_frame)]))
        self.pub_clock.publish(conv.clock_msg(t))

    def counters(self) -> dict[str, object]:
        """Link and safety counters (over all connections)."""
        total = {k: getattr(self.stats_total, k) + getattr(self.parser.stats, k)
                 for k in self.stats_total.__dataclass_fields__}
        total['malformed'] = (total['bad_crc'] + total['bad_version'] + total['unknown_type']
                              + total['bad_length'])
        return {'device': self.cfg.device, 'state': self.state, **total,
                'rejected_commands': self.guard.rejected, 'clamped_commands': self.guard.clamped,
                'watchdog_trips': self.guard.trips, 'reconnects': self.reconnects,
                'device_status': self.device_status,
                **{f'device_error_{k}': v for k, v in self.device_errors.items()}}

    def _diagnostics(self, now: float) -> None:
        if now < self.next_diag:
            return
        self.next_diag = now + self.cfg.diagnostics_period
        level = {'connected': 'ok', 'connecting': 'warn', 'lost': 'error'}[self.state]
        message = {'connected': 'connected', 'connecting': 'connecting',
                   'lost': f'link lost: {self.reason}'}[self.state]
        self.pub_diag.publish(bconv.diagnostics_msg(level, message, self.counters(), self.t,
                                                    'cr'))


def run(node: BridgeNode, executor: SingleThreadedExecutor, period: float = 0.005,
        stop: Callable[[], bool] = lambda: False) -> None:
    """Serve the link and the ROS callbacks in one thread, until rclpy shuts down or
    ``stop()``."""
    while rclpy.ok() and not stop():
        for _ in range(20):                     # the callbacks that are ready, not more
            executor.spin_once(timeout_sec=0.0)
        node.poll(period)


def main(args: list[str] | None = None) -> None:
    print_help_and_exit_if_asked(__doc__, args)
    # Ctrl-C and SIGTERM only raise a flag: the loop ends between two iterations and the
    # motors get their zero command, never an exception from inside rclpy
    node, stopping = start_node('bridge', BridgeNode, args)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        run(node, executor, stop=lambda: bool(stopping))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:                   # noqa: BLE001 - publishing or taking after a shutdown
        # signal: the context may turn invalid a moment before rclpy.ok() says so (seen: a
        # pybind11 RuntimeError from take_message at the SIGINT)
        reraise_unless_shut_down()
    finally:
        if node.link is not None:
            try:
                node.link.write(node._frame(proto.WheelCommand(0.0, 0.0, 0.0)))
            except LinkError:
                pass
            node.link.close()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
