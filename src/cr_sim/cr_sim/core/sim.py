"""The Cyber Rodent arena simulator: seeded, headless, no ROS.

One :class:`Simulator` holds one robot in one :class:`~cr_sim.core.arena.Arena`::

    sim = Simulator(arena, params, rng)     # rng: the only source of randomness
    obs = sim.reset(start='A')              # or 'random', 'wander', or a pose (x, y, theta)
    res = sim.step((v_left, v_right))       # wheel velocities [m/s] held for episode.dt
    res.reward, res.collision, res.reached, res.timeout, res.done, res.t
    obs = res.obs                           # sensors computed only on demand (lazy)

Model
-----
* Motion: differential drive, exact arc integration (:mod:`cr_sim.core.robot`); the command
  always goes through :func:`~cr_sim.core.robot.clamp_wheels` (NaN/inf -> 0, +-v_wheel_max).
* Contact: the robot is a disc. If the end pose of a step would overlap a wall or an obstacle,
  the forward speed is scaled by the largest factor s in [0, 1] (bisection, 20 halvings) whose
  end pose does not overlap, the yaw rate is kept: the robot moves up to the contact and still
  turns, so it can always turn away. The executed wheels ``sim.wheels`` are those of
  ``(s v, omega)``: integrating them gives the true motion (consistent odometry). Only end
  poses are checked: a step is at most v_wheel_max * dt = 6.5 cm, so a corner can at most be
  grazed mid-step (< 5 mm for r = 0.11 m); no pose the simulator ever reports overlaps.
* The robot *touches* when its last step was blocked or its gap to the nearest surface is below
  ``episode.contact_tolerance``. A *collision* is a new touch (not touching before the step,
  touching after it): ``reward_collision`` once, nothing more while it stays pressed.
* Reward of a step: ``reward_collision`` on a collision, plus ``reward_goal`` when the centre
  ends within ``goal_radius`` of the destination (episode ends, ``reached``), else 0. The
  episode also ends (``timeout``, not reached) after ``time_limit`` s. ``step`` after the end
  raises: call ``reset``. An ``endless`` simulator has no end (a robot world that runs on):
  the goal and the time limit end nothing, ``reached``, ``timeout`` and ``done`` stay False
  and the goal's reward is never given (a new contact's still is).
* IR: ``n_ir`` beams from the body surface at ``ir_angles_deg`` from the heading; each reads
  the distance from the surface to the first wall/obstacle (short or tall) along the beam,
  ``+ N(0, ir_noise_sigma^2)``, clipped to ``[0, ir_range]``; ``ir_range`` when nothing is
  within range.
* Omni-camera: the bearing of the destination and of each landmark relative to the heading,
  ``+ N(0, bearing_noise^2)``, wrapped to (-pi, pi]; ``nan`` when the segment robot->target
  crosses a tall obstacle or the target is beyond ``camera_range`` (the destination: beyond
  ``destination_range``, when set). Short obstacles and walls hide nothing.

Randomness: the ``rng`` passed in draws the start poses and the wander steering; the sensor
noise comes from a child generator spawned from it at construction, so whether (and how often)
a caller observes never changes the starts or the motion. Same seed, same calls -> bit-identical
results.

One piece, the simulator's state and the order of what changes it: the pose, the contact, the
clock and the two random streams are advanced by ``reset``, ``step``, ``hold`` and the sensors
in one fixed order, which is what makes a run bit-identical per seed and what ``carry`` and the
resume state save; the pure parts (geometry, kinematics, the compiled kernels, the parameters)
are modules of their own.
"""

from __future__ import annotations

from collections.abc import Mapping
import math
import os
from typing import Any

from clis_base.params import (
    ConfigError,
    as_dict,
    config_dir,
    dataclass,
    load_params,
    param,
    ros_parameters,
)
from clis_base.ufunc_loops import LOOPS
import numpy as np
from numpy.typing import ArrayLike

