"""Hand-made wander policy pi^wander: moves the robot to a new start between episodes.

The paper moves the CR to the next start position with a designer-given policy. This one is a
reactive random walk that only reads the robot's own sensors (an :class:`Observation`), so it
runs unchanged on the simulator and on the real robot:

* if an IR beam in the front sector (|beam angle| <= ``front_deg``) reads less than
  ``avoid_distance``, turn in place (wheels ``-+turn_speed``) toward the side whose beams read
  farther, and keep that direction until the front is clear (hysteresis: no dithering);
* a forward command that the odometry shows did not move the robot (executed forward speed
  below a quarter of the command: pressed against something between the beams) also starts
  such a turn;
* otherwise drive forward at ``speed`` with a steering offset ``s`` that does a bounded random
  walk: ``s <- clip(s + N(0, steer_sigma^2), -steer_max, steer_max)``, wheels
  ``(speed - s, speed + s)``.
"""

from __future__ import annotations

import math

from clis_base.params import dataclass, param
import numpy as np
from numpy.typing import ArrayLike

from cr_sim.core.observation import Observation

__all__ = ['WanderParams', 'WanderPolicy']


@dataclass(frozen=True)
class WanderParams:
    """Wander policy (``sim.yaml`` section ``wander``)."""

    speed: float = param(0.0, 1.3, doc='forward wheel speed when the way is clear [m/s]')
    turn_speed: float = param(0.01, 1.3, doc='wheel speed of an in-place avoidance turn [m/s]')
    avoid_distance: float = param(0.0, 2.0, doc='turn away when a front IR reads less [m]')
    front_deg: float = param(0.0, 180.0, doc='half-width of the front IR sector [deg]')
    steer_sigma: float = param(0.0, 1.0, doc='std of the steering random walk per step [m/s]')
    steer_max: float = param(0.0, 1.3, doc='bound of the steering offset [m/s]')


class WanderPolicy:
    """Reactive random wander (module docstring).

    Parameters
    ----------
    params : WanderParams
        Speeds and thresholds.
    ir_angles : array_like, shape (n_ir,)
        Beam angles relative to the heading [rad], counter-clockwise positive.
    rng : np.random.Generator
        Source of the steering noise.
    """

    def __init__(self, params: WanderParams, ir_angles: ArrayLike,
                 rng: np.random.Generator) -> None:
        self.params = params
        ang = np.asarray(ir_angles, dtype=np.float64)
        front = np.abs(ang) <= math.radians(params.front_deg) + 1e-12
        self._front = front if front.any() else np.ones_like(front)
        self._left = ang > 1e-9
        self._right = ang < -1e-9
        self._rng = rng
        self.reset()

    def reset(self) -> None:
        """Forget the steering offset and the turning direction."""
        self._steer = 0.0
        self._turn = 0.0
        self._last_v = 0.0

    def act(self, obs: Observation) -> np.ndarray:
        """Wheel command ``(v_left, v_right)`` [m/s], shape (2,), for one observation."""
        p = self.params
        ir = obs.ir
        stuck = self._last_v > 0.0 and 0.5 * float(obs.wheels[0] + obs.wheels[1]) \
            < 0.25 * self._last_v
        if stuck or float(ir[self._front].min()) < p.avoid_distance:
            if self._turn == 0.0:
                # turn toward the freer side (left = counter-clockwise = +1); ties: random
                left = float(ir[self._left].sum()) if self._left.any() else 0.0
                right = float(ir[self._right].sum()) if self._right.any() else 0.0
                if left == right:
                    self._turn = 1.0 if self._rng.random() < 0.5 else -1.0
                else:
                    self._turn = 1.0 if left > right else -1.0
            self._steer = 0.0
            self._last_v = 0.0
            return np.array((-self._turn * p.turn_speed, self._turn * p.turn_speed))
        self._turn = 0.0
        self._last_v = p.speed
        if p.steer_sigma > 0.0:
            self._steer += p.steer_sigma * float(self._rng.standard_normal())
            self._steer = min(p.steer_max, max(-p.steer_max, self._steer))
        return np.array((p.speed - self._steer, p.speed + self._steer))
