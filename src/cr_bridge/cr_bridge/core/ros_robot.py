"""A differential-drive robot on the ROS graph read as the Cyber Rodent: the robot adapter's core.

The adapter (``ros2 run cr_bridge robot``, :mod:`cr_bridge.robot_node`) drives a robot that
is already on the ROS graph (its ``odom``, ``scan`` and ``cmd_vel``) by its profile
(:mod:`cr_sim.core.profile`). What it computes is here, without rclpy or message types
(messages arrive as arrays, :mod:`cr_bridge.conversions`):

* :class:`SectorReader`: the scan read as the profile's sectors (the seven IR rays of the
  Cyber Rodent, or any others), and the scan's range in one bearing (rule ``range``);
* :class:`RobotReader`: the bridge's :class:`~cr_bridge.core.episode.Reading` of the latest
  scan, odometry twist and camera blobs, for the bridge's episode core;
* :func:`episode_rules`: the episode core's rules from the profile (reached by the
  destination's apparent width or its range, collision from the sectors, time limit, wander);
* :class:`Freshness`: which inputs are stale (older than the profile's ``stale_timeout``);
* :class:`Lockstep`: with a robot that waits for its controller (our simulator's and the Husky
  world's lockstep), which frame to read and which frames wait for the arbiter's decision;
* :func:`choose_cmd_vel_type`: Twist or TwistStamped, from the parameter or from the types of
  the robot's ``cmd_vel`` subscribers on the graph;
* :func:`scaled_wander`: the simulator's wander to the next start at the profile's size;
* :func:`robot_topic`, :func:`clashes`: the robot's topic names (absolute) and the check that
  none of them is one of the interface's;
* :func:`scaled_arena`: the arena file's layout at the profile's size.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
import math

from clis_base.instants import TOL, DecisionClock
from clis_base.params import ConfigError, build
from cr_sim.core.arena import Arena, Box, scaled_arena  # noqa: F401 - its users' one import
from cr_sim.core.profile import RobotProfile, ScanSpec, Topics
from cr_sim.core.robot import twist_to_wheels
from cr_sim.core.sim import EpisodeParams
from cr_sim.core.wander import WanderParams
import numpy as np

from cr_bridge.core.episode import ContactParams, Reading

__all__ = [
    'CMD_VEL_MSG_TYPES', 'ROBOT_TOPICS', 'INTERFACE_TOPICS', 'Scan', 'SectorReader',
    'RobotReader', 'EpisodeRules', 'episode_rules', 'Freshness', 'Lockstep',
    'choose_cmd_vel_type', 'scaled_wander',
    'robot_topic', 'clashes', 'finite_or_zero', 'scaled_arena',
]

#: The ROS type names of cmd_vel's two message types, and the names the profile and the node's
#: ``cmd_vel_type`` give them.
CMD_VEL_MSG_TYPES = {'geometry_msgs/msg/Twist': 'Twist',
                     'geometry_msgs/msg/TwistStamped': 'TwistStamped'}
#: The robot's topics the node uses (keys of the profile's ``topics``).
ROBOT_TOPICS = ('odom', 'scan', 'cmd_vel')
#: The interface's relative topics in the node's namespace (docs/robot.md#topics), with
#: ``cmd_vel``, which the graph's arbiter publishes beside ``wheels_cmd``: none may be a robot
#: topic.
INTERFACE_TOPICS = ('ir', 'ir_ranges', 'camera', 'wheels', 'reward', 'episode', 'odom', 'arena',
                    'markers', 'wheels_cmd', 'cmd_vel')


@dataclass(frozen=True)
class Scan:
    """A sensor_msgs/LaserScan as arrays.

    Attributes
    ----------
    t : float
        Its stamp [s].
    angle_min, angle_increment : float
        Ray ``i`` points at ``angle_min + i * angle_increment`` in the scanner's frame [rad].
    range_min, range_max : float
        A range outside ``[range_min, range_max]`` (or not finite) is no return [m].
    ranges : np.ndarray, shape (n_rays,)
    """

    t: float
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class SectorReader:
    """The scan read as the profile's sectors (:mod:`cr_sim.core.profile`, "Sectors").

    A sector reads the nearest valid return of the rays whose direction lies within its
    width; with none there (a sector narrower than the rays' spacing, ``width_deg`` 0) the one
    ray nearest its centre if that one is within half a spacing. A valid return is finite and
    within the scan's ``[range_min, range_max]``; it is measured from the body surface
    (``body.radius`` subtracted when ``scan.from_surface`` is false; at least 0) and cut to the
    profile's ``scan.range_max``, which a sector without a valid return reads.

    Parameters
    ----------
    spec : ScanSpec
        The profile's section ``scan``.
    radius : float
        The body's radius [m].
    """

    def __init__(self, spec: ScanSpec, radius: float) -> None:
        self.centres = np.radians(np.asarray(spec.angles_deg, dtype=np.float64))
        self.half = 0.5 * np.radians(np.array([s.width_deg for s in spec.sectors],
                                              dtype=np.float64))
        self.yaw = math.radians(spec.yaw_deg)
        self.offset = 0.0 if spec.from_surface else float(radius)
        self.range_max = float(spec.range_max)
        self._key: tuple[int, float, float] | None = None
        self._mask = np.zeros((len(self.centres), 0), dtype=bool)
        self._dirs = np.zeros(0)

    @property
    def angles(self) -> np.ndarray:
        """The sectors' centre directions from the heading [rad], shape (n_sectors,)."""
        return self.centres.copy()

    def _geometry(self, scan: Scan) -> tuple[np.ndarray, np.ndarray]:
        """The rays' directions from the heading (n_rays,) and which rays each sector reads
        (n_sectors, n_rays), kept while the scan's geometry stays."""
        n = len(scan.ranges)
        key = (n, float(scan.angle_min), float(scan.angle_increment))
        if key != self._key:
            dirs = _wrap(self.yaw + key[1] + key[2] * np.arange(n))
            diff = np.abs(_wrap(dirs[None, :] - self.centres[:, None]))
            mask = diff <= self.half[:, None] + 1e-9
            if n:
                tol = max(0.5 * abs(key[2]), 1e-9) + 1e-9
                nearest = np.argmin(diff, axis=1)
                rows = np.flatnonzero(~mask.any(axis=1)
                                      & (diff[np.arange(len(diff)), nearest] <= tol))
                mask[rows, nearest[rows]] = True
            self._key, self._mask, self._dirs = key, mask, dirs
        return self._dirs, self._mask

    def _surface(self, scan: Scan) -> np.ndarray:
        """Each ray's distance from the body surface [m], inf for no return, shape (n_rays,)."""
        r = np.asarray(scan.ranges, dtype=np.float64)
        with np.errstate(invalid='ignore'):
            valid = np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)
        return np.where(valid, np.maximum(r - self.offset, 0.0), np.inf)

    def read(self, scan: Scan) -> np.ndarray:
        """The sectors' readings [m], shape (n_sectors,), in ``[0, range_max]``."""
        _, mask = self._geometry(scan)
        d = self._surface(scan)
        if not d.size:
            return np.full(len(self.centres), self.range_max)
        near = np.where(mask, d[None, :], np.inf).min(axis=1)
        return np.minimum(near, self.range_max)

    def range_at(self, scan: Scan, bearing: float) -> float:
        """The distance from the body surface of the return in direction ``bearing`` (rad from
        the heading): the ray nearest it, within half a spacing [m]; NaN for no return, a NaN
        bearing or no ray there."""
        dirs, _ = self._geometry(scan)
        if math.isnan(bearing) or not dirs.size:
            return math.nan
        diff = np.abs(_wrap(dirs - bearing))
        k = int(np.argmin(diff))
        if diff[k] > max(0.5 * abs(scan.angle_increment), 1e-9) + 1e-9:
            return math.nan
        d = float(self._surface(scan)[k])
        return d if math.isfinite(d) else math.nan


