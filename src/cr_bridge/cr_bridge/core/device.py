"""The device side of the wire protocol, driven by the cr_sim core: the robot emulator.

A :class:`Device` is what the Cyber Rodent's onboard controller does, with the simulator's
physics and sensor model (:class:`cr_sim.core.sim.Simulator`, reused as is) in place of the
motors and sensors: it takes ``WHEELS`` commands, stops on its own when no command came within
the command's ``timeout`` (its own watchdog), and every ``episode.dt`` of device time steps the
physics and sends one ``SENSORS`` frame (IR, blob bearings and camera range estimates, the
executed wheel velocities, the bump switch = the simulator's contact, the accelerometer),
optionally a ``TRUE_POSE`` frame (a lab's tracking system; the bridge uses it for ``odom``) and
a ``HEARTBEAT`` now and then. A device knows nothing of episodes: when the simulator's episode
ends (goal or time limit) the physics simply continues from the same pose.

Fault injection for tests (``drop``, ``corrupt``, ``garbage``: probabilities per frame, drawn
from the injected generator) makes the line lossy and noisy.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math

from cr_sim.core.sim import Simulator
import numpy as np

from cr_bridge.core import protocol as proto

__all__ = ['Faults', 'Device']


@dataclass(frozen=True)
class Faults:
    """Per-frame probabilities of line faults on the device's output."""

    drop: float = 0.0       # the frame is not sent
    corrupt: float = 0.0    # one random byte of the frame is flipped
    garbage: float = 0.0    # random bytes (1-40) are sent before the frame


class Device:
    """The emulated robot (module docstring).

    Parameters
    ----------
    sim : Simulator
        Physics and sensors; its pose at construction is where the robot stands.
    rng : np.random.Generator
        Source of the injected faults.
    faults : Faults
        Line faults (none by default).
    true_pose : bool
        Also send ``TRUE_POSE`` frames.
    heartbeat_every : int
        A ``HEARTBEAT`` every this many ticks.
    speed : float
        Device time per wall second (the emulator's ``--speed``): a command's timeout is wall
        time, as the host's sending is, so it holds ``speed`` times as long in device time.
    """

    def __init__(self, sim: Simulator, rng: np.random.Generator, faults: Faults | None = None,
                 true_pose: bool = True, heartbeat_every: int = 10, speed: float = 1.0) -> None:
        self.sim = sim
        self.rng = rng
        self.faults = faults or Faults()
        self.speed = speed
        self.true_pose = true_pose
        self.heartbeat_every = heartbeat_every
        self.parser = proto.FrameParser(accept=frozenset({proto.MsgType.WHEELS,
                                                          proto.MsgType.HEARTBEAT}))
        self.dt = sim.params.episode.dt
        self.v_max = sim.params.robot.v_wheel_max
        self.k = 0                      # device ticks since boot
        self.seq = 0
        self.u = np.zeros(2)
        self.u_deadline = -math.inf     # device time until which the command holds
        self.stopped_by_watchdog = False
        self.commands: deque = deque(maxlen=10_000)   # (t, v_left, v_right) received, newest
        self.pending: list[bytes] = []  # error frames to send with the next tick
        self._v_prev = 0.0
        self.sent = 0

    @property
    def t(self) -> float:
        """Device time [s] (ticks since boot x dt)."""
        return self.k * self.dt

    def receive(self, data: bytes) -> None:
        """Bytes from the host: wheel commands and heartbeats."""
        before = self.parser.stats.malformed
        for frame in self.parser.feed(data):
            if frame.type is proto.MsgType.WHEELS:
                cmd = frame.payload
                u = np.array((cmd.v_left, cmd.v_right))
                if np.any(np.abs(u) > self.v_max + 1e-9):
                    self._error(proto.ErrorCode.OUT_OF_RANGE, frame.seq)
                self.u = np.clip(u, -self.v_max, self.v_max)
                self.u_deadline = self.t + cmd.timeout * self.speed
                self.stopped_by_watchdog = False
                self.commands.append((self.t, float(self.u[0]), float(self.u[1])))
        if self.parser.stats.malformed > before:
            self._error(proto.ErrorCode.BAD_CRC, 0)

    def _error(self, code: int, ref: int) -> None:
        self.pending.append(self._frame(proto.DeviceError(int(code), 0, ref)))

    def _frame(self, payload) -> bytes:
        data = proto.encode(payload, self.seq)
        self.seq = (self.seq + 1) & 0xFFFF
        return data

    def tick(self) -> list[bytes]:
        """Step the physics one ``dt``; the frames to send (one datagram each)."""
        if self.t > self.u_deadline + 1e-9:
            if np.any(self.u != 0.0):
                self.stopped_by_watchdog = True
                self._error(proto.ErrorCode.WATCHDOG_STOP, 0)
            self.u = np.zeros(2)
        res = self.sim.step(self.u)
        obs = res.obs
        pose = self.sim.pose
        touching = self.sim.touching
        if res.done:            # a robot has no episodes: the physics goes on from here
            try:
                self.sim.reset(start=pose)
            except ValueError:
                pass
        self.k += 1
        v = 0.5 * float(obs.wheels[0] + obs.wheels[1])
        w = float(obs.wheels[1] - obs.wheels[0]) / self.sim.params.robot.wheel_base
        accel = ((v - self._v_prev) / self.dt, v * w, 9.81)
        self._v_prev = v
        arena = self.sim.arena
        targets = [(arena.destination.x, arena.destination.y)] + \
            [(lm.x, lm.y) for lm in arena.landmarks]
        bearings = (obs.dest_bearing, *obs.landmark_bearings)
        distances = tuple(math.nan if math.isnan(b) else math.hypot(x - pose[0], y - pose[1])
                          for b, (x, y) in zip(bearings, targets))
        frames = self.pending
        self.pending = []
        frames.append(self._frame(proto.SensorFrame(
            self.t, tuple(obs.ir), bearings, distances, tuple(obs.wheels),
            1 if touching else 0, accel)))
        if self.true_pose:
            frames.append(self._frame(proto.TruePose(self.t, *pose)))
        if self.heartbeat_every and self.k % self.heartbeat_every == 0:
            status = 1 | (2 if self.stopped_by_watchdog else 0)
            frames.append(self._frame(proto.Heartbeat(self.t, status)))
        return [f for f in (self._fault(f) for f in frames) if f]

    def _fault(self, frame: bytes) -> bytes:
        f, rng = self.faults, self.rng
        self.sent += 1
        if f.drop and rng.random() < f.drop:
            return b''
        if f.corrupt and rng.random() < f.corrupt:
            b = bytearray(frame)
            b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
            frame = bytes(b)
        if f.garbage and rng.random() < f.garbage:
            frame = rng.bytes(int(rng.integers(1, 41))) + frame
        return frame
