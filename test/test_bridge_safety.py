"""The bridge's safety with its wall clock driven by the test: the watchdog, the command voided
at an episode start, ``node.allow_network``, and the zero command at shutdown.

The bridge node runs in the test process with an injected clock (``BridgeNode(clock=...)``);
the test is the device: it owns the UDP socket the bridge talks to, sends the sensor frames
(device time) and reads the wheel commands the bridge writes. Nothing is measured in wall
time: the test sets the bridge's clock and judges the frames that arrived.
"""

from __future__ import annotations

import contextlib
import functools
import math
import select
import socket

from clis_base.params import config_dir, ros_parameters
from cr_bridge.bridge_node import BridgeNode
from cr_bridge.core import protocol as proto
from cr_sim.core.arena import load_arena
from geometry_msgs.msg import TwistStamped
import pytest
import rclpy
from ros_util import Probe, start_node, stop

pytestmark = pytest.mark.ros
WATCHDOG = 0.15         # config/bridge.yaml node.watchdog [s wall]


class Clock:
    """The bridge's wall clock, set by the test."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class Device:
    """The robot's end of a UDP link: sensor frames out, the bridge's frames in."""

    def __init__(self, host: str = '127.0.0.1') -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, 0))
        self.url = f'udp://{host}:{self.sock.getsockname()[1]}'
        self.parser = proto.FrameParser(accept=frozenset({proto.MsgType.WHEELS,
                                                          proto.MsgType.HEARTBEAT}))
        self.peer = None
        self.seq = 0
        self.received: list[proto.Frame] = []

    def take(self, wait: float = 0.0) -> list[proto.Frame]:
        """The frames that arrived (waiting at most ``wait`` s for the first one)."""
        out = []
        timeout = wait
        while select.select([self.sock], [], [], timeout)[0]:
            data, self.peer = self.sock.recvfrom(2048)
            out += self.parser.feed(data)
            timeout = 0.0
        self.received += out
        return out

    def send(self, payload) -> None:
        self.sock.sendto(proto.encode(payload, self.seq), self.peer)
        self.seq = (self.seq + 1) & 0xFFFF

    def close(self) -> None:
        self.sock.close()


def wheels(frames) -> list[proto.WheelCommand]:
    return [f.payload for f in frames if f.type is proto.MsgType.WHEELS]


@contextlib.contextmanager
def bridge(clock: Clock, *params: str):
    """A BridgeNode in this process with ``-p`` overrides ``params``."""
    args = ['--ros-args']
    for p in params:
        args += ['-p', p]
    rclpy.init(args=args)
    node = None
    try:
        node = BridgeNode(clock=clock)
        yield node
    finally:
        if node is not None:
            if node.link is not None:
                node.link.close()
            node.destroy_node()
        rclpy.shutdown()


@functools.cache
def shape() -> tuple[int, int]:
    """(IR beams, camera blobs) of the configured robot and arena."""
    sim = ros_parameters(config_dir() / 'sim.yaml', 'sim')
    return len(sim['sensors']['ir_angles_deg']), 1 + len(load_arena(None).landmarks)


def sensors(t: float, v: float = 0.0) -> proto.SensorFrame:
    """A frame at device time ``t``: nothing near, the destination not seen."""
    n_ir, n_blob = shape()
    return proto.SensorFrame(t, (0.5,) * n_ir, (math.nan,) * n_blob, (math.nan,) * n_blob,
                             (v, -v))


def turn(w: float) -> TwistStamped:
    msg = TwistStamped()
    msg.twist.angular.z = w     # wheels at -+ w * b / 2
    return msg


def connect(node: BridgeNode, dev: Device, t_device: float = 0.0) -> list[proto.Frame]:
    """Open the link (the bridge's heartbeat tells the device its address), then one sensor
    frame makes it connected; the frames the bridge wrote in answer."""
    node.poll(0.0)                      # opens the link
    node.poll(0.0)                      # writes a heartbeat
    assert dev.take(wait=10.0), 'the bridge wrote nothing to its device'
    dev.send(sensors(t_device))
    node.poll(10.0)                     # waits for the frame (a hang guard, not a window)
    assert node.state == 'connected', node.reason
    return dev.take()


def test_watchdog_zeroes_the_wheels_exactly_when_its_time_has_passed():
    clock, dev = Clock(), Device()
    try:
        with bridge(clock, f'node.device:={dev.url}', 'node.start:=here') as node:
            connect(node, dev)
            assert node.episodes.running          # start 'here': the first frame starts one
            t_cmd = clock.t
            node._on_cmd(turn(4.0))               # what the cmd_vel subscription calls
            first = wheels(dev.take(wait=10.0))
            assert first and first[-1].v_left < -0.2 and first[-1].v_right > 0.2, first
            # 10 ms steps of the bridge's clock, a sensor frame each (the link stays alive):
            # every command it sends is the command until the watchdog, zero after it
            sent = []                             # (wall seconds since the command, command)
            for k in range(1, 31):
                clock.t = t_cmd + 0.01 * k
                dev.send(sensors(0.01 * k))
                node.poll(10.0)
                sent += [(clock.t - t_cmd, c) for c in wheels(dev.take(wait=10.0))]
            held = [c for dt, c in sent if dt <= WATCHDOG - 1e-6]
            after = [c for dt, c in sent if dt >= WATCHDOG + 1e-6]
            assert len(held) >= 10 and len(after) >= 10, sent
            assert all(c.v_left < -0.2 and c.v_right > 0.2 for c in held), held
            assert all(c.v_left == 0.0 and c.v_right == 0.0 for c in after), after
            assert node.counters()['watchdog_trips'] == 1
    finally:
        dev.close()


def test_a_command_of_the_last_episode_is_void_when_the_next_starts():
    clock, dev = Clock(), Device()
    try:
        with bridge(clock, f'node.device:={dev.url}', 'node.start:=here',
                    'episode.time_limit:=0.2', 'episode.wander_time:=0.1') as node:
            connect(node, dev)
            assert node.episodes.running and node.episodes.episode == 1
            t, late = 0.0, None
            while node.episodes.episode == 1 or not node.episodes.running:
                t += 0.02
                clock.t += 0.02                   # wall time as fast as device time
                if late is None and not node.episodes.running:
                    node._on_cmd(turn(4.0))      # a command of episode 1 arrives late
                    late = clock.t
                dev.send(sensors(t))
                node.poll(10.0)
                assert t < 5.0, 'the next episode never started'
            # episode 2 started within the watchdog of the late command: still in force but void
            assert late is not None and clock.t - late < WATCHDOG, (late, clock.t)
            cmds = wheels(dev.take(wait=10.0))
            assert cmds and cmds[-1].v_left == 0.0 and cmds[-1].v_right == 0.0, cmds
            assert not node.guard.output(clock.t).any()
    finally:
        dev.close()


def own_address() -> str | None:
    """This host's address off the loopback (the route to TEST-NET-1; UDP connect sends
    nothing), or None."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(('192.0.2.1', 9))
        except OSError:
            return None
        addr = s.getsockname()[0]
    return None if addr.startswith('127.') or addr == '0.0.0.0' else addr