@dataclass(frozen=True)
class EpisodeRules:
    """The episode core's rules for a robot (:class:`~cr_bridge.core.episode.RobotEpisodes`'
    arguments ``episode``, ``contact``, ``goal_radius``, ``goal_width``)."""

    episode: EpisodeParams
    contact: ContactParams
    goal_radius: float
    goal_width: float
    rule: str


def episode_rules(profile: RobotProfile, dt: float, reward_goal: float,
                  reward_collision: float) -> EpisodeRules:
    """The profile's episode rules with the simulator's rewards.

    * reached, rule ``size``: the destination's apparent width at least
      ``episode.reached.width_deg`` (``goal_width``); rule ``range``: the scan's return in its
      bearing at most ``episode.reached.distance`` from the body (``goal_radius``);
    * collision: a sector below ``episode.collision_range`` (the contact rule ``ir_contact``),
      or one of ``episode.collision_sectors`` (the reading's ``bump``, :class:`RobotReader`);
    * ``time_limit`` and ``wander_time`` of the profile; ``dt``: the node's period.

    Raises
    ------
    ConfigError
        Rule ``size`` by ``area_px`` only: the camera topic carries the blobs' angular widths,
        not their pixel areas.
    """
    spec = profile.episode
    reached = spec.reached
    if reached.rule == 'size' and reached.width_deg <= 0.0:
        raise ConfigError(f'episode.reached.area_px = {reached.area_px!r}: the camera topic '
                          "carries the blobs' bearings and angular widths, not their pixel "
                          'areas: set episode.reached.width_deg above 0')
    episode = build(EpisodeParams, {
        'dt': dt, 'time_limit': spec.time_limit, 'reward_goal': reward_goal,
        'reward_collision': reward_collision, 'contact_tolerance': 0.0,
        'wander_time': spec.wander_time}, where='episode')
    # built directly: collision_range was range-checked by the profile (ContactParams'
    # ir_contact range is the Cyber Rodent's IR range)
    contact = ContactParams(bump=bool(spec.collision_sectors) and spec.collision_range > 0.0,
                            accel_threshold=0.0, ir_contact=spec.collision_range)
    if reached.rule == 'size':
        return EpisodeRules(episode, contact, 0.0, math.radians(reached.width_deg), 'size')
    return EpisodeRules(episode, contact, reached.distance, 0.0, 'range')


