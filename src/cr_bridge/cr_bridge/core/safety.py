"""Safety of the bridge: the command guard (clamp, reject, watchdog), reconnect backoff, and
the device clock. Pure state machines: times are passed in (wall seconds, any monotonic
origin; the robot node's sim time), so the nodes and the tests drive them alike.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from cr_sim.core.robot import clamp_wheels, twist_to_wheels, wheels_to_twist
import numpy as np

__all__ = ['CommandGuard', 'Backoff', 'DeviceClock']


@dataclass
class CommandGuard:
    """What may reach the motors.

    * a command with a non-finite value (NaN, +-inf) is rejected as a whole: the wheels stop
      (a controller that emits NaN is broken) and ``rejected`` counts it;
    * a finite command is clipped to the body's twist limits when it has them (``v_body_max``,
      ``omega_max``: its forward speed and yaw rate, each clipped alone, then back to the
      wheels), then to ``v_max`` per wheel (:func:`cr_sim.core.robot.clamp_wheels`, the
      simulator's clamp): :meth:`limit`; ``clamped`` counts the clipped ones;
    * the watchdog: :meth:`output` is zero once ``watchdog`` seconds passed since the last
      command (``trips`` counts each time it fired).

    Parameters
    ----------
    v_max : float
        Wheel limit [m/s] (1.3 on the CR; ``math.inf``: none).
    watchdog : float
        Seconds a command holds (wall seconds on the bridge, sim time on the robot node).
    wheel_base : float
        Distance between the wheels [m], for the twist limits; 0: no twist limits.
    v_body_max : float
        Top forward speed [m/s] (``math.inf``: none).
    omega_max : float
        Top yaw rate [rad/s] (``math.inf``: none).
    """

    v_max: float
    watchdog: float
    wheel_base: float = 0.0
    v_body_max: float = math.inf
    omega_max: float = math.inf

    def __post_init__(self) -> None:
        self.u = np.zeros(2)
        self.t_cmd = -math.inf
        self.rejected = 0
        self.clamped = 0
        self.trips = 0
        self._tripped = True

    def command(self, u, now: float) -> bool:
        """A new command ``u = (v_left, v_right)`` at wall time ``now``; False if rejected."""
        a = np.asarray(u, dtype=np.float64).reshape(-1)
        self.t_cmd = now
        self._tripped = False
        if a.shape != (2,) or not np.all(np.isfinite(a)):
            self.rejected += 1
            self.u = np.zeros(2)
            return False
        self.u = self.limit(a)
        if np.any(self.u != a):
            self.clamped += 1
        return True

    def limit(self, u) -> np.ndarray:
        """``u = (v_left, v_right)`` within the limits, shape (2,): the twist limits (when
        ``wheel_base`` > 0), then the wheel clamp; a non-finite entry reads 0 (that wheel
        stops). A command within every limit is returned unchanged, to the bit."""
        a = clamp_wheels(u, math.inf)           # non-finite -> 0, shape (2,) checked
        if self.wheel_base > 0.0:
            v, w = wheels_to_twist(a[0], a[1], self.wheel_base)
            vc = min(self.v_body_max, max(-self.v_body_max, v))
            wc = min(self.omega_max, max(-self.omega_max, w))
            if vc != v or wc != w:
                a = np.asarray(twist_to_wheels(vc, wc, self.wheel_base), dtype=np.float64)
        return clamp_wheels(a, self.v_max)

    def stop(self) -> None:
        """Forget the command (link lost, episode over): zero until the next one."""
        self.u = np.zeros(2)
        self.t_cmd = -math.inf

    def output(self, now: float) -> np.ndarray:
        """The wheel command in force at wall time ``now``, shape (2,)."""
        if now - self.t_cmd > self.watchdog:
            if not self._tripped:
                self._tripped = True
                if np.any(self.u != 0.0):
                    self.trips += 1
            return np.zeros(2)
        return self.u.copy()

    def expired(self, now: float) -> bool:
        """Whether the watchdog holds the wheels at zero."""
        return now - self.t_cmd > self.watchdog


@dataclass
class Backoff:
    """Exponential reconnect delays: ``initial``, x``factor`` per failure, at most ``maximum``;
    :meth:`success` starts over."""

    initial: float = 0.1
    maximum: float = 2.0
    factor: float = 2.0

    def __post_init__(self) -> None:
        self.delay = self.initial
        self.attempts = 0

    def failure(self) -> float:
        """The delay before the next attempt (and grow it)."""
        d = self.delay
        self.delay = min(self.maximum, self.delay * self.factor)
        self.attempts += 1
        return d

    def success(self) -> None:
        self.delay = self.initial
        self.attempts = 0


@dataclass
class DeviceClock:
    """Maps device time to the bridge's clock: it starts at 0 with the first frame and stays
    monotonic when the device time jumps back (a device reboot, the ms counter's wrap): the
    clock then goes on one ``dt`` after its last value."""

    dt: float

    def __post_init__(self) -> None:
        self.offset: float | None = None
        self.last = -math.inf

    def __call__(self, t_device: float) -> float:
        if self.offset is None:
            self.offset = -t_device
        t = t_device + self.offset
        if t <= self.last + 1e-9:
            self.offset = self.last + self.dt - t_device
            t = self.last + self.dt
        self.last = t
        return t
