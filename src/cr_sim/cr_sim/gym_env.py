"""Gymnasium environments around the pure simulator core (no ROS): :class:`CRNavEnv` (one
robot) and :class:`CRNavVectorEnv` (many robots in one process, ``gymnasium.vector``).

Both are registered as ``CRNav-v0`` (:mod:`cr_sim.gym_plugin`, docs/gym.md): importing this
module registers them, and in the project's venv ``gymnasium.make('CRNav-v0')`` and
``gymnasium.make_vec('CRNav-v0', num_envs=N)`` work without importing it first.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
import numpy as np

from cr_sim.core import kernels
from cr_sim.core.arena import Arena, load_arena
from cr_sim.core.observation import Observation
from cr_sim.core.sim import SimParams, Simulator, load_sim_params
from cr_sim.gym_plugin import register_envs

__all__ = ['CRNavEnv', 'CRNavVectorEnv']


def _layout(ir: np.ndarray, bearings: np.ndarray, out: np.ndarray, low: np.ndarray,
            high: np.ndarray) -> None:
    """Observation vector(s) into ``out`` (..., n_ir + 2 T) float32 from the IR readings
    (..., n_ir) and the bearings of the destination then the landmarks (..., T), NaN = not
    seen: the readings, then per target (visible flag, bearing or 0), clipped to the bounds."""
    n = ir.shape[-1]
    out[..., :n] = ir
    seen = ~np.isnan(bearings)
    out[..., n::2] = seen
    out[..., n + 1::2] = np.where(seen, bearings, 0.0)
    # float32 rounding may put a bearing of +-pi a hair outside the float32 bounds
    np.clip(out, low, high, out=out)


@kernels.njit
def _layout_into(ir: np.ndarray, bearings: np.ndarray, out: np.ndarray, low: np.ndarray,
                 high: np.ndarray) -> None:
    """:func:`_layout` of one robot, compiled: ``ir`` (n_ir,), ``bearings`` (T,) float64 into
    ``out`` (n_ir + 2 T,) float32, the same values (each float64 rounded to float32 once, as
    numpy's assignment does, then clipped in float32)."""
    n = ir.shape[0]
    for j in range(n):
        out[j] = ir[j]
    for k in range(bearings.shape[0]):
        b = bearings[k]
        seen = not math.isnan(b)
        out[n + 2 * k] = 1.0 if seen else 0.0
        out[n + 2 * k + 1] = b if seen else 0.0
    for j in range(out.shape[0]):
        # np.clip(out, low, high) as numpy's clip loop: NaN kept, else
        # MIN(MAX(x, low), high) with MAX(a, b) = a > b ? a : b (so -0.0 clips to +0.0)
        v = out[j]
        if not math.isnan(v):
            v = v if v > low[j] else low[j]
            v = v if v < high[j] else high[j]
        out[j] = v


class _WheelBox(spaces.Box):
    """The action space: a bounded float32 :class:`gymnasium.spaces.Box` whose ``sample()``
    draws exactly what ``Box.sample()`` draws (one ``uniform(low, high)`` call on
    ``np_random``), without its per-call masks for unbounded coordinates (they cost more than
    a simulator step).

    ``Generator.uniform(low, high)`` computes ``low + (high - low) * u`` in float64 with one
    ``random()`` double u per element, in order; doing that arithmetic here on the same doubles
    gives the same bits (tested against ``Box.sample``) in a sixth of the time: the
    broadcasting of array bounds cost ~10 us per call.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._low64 = self.low.astype(np.float64)
        self._range64 = self.high.astype(np.float64) - self._low64

    def sample(self, mask: None = None, probability: None = None) -> np.ndarray:
        """A uniform sample in ``[low, high]`` (``Box.sample`` for a bounded box)."""
        if mask is not None or probability is not None:
            return super().sample(mask, probability)     # raises as Box does
        # Generator.uniform(low, high, shape): low + (high - low) * U[0, 1), float64
        u = self.np_random.random(self.shape)
        return (self._low64 + self._range64 * u).astype(self.dtype)


class CRNavEnv(gym.Env):
    """Cyber Rodent navigation to the destination of the CLIS arena (Uchibe & Doya).

    ## Description

    A two-wheeled robot (a disc of radius ``robot.radius``) drives in a walled square arena
    with short obstacles (they block motion and the IR), tall obstacles (they also hide
    targets from the omni-camera), four coloured landmarks and a destination marker. The goal
    is to bring the robot centre within ``goal_radius`` of the destination. Physics, sensors
    and rewards are those of :class:`cr_sim.core.sim.Simulator`; layout and parameters come
    from ``config/arena.yaml``, ``config/robot.yaml`` and ``config/sim.yaml``.

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
        self.action_space = _WheelBox(-vmax, vmax, shape=(2,), dtype=np.float32)
        n_ir = len(self.params.sensors.ir_angles_deg)
        n_t = 1 + len(self.arena.landmarks)
        pi = np.float32(math.pi)
        low = np.concatenate([np.zeros(n_ir), np.tile([0.0, -pi], n_t)]).astype(np.float32)
        high = np.concatenate([np.full(n_ir, self.params.sensors.ir_range),
                               np.tile([1.0, pi], n_t)]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._n_ir = n_ir
        self._bearings = np.empty(n_t)
        self._low, self._high = self.observation_space.low, self.observation_space.high
        self._n_obs = self.observation_space.shape[0]
        self._sim: Simulator | None = None

    @property
    def sim(self) -> Simulator:
        """The underlying simulator (after the first :meth:`reset`)."""
        if self._sim is None:
            raise RuntimeError('call reset() first')
        return self._sim

    def _vector(self, obs: Observation, out: np.ndarray | None = None) -> np.ndarray:
        """The observation vector (class docstring) of ``obs``, into ``out`` if given."""
        if out is None:
            out = np.empty(self.observation_space.shape, dtype=np.float32)
        bearings = self._bearings
        bearings[0] = obs.dest_bearing
        bearings[1:] = obs.landmark_bearings
        _layout(obs.ir, bearings, out, self._low, self._high)
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
        """Apply wheel velocities for one step; see the class docstring.

        The observation vector is laid out from the simulator's sensors of the step
        (:meth:`Simulator.sense_all`'s IR and bearings, the values and noise of
        :meth:`Simulator.observe`) in one compiled call (:func:`_layout_into`, the arithmetic
        of :func:`_layout`), without an :class:`Observation` made.
        """
        sim = self.sim
        res = sim.step(action)
        ir, bearings, _ = sim._sensors()
        out = np.empty(self._n_obs, dtype=np.float32)
        _layout_into(ir, bearings, out, self._low, self._high)
        return (out, float(res.reward), res.reached, res.timeout,
                {'pose': np.array((sim._x, sim._y, sim._th)), 'collision': res.collision,
                 't': res.t, 'wheels': np.array((sim._wl, sim._wr))})


class CRNavVectorEnv(VectorEnv):
    """``num_envs`` robots in one process, each in its own arena: a native ``gymnasium.vector``
    environment with the results of ``SyncVectorEnv([CRNavEnv] * num_envs)`` (same seeds, same
    actions -> same observations, rewards and ends; tested), without its per-robot wrapper
    work: the robots' simulators step in one loop, their sensors are computed in one compiled
    call for all robots and laid out into shared batch arrays (:meth:`step`).

    Spaces: ``single_action_space`` / ``single_observation_space`` are those of
    :class:`CRNavEnv`; ``action_space`` (num_envs, 2) and ``observation_space``
    (num_envs, 17) their batches. Autoreset: ``next_step`` (gymnasium's default): the step after
    a robot's episode ended resets that robot (reward 0, not terminated, not truncated).
    ``reset(seed=s)`` seeds robot i with ``s + i`` (or a list of seeds). Infos are empty (the
    ground-truth poses are :attr:`poses`).

    Parameters
    ----------
    num_envs : int
        Number of robots, >= 1.
    arena, params, start
        As for :class:`CRNavEnv` (shared by all robots).
    """

    metadata = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int, arena: Arena | None = None,
                 params: SimParams | None = None, start: str = 'random') -> None:
        if int(num_envs) < 1:
            raise ValueError(f'num_envs must be >= 1, got {num_envs}')
        self.num_envs = int(num_envs)
        first = CRNavEnv(arena, params, start)
        self.envs = [first] + [CRNavEnv(first.arena, first.params, start)
                               for _ in range(self.num_envs - 1)]
        self.single_action_space = first.action_space
        self.single_observation_space = first.observation_space
        batched = batch_space(self.single_action_space, self.num_envs)
        self.action_space = _WheelBox(batched.low, batched.high, dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.render_mode = None
        self._obs = np.zeros(self.observation_space.shape, dtype=np.float32)
        self._rewards = np.zeros(self.num_envs)
        self._terminations = np.zeros(self.num_envs, dtype=bool)
        self._truncations = np.zeros(self.num_envs, dtype=bool)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._stepped = np.zeros(self.num_envs, dtype=bool)
        n_ir, n_t = first._n_ir, len(first._bearings)
        self._x, self._y, self._th = (np.zeros(self.num_envs) for _ in range(3))
        self._noise = np.zeros((self.num_envs, n_ir + n_t))
        self._ir = np.zeros((self.num_envs, n_ir))
        self._bear = np.zeros((self.num_envs, n_t))
        self._low, self._high = first._low, first._high
        self._sims: list[Simulator] = []

    @property
    def poses(self) -> np.ndarray:
        """Ground-truth ``(x, y, theta)`` of every robot, shape (num_envs, 3)."""
        return np.stack([env.sim.pose for env in self.envs])

    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every robot (``seed``: an int s seeds robot i with s + i, or one per robot)."""
        if seed is None or isinstance(seed, int):
            seeds = [None if seed is None else seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f'{len(seeds)} seeds for num_envs = {self.num_envs}')
        for i, (env, s) in enumerate(zip(self.envs, seeds)):
            self._obs[i], _ = env.reset(seed=s, options=options)
        self._sims = [env.sim for env in self.envs]       # a seed makes a new simulator
        self._terminations[:] = self._truncations[:] = self._autoreset[:] = False
        return self._obs.copy(), {}

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          dict[str, Any]]:
        """Step every robot with its row of ``actions`` (num_envs, 2) [m/s].

        Each robot's simulator steps (motion, contact, reward, episode end) and draws its
        sensor noise as :meth:`Simulator.observe` would; then the sensors of all robots are
        computed in one call (:func:`cr_sim.core.kernels.scan_many`, the same arithmetic) and
        laid out in one batch.
        """
        actions = np.asarray(actions)
        if actions.shape != self.action_space.shape:
            raise ValueError(f'actions must have shape {self.action_space.shape}, got '
                             f'{actions.shape}')
        obs, rewards = self._obs, self._rewards
        terminations, truncations = self._terminations, self._truncations
        x, y, th, noise, stepped = self._x, self._y, self._th, self._noise, self._stepped
        for i, sim in enumerate(self._sims):
            if self._autoreset[i]:
                env = self.envs[i]
                env._vector(sim.reset(start=env.start), obs[i])
                rewards[i] = 0.0
                terminations[i] = truncations[i] = stepped[i] = False
                continue
            res = sim.step(actions[i])
            rewards[i] = res.reward
            terminations[i] = res.reached
            truncations[i] = res.timeout
            noise[i] = sim._draw_noise()
            x[i], y[i], th[i] = sim._x, sim._y, sim._th
            stepped[i] = True
        s = self._sims[0]
        dx = s._targets_x[None, :] - x[:, None]
        dy = s._targets_y[None, :] - y[:, None]
        kernels.scan_many(x, y, th, s._ir_angles, s._targets_x, s._targets_y,
                          np.arctan2(dy, dx), s._planes, s._n_tall, s._r, s._ir_range, noise,
                          s._noisy, self._ir, self._bear)
        if s._cam_range is not None:
            self._bear[np.hypot(dx, dy) > s._cam_range] = np.nan
        if stepped.all():
            _layout(self._ir, self._bear, obs, self._low, self._high)
        elif stepped.any():
            rows = np.empty((int(stepped.sum()), obs.shape[1]), dtype=np.float32)
            _layout(self._ir[stepped], self._bear[stepped], rows, self._low, self._high)
            obs[stepped] = rows
        np.logical_or(terminations, truncations, out=self._autoreset)
        return obs.copy(), rewards.copy(), terminations.copy(), truncations.copy(), {}


register_envs()         # 'CRNav-v0' for gymnasium.make / make_vec (docs/gym.md)