from cr_sim.core import kernels
from cr_sim.core.arena import Arena
from cr_sim.core.geometry import box_planes, disc_gap, wrap_angle
from cr_sim.core.observation import Observation
from cr_sim.core.robot import ROBOT_FILE, RobotParams, clamp_wheels, load_robot_params
from cr_sim.core.wander import WanderParams, WanderPolicy

__all__ = [
    'SensorParams', 'EpisodeParams', 'SimParams', 'load_sim_params', 'StepResult', 'Simulator',
    'IGNORED_SECTIONS',
]

#: Sections of ``sim.ros__parameters`` read by the ROS node, not by the core.
IGNORED_SECTIONS = ('node',)

_N_BISECT = 20          # halvings of the contact search: resolution 2^-20 of a step
_MAX_TRIES = 100_000    # rejection sampling of a random free start
_NOISE_BLOCK = 256      # observations' noise drawn at a time
_ENDLESS_K = 2**62      # the step count an endless simulator never reaches (int64)


# ------------------------------------------------------------------------------------------
# parameters

@dataclass(frozen=True)
class SensorParams:
    """IR proximity sensors and omni-camera (``sim.yaml`` section ``sensors``)."""

    ir_angles_deg: tuple[float, ...] = param(
        -180.0, 180.0, doc='beam directions from the heading, counter-clockwise [deg]')
    ir_range: float = param(0.01, 5.0, doc='maximum IR reading [m]')
    ir_noise_sigma: float = param(0.0, 1.0, doc='std of the Gaussian IR noise [m]')
    camera_range: float = param(0.1, 100.0, doc='targets farther than this are not seen [m]')
    destination_range: float = param(
        0.0, 100.0, doc='the destination marker is not seen farther than this [m] (a small '
        'blob on the floor; the landmarks keep camera_range); 0 = camera_range')
    bearing_noise_deg: float = param(0.0, 90.0, doc='std of the bearing noise [deg]')

    def validate(self) -> None:
        """At least one IR beam."""
        if len(self.ir_angles_deg) < 1:
            raise ValueError('sensors.ir_angles_deg needs at least one beam')


@dataclass(frozen=True)
class EpisodeParams:
    """Time step, rewards and episode end (``sim.yaml`` section ``episode``)."""

    dt: float = param(0.001, 1.0, doc='simulation step: a command is held this long [s]')
    time_limit: float = param(0.01, 3600.0, doc='episode length before timeout [s]')
    reward_goal: float = param(-100.0, 100.0, doc='reward on reaching the destination')
    reward_collision: float = param(-100.0, 100.0, doc='reward on each new contact')
    contact_tolerance: float = param(0.0, 0.1, doc='gap below which the robot touches [m]')
    wander_time: float = param(0.0, 600.0, doc="duration of reset(start='wander') [s]")

    def validate(self) -> None:
        """The time limit holds at least one step."""
        if self.dt > self.time_limit:
            raise ValueError(f'episode.dt = {self.dt} exceeds episode.time_limit = '
                             f'{self.time_limit}')


@dataclass(frozen=True)
class SimParams:
    """Everything the simulator core reads: the body from ``robot.yaml``, the rest from
    ``sim.yaml`` (``sim: ros__parameters:``)."""

    robot: RobotParams = param(doc='the body: robot.yaml, section robot')
    sensors: SensorParams = param(doc='section sensors')
    episode: EpisodeParams = param(doc='section episode')
    wander: WanderParams = param(doc='section wander')


