"""Gymnasium environment around the pure simulator core (no ROS)."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
from gymnasium import spaces
import numpy as np

from cr_sim.core.arena import Arena, load_arena
from cr_sim.core.sim import Observation, SimParams, Simulator, load_sim_params

__all__ = ['CRNavEnv']


class CRNavEnv(gym.Env):
    """Cyber Rodent navigation to the destination of the CLIS arena (Uchibe & Doya).

    ## Description

    A two-wheeled robot (a disc of radius ``robot.radius``) drives in a walled square arena
    with short obstacles (they block motion and the IR), tall obstacles (they also hide
    targets from the omni-camera), four coloured landmarks and a destination marker. The goal
    is to bring the robot centre within ``goal_radius`` of the destination. Physics, sensors
    and rewards are those of :class:`cr_sim.core.sim.Simulator`; layout and parameters come
    from ``config/arena.yaml`` and ``config/sim.yaml``.

    ## Action Space

    ``Box(-v_wheel_max, v_wheel_max, (2,), float32)`` (v_wheel_max = 1.3 m/s): the left and
    right wheel velocities [m/s], held for one step ``episode.dt`` (0.05 s). Out-of-range
    values are clipped and NaN/inf stop that wheel (safety clamp).

    ## Observation Space

    ``Box(low, high, (n_ir + 2 + 2 * n_landmarks,), float32)``, 17 with the default files:

    | index            | observation                                  | min   | max      |
    |------------------|----------------------------------------------|-------|----------|
    | 0 .. n_ir-1      | IR distance from the body surface [m]        | 0     | ir_range |
    | n_ir             | destination visible (1) or hidden (0)        | 0     | 1        |
    | n_ir + 1         | destination bearing from the heading [rad]   | -pi   | pi       |
    | n_ir + 2 + 2k    | landmark k visible (1) or hidden (0)         | 0     | 1        |
    | n_ir + 3 + 2k    | landmark k bearing [rad]                     | -pi   | pi       |

    Bearings are counter-clockwise positive, 0 when the target is not visible.

    ## Rewards

    ``reward_goal`` (+1) on reaching the destination, ``reward_collision`` (-0.1) on each new
    contact with a wall or an obstacle (not repeated while pressed), 0 otherwise.

    ## Starting State

    ``options={'start': S}`` in :meth:`reset`, with S a start name of the arena file
    ('A'..'E'), ``'random'`` (uniform free pose), ``'wander'`` (wander from the current pose),
    or a pose ``(x, y, theta)``; ``options={'heading': rad}`` overrides the heading. The
    default S is the ``start`` given to the constructor.

    ## Episode End

    ``terminated`` when the destination is reached; ``truncated`` after ``time_limit`` (60 s,
    1200 steps).

    ## Info

    ``pose`` (x, y, theta) ground truth, ``collision`` (bool), ``t`` [s], ``wheels`` (executed
    wheel velocities [m/s]).

    Parameters
    ----------
    arena : Arena, optional
        Default: ``load_arena()``.
    params : SimParams, optional
        Default: ``load_sim_params()``.
    start : str
        Default start of :meth:`reset`.
    render_mode : None
        No rendering (the ROS node publishes markers for RViz/Foxglove).
    """

    metadata = {'render_modes': [], 'render_fps': 20}

    def __init__(self, arena: Arena | None = None, params: SimParams | None = None,
                 start: str = 'random', render_mode: str | None = None) -> None:
        if render_mode is not None:
            raise ValueError(f'render_mode {render_mode!r} is not supported (None only)')
        self.render_mode = render_mode
        self.params = params if params is not None else load_sim_params()
        self.arena = arena if arena is not None else load_arena(
            robot_radius=self.params.robot.radius)
        self.start = start
        vmax = self.params.robot.v_wheel_max
        self.action_space = spaces.Box(-vmax, vmax, shape=(2,), dtype=np.float32)
        n_ir = len(self.params.sensors.ir_angles_deg)
        n_t = 1 + len(self.arena.landmarks)
        pi = np.float32(math.pi)
        low = np.concatenate([np.zeros(n_ir), np.tile([0.0, -pi], n_t)]).astype(np.float32)
        high = np.concatenate([np.full(n_ir, self.params.sensors.ir_range),
                               np.tile([1.0, pi], n_t)]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._n_ir = n_ir
        self._sim: Simulator | None = None

    @property
    def sim(self) -> Simulator:
        """The underlying simulator (after the first :meth:`reset`)."""
        if self._sim is None:
            raise RuntimeError('call reset() first')
        return self._sim

    def _vector(self, obs: Observation) -> np.ndarray:
        bearings = np.concatenate([[obs.dest_bearing], obs.landmark_bearings])
        seen = ~np.isnan(bearings)
        out = np.empty(self.observation_space.shape, dtype=np.float32)
        out[:self._n_ir] = obs.ir
        out[self._n_ir::2] = seen
        out[self._n_ir + 1::2] = np.where(seen, bearings, 0.0)
        # float32 rounding may put a bearing of +-pi a hair outside the float32 bounds
        np.clip(out, self.observation_space.low, self.observation_space.high, out=out)
        return out

    def _info(self, collision: bool = False) -> dict[str, Any]:
        sim = self.sim
        return {'pose': sim.pose, 'collision': collision, 't': sim.t, 'wheels': sim.wheels}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; ``seed`` re-seeds (a new simulator on ``self.np_random``)."""
        super().reset(seed=seed)
        if seed is not None or self._sim is None:
            self._sim = Simulator(self.arena, self.params, self.np_random)
        options = dict(options or {})
        start = options.pop('start', self.start)
        heading = options.pop('heading', None)
        if options:
            raise ValueError(f'unknown reset options: {sorted(options)}; use start, heading')
        obs = self._sim.reset(start=start, heading=heading)
        return self._vector(obs), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply wheel velocities for one step; see the class docstring."""
        res = self.sim.step(action, observe=True)
        return (self._vector(res.obs), float(res.reward), bool(res.reached), bool(res.timeout),
                self._info(res.collision))