def scaled_wander(wander: WanderParams, scale: float, v_max: float) -> WanderParams:
    """The simulator's wander policy (set for the CR's arena) at the profile's size.

    Its speeds, steering and avoidance distance are multiplied by the arena's ``scale``
    (:meth:`~cr_sim.core.profile.ArenaSpec.scale`, by which every length of the layout is
    multiplied), so that a wander of ``episode.wander_time`` moves the robot the same share of
    its arena as the CR's moves it in the paper's (the next start is elsewhere, not where the
    last episode ended); the speeds at most ``v_max`` (the profile's; 0 = no limit).

    Parameters
    ----------
    wander : WanderParams
        The simulator's (``config/sim.yaml``, section ``wander``).
    scale : float
        The layout's scale (1: the CR's arena, the wander as it is).
    v_max : float
        The robot's forward speed limit [m/s].
    """
    def speed(x: float) -> float:
        return min(x * scale, v_max) if v_max > 0.0 else x * scale

    return replace(wander, speed=speed(wander.speed), turn_speed=speed(wander.turn_speed),
                   avoid_distance=wander.avoid_distance * scale,
                   steer_sigma=wander.steer_sigma * scale,
                   steer_max=speed(wander.steer_max))


class RobotReader:
    """The bridge's :class:`Reading` of a robot's latest inputs.

    Parameters
    ----------
    profile : RobotProfile
    rule : str
        ``'size'`` or ``'range'`` (:attr:`EpisodeRules.rule`): with ``'range'`` the reading's
        ``dest_distance`` is the scan's return in the destination's bearing.

    The profile's ``episode.collision_sectors`` (read by :attr:`behind`, None without them)
    are the reading's bump switch: ``bump`` is 1 when one of them reads less than
    ``episode.collision_range``.
    """

    def __init__(self, profile: RobotProfile, rule: str) -> None:
        self.sectors = SectorReader(profile.scan, profile.body.radius)
        more = profile.episode.collision_sectors
        self.behind = (SectorReader(replace(profile.scan, sectors=more), profile.body.radius)
                       if more else None)
        self.collision_range = profile.episode.collision_range
        self.wheel_base = profile.body.wheel_base
        self.rule = rule

    def wheels(self, v: float, omega: float) -> np.ndarray:
        """The wheel speeds of the odometry's twist [m/s], shape (2,)."""
        return np.asarray(twist_to_wheels(float(v), float(omega), self.wheel_base),
                          dtype=np.float64)

    def reading(self, t: float, scan: Scan, v: float, omega: float, bearings: np.ndarray,
                widths: np.ndarray) -> Reading:
        """One reading at ``t``.

        Parameters
        ----------
        t : float
            The robot's clock [s].
        scan : Scan
        v, omega : float
            The odometry's forward speed [m/s] and yaw rate [rad/s].
        bearings, widths : np.ndarray, shape (1 + n_landmarks,)
            The camera's blobs, the destination first: bearing and apparent angular width
            [rad], NaN when not seen.
        """
        bearings = np.asarray(bearings, dtype=np.float64)
        widths = np.asarray(widths, dtype=np.float64)
        dest = float(bearings[0])
        distance = self.sectors.range_at(scan, dest) if self.rule == 'range' else math.nan
        bump = int(self.behind is not None
                   and float(self.behind.read(scan).min()) < self.collision_range)
        return Reading(float(t), self.sectors.read(scan), dest, distance, bearings[1:].copy(),
                       self.wheels(v, omega), bump, (0.0, 0.0, 0.0), float(widths[0]))


class Freshness:
    """Which inputs are stale: never received, older than ``timeout``, or received after
    ``now`` (the clock went back).

    Parameters
    ----------
    names : sequence of str
        The inputs, in the order they are reported.
    timeout : float
        [s] of the clock the times are given in.
    """

    def __init__(self, names: Sequence[str], timeout: float) -> None:
        self.timeout = timeout
        self.last: dict[str, float | None] = dict.fromkeys(names)

    def seen(self, name: str, t: float) -> None:
        """Input ``name`` arrived at ``t``."""
        self.last[name] = t

    def forget(self) -> None:
        """As if nothing had arrived."""
        self.last = dict.fromkeys(self.last)

    def stale(self, now: float) -> tuple[str, ...]:
        """The stale inputs at ``now``, in order (empty: all fresh)."""
        return tuple(k for k, t in self.last.items()
                     if t is None or not -1e-9 <= now - t <= self.timeout + 1e-9)

    def never(self) -> tuple[str, ...]:
        """The inputs that never arrived."""
        return tuple(k for k, t in self.last.items() if t is None)