def load_sim_params(path: str | os.PathLike | None = None,
                    overrides: Mapping[str, Any] | None = None,
                    robot_path: str | os.PathLike | None = None) -> SimParams:
    """Read ``sim: ros__parameters:`` of a ROS 2 parameter file and the body of ``robot.yaml``
    (:func:`~cr_sim.core.robot.load_robot_params`) into :class:`SimParams`.

    Parameters
    ----------
    path : path-like, optional
        Default ``config_dir() / 'sim.yaml'``.
    overrides : Mapping, optional
        Values replacing the files', as a nested mapping (``{'robot': {'radius': 0.1}}``)
        and/or dotted keys (``{'robot.radius': 0.1}``). Every key must exist in the files.
    robot_path : path-like, optional
        Default ``config_dir() / 'robot.yaml'``.

    Raises
    ------
    ConfigError
        Naming the file and the key: missing, unknown, wrong type or out of range.
        Sections listed in :data:`IGNORED_SECTIONS` (``node``) are left to the ROS node; a
        ``robot`` section in the simulator's file is an error (the body is in ``robot.yaml``).
    """
    p = path if path is not None else config_dir() / 'sim.yaml'
    if 'robot' in ros_parameters(p, 'sim'):
        raise ConfigError(f'{p}: section robot: the body is described once, in {ROBOT_FILE} '
                          '(cr_sim.core.robot.load_robot_params), not here')
    robot = as_dict(load_robot_params(robot_path))
    return load_params(SimParams, 'sim.yaml', 'sim', path, overrides, IGNORED_SECTIONS, 'sim',
                       extra={'robot': robot})


# ------------------------------------------------------------------------------------------
# results

class StepResult:
    """Outcome of one :meth:`Simulator.step`.

    Attributes
    ----------
    t : float
        Time after the step [s].
    reward : float
    collision : bool
        A new contact began during this step.
    reached : bool
        The robot centre is within ``goal_radius`` of the destination (episode over).
    timeout : bool
        ``time_limit`` reached without reaching the destination (episode over).
    steps : int
        Simulator steps it covers (:meth:`Simulator.hold`; 1 for :meth:`Simulator.step`).
    """

    __slots__ = ('t', 'reward', 'collision', 'reached', 'timeout', 'steps', '_sim', '_tick',
                 '_obs')

    def __init__(self, t: float, reward: float, collision: bool, reached: bool, timeout: bool,
                 sim: Simulator, tick: int, obs: Observation | None = None,
                 steps: int = 1) -> None:
        self.t = t
        self.reward = reward
        self.collision = collision
        self.reached = reached
        self.timeout = timeout
        self.steps = steps
        self._sim = sim
        self._tick = tick
        self._obs = obs

    @property
    def done(self) -> bool:
        """The episode is over (reached or timeout)."""
        return self.reached or self.timeout

    @property
    def obs(self) -> Observation:
        """The observation after this step, computed on first access.

        Raises
        ------
        RuntimeError
            If the simulator has stepped or reset since (the state is gone).
        """
        if self._obs is None:
            if self._sim._tick != self._tick:
                raise RuntimeError('StepResult.obs read after the simulator moved on: read it '
                                   'before the next step/reset, or use step(u, observe=True)')
            self._obs = self._sim.observe()
        return self._obs

    def __repr__(self) -> str:
        return (f'StepResult(t={self.t:.3f}, reward={self.reward}, collision={self.collision}, '
                f'reached={self.reached}, timeout={self.timeout})')


# ------------------------------------------------------------------------------------------
# the simulator