@pytest.mark.parametrize('allow', [False, True])
def test_allow_network_decides_whether_an_address_off_the_loopback_is_opened(allow):
    host = own_address()
    if host is None:
        pytest.skip('no address off the loopback on this host')
    clock, dev = Clock(), Device(host)    # this host's own address: packets stay on it
    try:
        with bridge(clock, f'node.device:={dev.url}',
                    f'node.allow_network:={str(allow).lower()}') as node:
            node.poll(0.0)
            node.poll(0.0)
            if allow:
                assert node.link is not None, node.reason
                assert dev.take(wait=10.0), 'the bridge wrote nothing to its device'
            else:
                assert node.link is None and 'allow_network' in node.reason, node.reason
                assert node.state == 'connecting'
                assert not dev.take(wait=0.0)
    finally:
        dev.close()


def test_the_bridge_commands_zero_when_it_shuts_down():
    dev = Device()
    probe = Probe('shutdown_probe')
    pub = probe.node.create_publisher(TwistStamped, 'cmd_vel', 10)
    proc = start_node('cr_bridge.bridge_node', '-p', f'node.device:={dev.url}',
                      '-p', 'node.start:=here', '-p', 'node.watchdog:=0.3',
                      '-p', 'node.link_timeout:=30.0')
    out = ''
    try:
        assert dev.take(wait=60.0), 'the bridge never wrote to its device'
        # answer every frame with a sensor frame until a command from cmd_vel arrives
        t, moving = 0.0, False
        for _ in range(2000):
            dev.send(sensors(t))
            t += 0.01
            pub.publish(turn(4.0))
            probe.spin_for(0.01)
            moving = any(c.v_left < -0.2 for c in wheels(dev.take(wait=0.05)))
            if moving:
                break
        assert moving, 'cmd_vel never reached the device'
        pub.publish(turn(4.0))
        probe.spin_for(0.0)
        n = len(dev.received)
        out = stop(proc)                   # SIGINT: the bridge shuts down
        dev.take()                         # it has exited: all it wrote is here
        last = wheels(dev.received[n:]) or wheels(dev.received)
        assert last[-1] == proto.WheelCommand(0.0, 0.0, 0.0), last[-3:]
    finally:
        if proc.poll() is None:
            out = stop(proc)
        probe.close()
        dev.close()
    assert 'Traceback' not in out, out