class Lockstep:
    """A robot that waits for its controller: it holds its clock after each camera frame until
    a ``cmd_vel`` stamped at or after the frame arrives (our simulator's ``node.lockstep`` in
    world mode, the Husky world's ``lockstep``). The adapter then reads each frame once the
    camera's bearings (the detector's, stamped with the image) and the odometry and scan of its
    instant are in, and answers every frame with one ``cmd_vel`` stamped with it: at once, with
    the command in force, unless an episode runs and the frame is a decision instant
    ``t_0 + l tau_i`` of the graph's modules (the instants the module nodes decide at), where
    the arbiter's decision on that frame answers it. Each decision is then made on the frame of
    its instant however loaded the host is, as the native graph's lockstep makes it.

    Parameters
    ----------
    periods : sequence of float
        The modules' decision periods ``tau_i`` [s]; none above 0: every frame of an episode
        waits for a decision.
    dt : float
        The decision grid's tick [s] (the modules' ``episode.dt``).
    """

    def __init__(self, periods: Sequence[float], dt: float) -> None:
        taus = [float(p) for p in periods if p > 0.0]
        self.clock = DecisionClock(taus, dt) if taus else None

    @staticmethod
    def frame(camera: float, odom: float, scan: float, last: float) -> float | None:
        """The instant to read now: the camera's latest stamp once odometry and scan stamped
        at or after it are in and it is after ``last`` (the frame read last); else None."""
        if camera > last + TOL and odom >= camera - TOL and scan >= camera - TOL:
            return camera
        return None

    def waits(self, t: float, t0: float, running: bool) -> bool:
        """Whether frame ``t`` waits for the arbiter's decision (an episode started at ``t0``
        runs and a module decides at ``t``)."""
        if not running:
            return False
        if self.clock is None:
            return True
        k = self.clock.tick(t, t0)
        return k is not None and bool(self.clock.due_at(k))


def choose_cmd_vel_type(setting: str, subscriber_types: Iterable[str]) -> tuple[str | None, str]:
    """cmd_vel's type: ``'Twist'`` or ``'TwistStamped'``, or None and why not yet.

    Parameters
    ----------
    setting : str
        ``'Twist'`` or ``'TwistStamped'`` (taken as is), or ``'auto'``: the type of the robot's
        subscribers.
    subscriber_types : iterable of str
        The ROS types of the subscribers of the robot's cmd_vel on the graph
        (``'geometry_msgs/msg/TwistStamped'``, ...).

    Returns
    -------
    kind : str or None
        None: wait (no subscriber yet, or subscribers that do not say one type).
    why : str
        ``''`` when chosen or when no subscriber is there yet; else what is wrong.
    """
    if setting in CMD_VEL_MSG_TYPES.values():
        return setting, ''
    if setting != 'auto':
        raise ValueError(f'cmd_vel_type {setting!r}: one of auto, Twist, TwistStamped')
    types = sorted(set(subscriber_types))
    if not types:
        return None, ''
    other = [t for t in types if t not in CMD_VEL_MSG_TYPES]
    if other:
        return None, (f'a subscriber of type {other[0]} is neither Twist nor TwistStamped')
    if len(types) > 1:
        return None, 'subscribers of both Twist and TwistStamped'
    return CMD_VEL_MSG_TYPES[types[0]], ''


def robot_topic(topics: Topics, key: str) -> str:
    """The name of the robot's topic ``key`` (``'odom'``, ...): the profile's name under its
    namespace, made absolute (the robot is not in the node's namespace); a private (``~/``)
    name as given."""
    name = topics.resolved(key)
    if name.startswith(('/', '~')):
        return name
    return '/' + name


def clashes(robot: Mapping[str, str], interface: Iterable[str]) -> list[str]:
    """The robot topics whose (resolved) name is also an interface topic's: e.g. ``['odom:
    /odom']``; empty when they are apart (the node in a namespace of its own, or the robot's
    topics remapped)."""
    names = set(interface)
    return [f'{key}: {name}' for key, name in robot.items() if name in names]


def finite_or_zero(u: Sequence[float]) -> np.ndarray:
    """``u`` (shape (2,)) as float64, or zeros if any entry is not finite: the last check
    before a command is sent."""
    a = np.asarray(u, dtype=np.float64).reshape(-1)
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        return np.zeros(2)
    return a