class Simulator:
    """The CR in the arena (module docstring for the model).

    Parameters
    ----------
    arena : Arena
        Layout; checked against ``params.robot.radius``.
    params : SimParams
        Robot, sensors, episode and wander parameters.
    rng : np.random.Generator
        The only source of randomness (start poses, wander, and via a spawned child, noise).
    endless : bool
        No episode end (module docstring): the robot drives on past the goal and the time
        limit.
    """

    def __init__(self, arena: Arena, params: SimParams, rng: np.random.Generator, *,
                 endless: bool = False) -> None:
        if not isinstance(rng, np.random.Generator):
            raise TypeError('rng must be a numpy.random.Generator')
        arena.check(params.robot.radius)
        self.arena = arena
        self.params = params
        self._rng = rng
        try:
            self._noise_rng = rng.spawn(1)[0]
        except (TypeError, AttributeError):   # a generator without a SeedSequence
            self._noise_rng = np.random.default_rng(int(rng.integers(2**63)))
        self._noise_state0 = self._noise_rng.bit_generator.state
        self._noise_rows = 0                  # observations' noise drawn since then

        rp, sp, ep = params.robot, params.sensors, params.episode
        self._r = rp.radius
        self._b = rp.wheel_base
        self._vmax = rp.v_wheel_max
        self._dt = ep.dt
        # integer step count of the time limit (t = k dt, no accumulated rounding)
        self._k_max = max(1, math.ceil(ep.time_limit / ep.dt - 1e-9))
        self.endless = endless
        self._boxes, self._half = arena.gap_boxes()   # a non-square floor: walls as boxes
        # for the kernel: numba cannot iterate an empty tuple; a box at infinity is never near
        self._kernel_boxes = self._boxes or ((math.inf,) * 4,)
        dest = arena.destination
        self._dest = (dest.x, dest.y)
        self._goal_r2 = dest.goal_radius ** 2
        # what ends an episode: the step count and the goal's squared radius (endless: never)
        self._k_end, self._end_r2 = (_ENDLESS_K, -1.0) if endless else (self._k_max,
                                                                          self._goal_r2)
        self._reward_goal, self._reward_collision = ep.reward_goal, ep.reward_collision
        self._tol = ep.contact_tolerance

        # sensor model: rows = IR beams then camera targets (destination, landmarks);
        # columns = tall obstacles, short obstacles, then the 4 walls
        self._ir_angles = np.radians(np.asarray(sp.ir_angles_deg, dtype=np.float64))
        self._n_ir = len(self._ir_angles)
        self._targets = np.array([[dest.x, dest.y]] + [[lm.x, lm.y] for lm in arena.landmarks])
        self._n_rays = self._n_ir + len(self._targets)
        self._targets_x = np.ascontiguousarray(self._targets[:, 0])
        self._targets_y = np.ascontiguousarray(self._targets[:, 1])
        self._planes = box_planes(arena.box_array(walls=True))
        self._n_tall = len(arena.tall_obstacles)
        self._ir_range = sp.ir_range
        diag = math.hypot(arena.width, arena.height)
        # the farthest each target is seen: the destination, then the landmarks
        ranges = np.full(len(self._targets), sp.camera_range)
        ranges[0] = sp.destination_range or sp.camera_range
        self._cam_range = ranges if (ranges < diag).any() else None
        sig_b = math.radians(sp.bearing_noise_deg)
        self._noisy = sp.ir_noise_sigma > 0.0 or sig_b > 0.0
        self._sigmas = np.concatenate([np.full(self._n_ir, sp.ir_noise_sigma),
                                       np.full(len(self._targets), sig_b)])
        self._no_noise = np.zeros(self._n_rays)
        # the noise of the next observations, drawn _NOISE_BLOCK at a time (the same stream
        # as one draw per observation: standard_normal fills its array in order)
        self._noise_block = np.empty((0, self._n_rays))
        self._noise_pos = 0
        self._scan_dx, self._scan_dy = np.empty(len(self._targets)), np.empty(len(self._targets))
        self._scan_tick = -1
        self._scan = (math.nan, math.nan, np.empty(0))

        self._held = np.empty((1, 2))          # executed wheels of the steps of hold()
        self._wander = WanderPolicy(params.wander, self._ir_angles, rng)
        self._tick = 0
        start = arena.starts[0]
        self._set_pose(start.x, start.y, start.heading)
        self._obs: Observation | None = None
        self._obs_tick = -1

    # -------------------------------------------------------------------- state accessors
    @property
    def pose(self) -> np.ndarray:
        """Ground-truth ``(x, y, theta)`` [m, m, rad], theta in (-pi, pi], shape (3,)."""
        return np.array((self._x, self._y, self._th))

    @property
    def t(self) -> float:
        """Time since reset [s]."""
        return self._k * self._dt

    @property
    def steps(self) -> int:
        """Steps since reset."""
        return self._k

    @property
    def wheels(self) -> np.ndarray:
        """Executed ``(v_left, v_right)`` of the last step [m/s], shape (2,)."""
        return np.array((self._wl, self._wr))

    @property
    def wheel_speeds(self) -> tuple[float, float]:
        """:attr:`wheels` as two floats ``(v_left, v_right)`` [m/s] (no array made)."""
        return self._wl, self._wr

    @property
    def done(self) -> bool:
        """The episode is over: call :meth:`reset`."""
        return self._done

    @property
    def touching(self) -> bool:
        """The robot is in contact with a wall or an obstacle."""
        return self._touching

    @property
    def gap(self) -> float:
        """Free distance from the body surface to the nearest wall/obstacle [m] (>= 0)."""
        return disc_gap(self._x, self._y, self._r, self._boxes, self._half)

    @property
    def n_ir(self) -> int:
        """Number of IR beams."""
        return self._n_ir

    # -------------------------------------------------------------------------- episode
    def reset(self, start: str | ArrayLike = 'A', heading: float | None = None) -> Observation:
        """Start a new episode.

        Parameters
        ----------
        start : str or array_like, shape (3,)
            A start name of the arena file (heading from the file); ``'random'``: a uniformly
            random free position (not in the goal) and heading; ``'wander'``: run the wander
            policy from the current pose for ``episode.wander_time`` s (longer if it ends in
            the goal) and start where it stops; or an explicit free pose ``(x, y, theta)``.
        heading : float, optional
            Overrides the start heading [rad].

        Returns
        -------
        Observation
            At t = 0.

        Raises
        ------
        ValueError
            Unknown start name, or an explicit pose that overlaps a wall/obstacle.
        """
        if isinstance(start, str):
            if start == 'random':
                x, y, th = self._random_pose()
            elif start == 'wander':
                x, y, th = self._run_wander()
            else:
                try:
                    s = self.arena.start(start)
                except KeyError as exc:
                    raise ValueError(f"{exc.args[0]}, 'random', 'wander'") from None
                x, y, th = s.x, s.y, s.heading
        else:
            x, y, th = (float(v) for v in np.asarray(start, dtype=np.float64).reshape(3))
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
                raise ValueError(f'start pose must be finite, got {start!r}')
            if disc_gap(x, y, self._r, self._boxes, self._half) < 0.0:
                raise ValueError(f'start pose ({x}, {y}) overlaps a wall or an obstacle')
        if heading is not None:
            th = float(heading)
            if not math.isfinite(th):
                raise ValueError(f'heading must be finite, got {heading!r}')
        self._set_pose(x, y, th)
        return self.observe()

    def reseed(self, rng: np.random.Generator) -> None:
        """Draw everything from now on from ``rng`` (starts, wander, and via a spawned child,
        noise), as a new simulator would: the noise already drawn is dropped and the last
        observation is not reused. With :meth:`carried` / :meth:`carry`, a run whose episodes
        are reseeded at each reset can stop and go on in another process, the same to the bit
        (the sim node, ``clis run --resume``)."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError('rng must be a numpy.random.Generator')
        self._rng = self._wander._rng = rng
        try:
            self._noise_rng = rng.spawn(1)[0]
        except (TypeError, AttributeError):   # a generator without a SeedSequence
            self._noise_rng = np.random.default_rng(int(rng.integers(2**63)))
        self._noise_block = np.empty((0, self._n_rays))
        self._noise_pos = 0
        self._noise_state0 = self._noise_rng.bit_generator.state
        self._noise_rows = 0
        self._tick += 1                        # the observation made before: drawn then

    def random_state(self) -> dict:
        """Where the simulator's random streams stand (plain JSON): its generator's state and
        the number of observations' noise drawn (the noise generator is a child of it, drawn a
        block at a time: :meth:`set_random_state` draws those blocks again). With
        :meth:`carried`, what a run needs to go on in another process exactly as in this one
        (the sim node, ``clis run --resume``)."""
        return {'rng': self._rng.bit_generator.state, 'noise_rows': self._noise_rows}

    def set_random_state(self, state: dict) -> None:
        """Continue from :meth:`random_state` of a simulator built with the same generator
        seed (its noise generator starts where this one's started)."""
        self._rng.bit_generator.state = state['rng']
        rows = int(state['noise_rows'])
        self._noise_rng.bit_generator.state = self._noise_state0
        self._noise_block = np.empty((0, self._n_rays))
        self._noise_pos = 0
        if rows > 0:
            blocks = -(-rows // _NOISE_BLOCK)
            for _ in range(blocks):
                block = self._noise_rng.standard_normal((_NOISE_BLOCK, self._n_rays))
            self._noise_block = block * self._sigmas
            self._noise_pos = rows - (blocks - 1) * _NOISE_BLOCK
        self._noise_rows = rows
        self._tick += 1

    def carried(self) -> tuple[float, ...]:
        """What the next :meth:`reset` (``'wander'``) starts from: ``(x, y, theta, v_left,
        v_right, touching)`` (:meth:`carry` puts it in another simulator)."""
        return (self._x, self._y, self._th, self._wl, self._wr, float(self._touching))

    def carry(self, state: ArrayLike) -> None:
        """Take :meth:`carried` of another simulator (the robot stands where it stood)."""
        x, y, th, wl, wr, touching = (float(v) for v in np.asarray(state, float).reshape(6))
        if disc_gap(x, y, self._r, self._boxes, self._half) < 0.0:
            raise ValueError(f'carried pose ({x}, {y}) overlaps a wall or an obstacle')
        self._x, self._y, self._th, self._wl, self._wr = x, y, th, wl, wr
        self._touching = bool(touching)
        self._tick += 1

    def _set_pose(self, x: float, y: float, th: float) -> None:
        self._x, self._y, self._th = float(x), float(y), wrap_angle(float(th))
        self._k = 0
        self._done = False
        self._wl = self._wr = 0.0
        self._touching = disc_gap(x, y, self._r, self._boxes, self._half) < self._tol
        self._tick += 1

    def _in_goal(self, x: float, y: float) -> bool:
        dx, dy = x - self._dest[0], y - self._dest[1]
        return dx * dx + dy * dy <= self._goal_r2

    def _random_pose(self) -> tuple[float, float, float]:
        x0, y0, x1, y1 = self.arena.bounds
        r = self._r
        for _ in range(_MAX_TRIES):
            x, y = self._rng.uniform((x0 + r, y0 + r), (x1 - r, y1 - r))
            th = self._rng.uniform(-math.pi, math.pi)
            if (disc_gap(x, y, self._r, self._boxes, self._half) >= self._tol
                    and not self._in_goal(x, y)):
                return float(x), float(y), float(th)
        raise RuntimeError(f'no free random start found in {_MAX_TRIES} tries')

    def _run_wander(self) -> tuple[float, float, float]:
        n = round(self.params.episode.wander_time / self._dt)
        self._wander.reset()
        self._k = 0
        k = 0
        # keep wandering while in the goal (the episode would be over at once); bounded
        n_max = 10 * n + 1000
        if self._obs_tick == self._tick and (k < n or (self._in_goal(self._x, self._y)
                                                        and k < n_max)):
            # the first tick reads the observation already made (no new noise)
            u = self._wander.act(self.observe())
            self._move(float(u[0]), float(u[1]))
            self._tick += 1
            k += 1
        # the other ticks: observation (IR), WanderPolicy.act and _move compiled as one loop
        w, wp = self._wander, self._wander.params
        state = np.array((w._steer, w._turn, w._last_v))
        if self._noisy and self._noise_pos == len(self._noise_block):
            self._noise_block = np.empty((_NOISE_BLOCK, self._n_rays))   # filled there
            self._noise_pos = _NOISE_BLOCK
        pos = np.array([self._noise_pos])
        (self._x, self._y, self._th, self._wl, self._wr, self._touching, k_end) = \
            kernels.wander(
                self._x, self._y, self._th, self._wl, self._wr, self._touching, k, n, n_max,
                state, np.array((wp.speed, wp.turn_speed, wp.avoid_distance, wp.steer_sigma,
                                 wp.steer_max)), w._front, w._left, w._right,
                self._ir_angles, self._planes, self._r, self._ir_range, self._sigmas,
                self._noisy, self._rng, self._noise_rng, self._noise_block, pos, self._vmax,
                self._b, self._dt,
                self._kernel_boxes, self._half, self._tol, _N_BISECT, self._dest[0],
                self._dest[1], self._goal_r2)
        w._steer, w._turn, w._last_v = (float(v) for v in state)
        self._noise_pos = int(pos[0])
        if self._noisy:
            self._noise_rows += k_end - k      # one observation per tick of the loop
        self._tick += k_end - k
        return self._x, self._y, self._th

    def _run_wander_reference(self) -> tuple[float, float, float]:
        """:meth:`_run_wander` as a Python loop of :meth:`observe`, ``WanderPolicy.act`` and
        :meth:`_move` (the reference of the compiled loop, for the tests)."""
        n = round(self.params.episode.wander_time / self._dt)
        self._wander.reset()
        self._k = 0
        k = 0
        while k < n or (self._in_goal(self._x, self._y) and k < 10 * n + 1000):
            u = self._wander.act(self.observe())
            self._move(float(u[0]), float(u[1]))
            self._tick += 1
            k += 1
        return self._x, self._y, self._th

    # ---------------------------------------------------------------------------- motion
    def _move(self, u_left: float, u_right: float) -> None:
        """Advance one dt under the command ``(u_left, u_right)`` [m/s], clamped, with the
        contact model of the module docstring (:func:`cr_sim.core.kernels.move`)."""
        (self._x, self._y, self._th, self._wl, self._wr, _blocked,
         self._touching) = kernels.move(
            self._x, self._y, self._th, u_left, u_right, self._vmax, self._b, self._dt,
            self._r, self._kernel_boxes, self._half, self._tol, _N_BISECT)

    def step(self, u: ArrayLike, observe: bool = False) -> StepResult:
        """Hold the wheel command ``u`` for one ``episode.dt``.

        Parameters
        ----------
        u : array_like, shape (2,)
            ``(v_left, v_right)`` [m/s]; clamped by :func:`clamp_wheels` (NaN/inf -> 0,
            +-v_wheel_max), so no command can move the robot more than v_wheel_max * dt.
        observe : bool
            Compute the observation now (else on first access of ``result.obs``).

        Returns
        -------
        StepResult

        Raises
        ------
        RuntimeError
            If the episode is over (call :meth:`reset`).
        """
        res = self._advance(u, 1)
        if observe:
            res._obs = self.observe()
        return res

    def hold(self, u: ArrayLike, n: int) -> tuple[StepResult, np.ndarray]:
        """:meth:`step` with the same command up to ``n`` (>= 1) times, stopping after the
        first step with a reward (a new contact, the goal) or the end of the episode: the same
        results as those calls of :meth:`step`, without a return to Python per step.

        Returns
        -------
        StepResult
            Of the last step done.
        np.ndarray, shape (steps, 2)
            Executed ``(v_left, v_right)`` of each step done [m/s] (a view, valid until the
            next call).
        """
        res = self._advance(u, n)
        return res, self._held[:res.steps]

    def _advance(self, u: ArrayLike, n: int) -> StepResult:
        if self._done:
            raise RuntimeError('the episode is over (reached or timeout): call reset()')
        if type(u) is np.ndarray and u.shape == (2,) and u.dtype.kind == 'f':
            u_left, u_right = u.tolist()                   # the clamp is in the kernel
        else:
            u_left, u_right = clamp_wheels(u, self._vmax)  # any other input: checked here
        if n > len(self._held):
            self._held = np.empty((n, 2))
        # kernels.hold: _move until a new contact (collision), the centre within goal_radius
        # (reached) or the time limit
        (self._x, self._y, self._th, self._touching, self._k, steps, collision,
         reached) = kernels.hold(
            self._x, self._y, self._th, self._touching, self._k, self._k_end, u_left, u_right,
            n, self._vmax, self._b, self._dt, self._r, self._kernel_boxes, self._half,
            self._tol, _N_BISECT, self._dest[0], self._dest[1], self._end_r2, self._held)
        self._wl, self._wr = self._held[steps - 1].tolist()
        self._tick += steps
        timeout = (not reached) and self._k >= self._k_end
        reward = 0.0
        if collision:
            reward += self._reward_collision
        if reached:
            reward += self._reward_goal
        self._done = reached or timeout
        return StepResult(self._k * self._dt, reward, collision, reached, timeout, self,
                          self._tick, steps=steps)

    # --------------------------------------------------------------------------- sensing
    def _draw_noise(self) -> np.ndarray:
        """The noise of one observation: IR beams then targets, shape (n_ir + T,) (zeros
        without noise; nothing is drawn then): the next row of ``standard_normal`` draws
        times the sensors' sigmas (drawn :data:`_NOISE_BLOCK` observations at a time)."""
        if self._noisy:
            if self._noise_pos == len(self._noise_block):
                self._noise_block = (self._noise_rng.standard_normal((_NOISE_BLOCK,
                                                                       self._n_rays))
                                     * self._sigmas)
                self._noise_pos = 0
            self._noise_pos += 1
            self._noise_rows += 1
            return self._noise_block[self._noise_pos - 1]
        return self._no_noise

    def _sensors(self) -> tuple[np.ndarray, np.ndarray, float]:
        """IR readings, camera bearings (destination, then landmarks) and the smallest IR
        reading at the current time, computed once per step/reset (the noise is drawn
        then)."""
        if self._scan_tick != self._tick:
            x, y, th = self._x, self._y, self._th
            # ray casts of the IR beams (unit directions) and of the segments robot -> target
            # (t in [0, 1]) through the boxes; a target is hidden when its segment enters a
            # tall obstacle (the first boxes). Walls and short obstacles hide nothing.
            ir, bearing = np.empty(self._n_ir), np.empty(len(self._targets_x))
            d_o = kernels.sense(x, y, th, self._ir_angles, self._targets_x, self._targets_y,
                                self._planes, self._n_tall, self._r, self._ir_range,
                                self._draw_noise(), self._noisy, LOOPS, self._scan_dx,
                                self._scan_dy, ir, bearing)
            if self._cam_range is not None:
                bearing[np.hypot(self._scan_dx, self._scan_dy) > self._cam_range] = np.nan
            ir.flags.writeable = False
            bearing.flags.writeable = False
            self._scan, self._scan_tick = (ir, bearing, d_o), self._tick
        return self._scan

    def sense(self) -> tuple[float, float, np.ndarray]:
        """What the modules read of :meth:`observe` at the current time, without making the
        :class:`Observation`: ``(dest_bearing, d_o, landmark_bearings)`` (the same values, and
        the same noise whichever of the two is called first)."""
        _, bearing, d_o = self._sensors()
        return float(bearing[0]), d_o, bearing[1:]

    def sense_all(self) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`sense` and every sensor besides: ``(dest_bearing, d_o, landmark_bearings,
        ir, wheels)`` (every IR ray, read-only; the executed wheel velocities of the last
        step), the fields of a module's ``Percept`` after its time; no draw of its own."""
        ir, bearing, d_o = self._sensors()
        return float(bearing[0]), d_o, bearing[1:], ir, np.array((self._wl, self._wr))

    def observe(self) -> Observation:
        """The full sensor model at the current time (cached until the next step/reset).

        Returns
        -------
        Observation
        """
        if self._obs_tick == self._tick:
            return self._obs
        ir, bearing, _ = self._sensors()
        wheels = np.array((self._wl, self._wr))
        wheels.flags.writeable = False
        obs = Observation(self._k * self._dt, ir, float(bearing[0]), bearing[1:], wheels)
        self._obs, self._obs_tick = obs, self._tick
        return obs
