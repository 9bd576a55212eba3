"""Robot profiles: any differential-drive ROS 2 robot described once, for CLIS to drive it.

A profile is a plain YAML file ``config/robots/NAME.yaml`` in the config folder
(:func:`~clis_base.params.config_dir`, ``$CLIS_CONFIG_DIR``); :func:`load_profile` reads and
validates it into a frozen :class:`RobotProfile`, :func:`PROFILE_NAMES` lists the folder. It is
not a ROS parameter file: ``scan.sectors`` is a list of mappings, which ROS parameters cannot
hold, and a profile describes a robot as an arena file describes a layout (data a node takes by
name). Every value is range-checked at load (the fields' ``param`` declarations); a bad one
raises :class:`~clis_base.params.ConfigError` naming the profile, the dotted key and its
allowed range, e.g. ``profile husky: camera.hfov_deg = 400.0 is out of range: must be in
[1, 360]``.

Sections (the keys, units and ranges are the fields below; ``config/robots/cr.yaml`` comments
every one):

* ``body``: the robot as a disc of ``radius`` on two wheels ``wheel_base`` apart, its speed
  limits (``v_max``, ``omega_max``) and, where meaningful, each wheel's (``v_wheel_max``);
* ``topics``: the standard topics and their names: ``cmd_vel`` (geometry_msgs Twist or
  TwistStamped: ``cmd_vel_type`` ``auto`` takes the type of the robot's subscriber on the
  graph), ``odom`` (nav_msgs/Odometry), ``scan`` (sensor_msgs/LaserScan), ``image``
  (sensor_msgs/Image) and ``camera_info`` ('' = none: the camera section's field of view), all
  under ``namespace``;
* ``scan``: the angular sectors the scan is read as (the Cyber Rodent's seven IR rays are seven
  sectors, below) and ``range_max``, what "nothing within range" reads;
* ``camera``: a forward-looking ``pinhole`` or an omni-directional camera's ``panoramic``
  strip (the models of :mod:`cr_sim.core.camera`: :meth:`CameraSpec.camera_model`);
* ``colours``: the destination's and each landmark's colour, a colour name (:data:`COLOUR_NAMES`)
  or an explicit HSV box (:class:`HsvRange`, the blob detector's ``ColourRange``);
* ``episode``: when the destination is reached (its blob's apparent size, or its range on the
  scan), the collision range on the scan (the sectors of ``scan``, and the
  ``collision_sectors`` the modules do not read, e.g. behind the robot), the time limit, the
  stale-input timeout and the wander to the next start;
* ``arena``: the arena file and the size its layout is scaled to.

Sectors
-------
A sector ``{angle_deg, width_deg}`` is centred on the direction ``angle_deg`` from the robot's
heading, counter-clockwise positive (left > 0), as the simulator's ``sensors.ir_angles_deg``.
It reads the nearest valid return of the scan's rays whose direction lies within
``angle_deg +- width_deg / 2``; ``width_deg = 0`` reads the one ray nearest ``angle_deg``. A
ray ``i`` of a LaserScan points at ``scan.yaw_deg + angle_min + i * angle_increment`` from the
heading (``yaw_deg``: the scanner's mounting yaw). A reading is a distance from the body's
surface: with ``scan.from_surface`` false the scan measures from the robot's centre and
``body.radius`` is subtracted. Readings are cut to ``scan.range_max``, which a sector with no
return within it reads (the Cyber Rodent's IR range).

Pure: no rclpy, no message types; the node that drives a robot by its profile reads these.
"""

from __future__ import annotations

from collections.abc import Mapping
import math
import os
from pathlib import Path
import re
from typing import Any

from clis_base.params import ConfigError, build, config_dir, dataclass, load_yaml, param

from cr_sim.core.arena import ArenaError, load_arena
from cr_sim.core.camera import MAX_PIXELS, Panoramic, Pinhole
from cr_sim.core.render import COLOURS

__all__ = [
    'ROBOTS_DIR', 'COLOUR_NAMES', 'CMD_VEL_TYPES', 'CAMERA_MODELS', 'REACHED_RULES', 'Body',
    'Topics', 'Sector', 'ScanSpec', 'CameraSpec', 'HsvRange', 'ColourSpec', 'Colours', 'Reached',
    'EpisodeSpec', 'ArenaSpec', 'RobotProfile', 'PROFILE_NAMES', 'profile_path', 'load_profile',
]

#: The folder of the profiles in :func:`~clis_base.params.config_dir`.
ROBOTS_DIR = 'robots'
#: The colour names a profile may give: those of an arena file (:data:`cr_sim.core.render.
#: COLOURS`), the names the blob detector has a range for (``clis_modules.core.blobs.
#: NAMED_RANGES``, which ``test/test_robot_profiles.py`` holds equal to these).
COLOUR_NAMES: tuple[str, ...] = tuple(COLOURS)
#: ``topics.cmd_vel_type``: ``auto`` = the type of the robot's ``cmd_vel`` subscriber.
CMD_VEL_TYPES = ('auto', 'Twist', 'TwistStamped')
#: ``camera.model``: :class:`~cr_sim.core.camera.Pinhole`, :class:`~cr_sim.core.camera.Panoramic`.
CAMERA_MODELS = ('pinhole', 'panoramic')
#: ``episode.reached.rule``: the destination's apparent size, or its range on the scan.
REACHED_RULES = ('size', 'range')

#: A ROS topic name: relative, absolute (/) or private (~/); tokens of letters, digits and _.
_TOPIC = re.compile(r'(~/|/)?[A-Za-z_]\w*(/[A-Za-z_]\w*)*')
#: A namespace: a topic name that is not private.
_NAMESPACE = re.compile(r'/?[A-Za-z_]\w*(/[A-Za-z_]\w*)*')
#: HSV keys of an explicit colour.
_HSV_KEYS = ('hue_lo', 'hue_hi', 'sat_lo', 'sat_hi', 'val_lo', 'val_hi')


@dataclass(frozen=True)
class Body:
    """The robot as a disc on two wheels, and its speed limits (section ``body``)."""

    radius: float = param(0.01, 2.0, doc='radius of the disc that holds the body (a '
                          'rectangular base: its circumscribed disc) [m]')
    wheel_base: float = param(0.01, 2.0, doc='distance between the wheels (skid steer: the '
                              'track of the kinematic model) [m]')
    v_max: float = param(0.01, 10.0, doc='top forward speed sent on cmd_vel [m/s]')
    omega_max: float = param(0.01, 50.0, doc='top yaw rate sent on cmd_vel [rad/s]')
    v_wheel_max: float = param(0.0, 10.0, doc='limit of each wheel [m/s]; 0 = none (the base '
                               'controller limits its wheels)')

    def validate(self) -> None:
        """The twist limits are within what the wheels can do, when they have a limit."""
        if self.v_wheel_max <= 0.0:
            return
        if self.v_max > self.v_wheel_max:
            raise ConfigError(f'body.v_max = {self.v_max!r} exceeds body.v_wheel_max = '
                              f'{self.v_wheel_max!r}: the wheels cannot go faster')
        turn = 2.0 * self.v_wheel_max / self.wheel_base
        if self.omega_max > turn * (1.0 + 1e-9):
            raise ConfigError(f'body.omega_max = {self.omega_max!r} exceeds 2 v_wheel_max / '
                              f'wheel_base = {turn:.6g} rad/s: the wheels cannot turn faster')


@dataclass(frozen=True)
class Topics:
    """The standard topics and their names (section ``topics``); every one is remappable."""

    cmd_vel: str = param(doc='the command: geometry_msgs Twist or TwistStamped')
    cmd_vel_type: str = param(choices=CMD_VEL_TYPES, doc="cmd_vel's type; 'auto': the type "
                              "of the robot's subscriber on the graph")
    odom: str = param(doc='nav_msgs/Odometry of the base')
    scan: str = param(doc='sensor_msgs/LaserScan read as the sectors of section scan')
    image: str = param(doc='sensor_msgs/Image, rgb8, bgr8 or rgba8')
    camera_info: str = param(doc="sensor_msgs/CameraInfo of the image; '' = none: the "
                             "camera section's field of view")
    namespace: str = param(doc="the relative names are under it; '' = none")

    def validate(self) -> None:
        """Each name is a ROS topic name; only camera_info and namespace may be empty."""
        for key in ('cmd_vel', 'odom', 'scan', 'image', 'camera_info'):
            name = getattr(self, key)
            if key == 'camera_info' and name == '':
                continue
            if not _TOPIC.fullmatch(name):
                raise ConfigError(f'topics.{key} = {name!r} is not a topic name: tokens of '
                                  'letters, digits and _ (not starting with a digit) joined by '
                                  '/, optionally after / or ~/')
        if self.namespace and not _NAMESPACE.fullmatch(self.namespace.rstrip('/')):
            raise ConfigError(f'topics.namespace = {self.namespace!r} is not a namespace: '
                              "'' or tokens of letters, digits and _ joined by /")

    def resolved(self, key: str) -> str:
        """The name of topic ``key`` (``'scan'``, ...) with a relative one under
        ``namespace`` (``''`` for an empty ``camera_info``)."""
        name = getattr(self, key)
        if not name or not self.namespace or name.startswith(('/', '~')):
            return name
        return '/' + self.namespace.strip('/') + '/' + name


@dataclass(frozen=True)
class Sector:
    """One direction the scan is read in (module docstring)."""

    angle_deg: float = param(-180.0, 180.0, doc='centre direction from the heading, '
                             'counter-clockwise > 0 [deg]')
    width_deg: float = param(0.0, 360.0, doc='angular width: the nearest return in it; 0 = '
                             'the one ray nearest angle_deg [deg]')


@dataclass(frozen=True)
class ScanSpec:
    """How the LaserScan is read (section ``scan``)."""

    sectors: tuple[Sector, ...] = param(doc='the directions read, in the order the modules '
                                        'take them (the CR: right to left)')
    range_max: float = param(0.01, 100.0, doc='what a sector with no return within it '
                             'reads; longer readings are cut to it (the IR range) [m]')
    yaw_deg: float = param(-180.0, 180.0, doc="direction of the scan's angle 0 from the "
                           "heading (the scanner's mounting yaw) [deg]")
    from_surface: bool = param(doc='the ranges are from the body surface (the CR IR); '
                               'false: from the centre, body.radius is subtracted')

    def validate(self) -> None:
        """One sector at least, at most 360."""
        if not 1 <= len(self.sectors) <= 360:
            raise ConfigError(f'scan.sectors has {len(self.sectors)} sectors: must have 1 to '
                              '360')

    @property
    def angles_deg(self) -> tuple[float, ...]:
        """The sectors' centre directions [deg], in order."""
        return tuple(s.angle_deg for s in self.sectors)


@dataclass(frozen=True)
class CameraSpec:
    """The camera (section ``camera``): its model, field of view, size and mounting."""

    model: str = param(choices=CAMERA_MODELS, doc="'pinhole': forward-looking; 'panoramic': "
                       "an omni-directional camera's unrolled strip")
    hfov_deg: float = param(1, 360, doc='horizontal field of view (pinhole below 180, '
                            'panoramic 360) [deg]')
    width: int = param(1, MAX_PIXELS, doc='image width [px]')
    height: int = param(1, MAX_PIXELS, doc='image height [px]')
    yaw_deg: float = param(-180.0, 180.0, doc='mounting yaw: bearing of the optical axis '
                           '(panoramic: added to bearing0_deg) [deg]')
    bearing0_deg: float = param(-180.0, 180.0, doc="panoramic: bearing of column 0's centre "
                                '(180: the heading at the middle column) [deg]')
    min_blob_px: int = param(1, 1_000_000, doc='pixels of the smallest blob that is seen')

    def validate(self) -> None:
        """A pinhole sees less than a half turn; a panoramic strip the full turn."""
        if self.model == 'pinhole' and self.hfov_deg >= 180.0:
            raise ConfigError(f'camera.hfov_deg = {self.hfov_deg!r} is out of range for a '
                              'pinhole camera: must be below 180')
        if self.model == 'panoramic' and self.hfov_deg != 360.0:
            raise ConfigError(f'camera.hfov_deg = {self.hfov_deg!r} must be 360 for a '
                              'panoramic camera')

    def camera_model(self) -> Pinhole | Panoramic:
        """The camera model of this field of view (a robot without camera_info).

        Returns
        -------
        Pinhole or Panoramic
            ``Pinhole.from_fov(width, height, hfov, yaw)``, or ``Panoramic(width, height,
            bearing0 + yaw)`` (wrapped to [-pi, pi]). With camera_info the node takes its
            intrinsics instead: ``Pinhole.from_k(width, height, k, yaw)``.
        """
        yaw = math.radians(self.yaw_deg)
        if self.model == 'pinhole':
            return Pinhole.from_fov(self.width, self.height, math.radians(self.hfov_deg), yaw)
        b0 = math.remainder(math.radians(self.bearing0_deg) + yaw, 2.0 * math.pi)
        return Panoramic(self.width, self.height, bearing0=max(-math.pi, min(math.pi, b0)))


@dataclass(frozen=True)
class HsvRange:
    """An explicit colour: a box in HSV (the blob detector's ``ColourRange``)."""

    hue_lo: float = param(0.0, 360.0, doc='hue lower bound; above hue_hi the range wraps '
                          'through 0 (red) [deg]')
    hue_hi: float = param(0.0, 360.0, doc='hue upper bound [deg]')
    sat_lo: float = param(0.0, 1.0, doc='saturation lower bound')
    sat_hi: float = param(0.0, 1.0, doc='saturation upper bound')
    val_lo: float = param(0.0, 1.0, doc='value (brightness) lower bound')
    val_hi: float = param(0.0, 1.0, doc='value (brightness) upper bound')

    def validate(self) -> None:
        """The saturation and value bounds are ordered."""
        for key in ('sat', 'val'):
            lo, hi = getattr(self, f'{key}_lo'), getattr(self, f'{key}_hi')
            if lo > hi:
                raise ValueError(f'{key}_lo = {lo!r} exceeds {key}_hi = {hi!r}')


@dataclass(frozen=True)
class ColourSpec:
    """A target's colour: a name of :data:`COLOUR_NAMES` (``hsv`` None), or an explicit
    :class:`HsvRange` (``name`` '')."""

    name: str
    hsv: HsvRange | None

    @classmethod
    def parse(cls, value: Any, where: str) -> ColourSpec:
        """A colour name or a mapping of the six HSV bounds; ConfigError naming ``where``."""
        if isinstance(value, str):
            if value not in COLOUR_NAMES:
                raise ConfigError(f'{where} = {value!r} is not a colour name: must be one of '
                                  + ', '.join(COLOUR_NAMES) + ', or a mapping of '
                                  + ', '.join(_HSV_KEYS))
            return cls(value, None)
        if isinstance(value, Mapping):
            return cls('', build(HsvRange, value, where=where))
        raise ConfigError(f'{where} = {value!r} must be a colour name or a mapping of '
                          + ', '.join(_HSV_KEYS))


@dataclass(frozen=True)
class Colours:
    """The destination's and each landmark's colour (section ``colours``).

    Attributes
    ----------
    destination : ColourSpec
    landmarks : tuple of (str, ColourSpec)
        Landmark name and colour, in the file's order; the names are the arena's landmarks.
    """

    destination: ColourSpec
    landmarks: tuple[tuple[str, ColourSpec], ...]

    @classmethod
    def __build_params__(cls, mapping: Any, where: str) -> Colours:
        """Build from ``{destination: COLOUR, landmarks: {NAME: COLOUR, ...}}``, a COLOUR
        as :meth:`ColourSpec.parse` takes it; ConfigError naming the key."""
        keys = ('destination', 'landmarks')
        if not isinstance(mapping, Mapping):
            raise ConfigError(f'{where} must be a mapping with keys ' + ', '.join(keys))
        unknown = sorted(set(mapping) - set(keys))
        if unknown:
            raise ConfigError(f'unknown key {where}.{unknown[0]}; allowed keys: '
                              + ', '.join(keys))
        for key, doc in zip(keys, ('a colour name or HSV bounds', 'landmark name: colour')):
            if key not in mapping:
                raise ConfigError(f'missing key {where}.{key} ({doc})')
        marks = mapping['landmarks']
        if not isinstance(marks, Mapping):
            raise ConfigError(f'{where}.landmarks must be a mapping landmark name: colour')
        landmarks = []
        for name, value in marks.items():
            if not isinstance(name, str) or not name:
                raise ConfigError(f'{where}.landmarks: name {name!r} must be a non-empty '
                                  'string')
            landmarks.append((name, ColourSpec.parse(value, f'{where}.landmarks.{name}')))
        return cls(ColourSpec.parse(mapping['destination'], f'{where}.destination'),
                   tuple(landmarks))

    @property
    def landmark_names(self) -> tuple[str, ...]:
        """The landmarks' names, in order."""
        return tuple(name for name, _ in self.landmarks)

    def of(self, target: str) -> ColourSpec:
        """The colour of ``'destination'`` or of a landmark; KeyError naming the known ones."""
        if target == 'destination':
            return self.destination
        for name, spec in self.landmarks:
            if name == target:
                return spec
        raise KeyError(f'no colour for {target!r}; known: destination, '
                       + ', '.join(self.landmark_names))


@dataclass(frozen=True)
class Reached:
    """When the destination is reached (section ``episode.reached``)."""

    rule: str = param(choices=REACHED_RULES, doc="'size': by its blob's apparent size; "
                      "'range': by the scan's return in its bearing")
    width_deg: float = param(0.0, 360.0, doc='size: the blob at least this wide; 0 = not '
                             'used [deg]')
    area_px: int = param(0, 10_000_000_000, doc='size: the blob at least this many pixels; '
                         '0 = not used [px]')
    distance: float = param(0.0, 100.0, doc='range: the return at most this far from the '
                            'body surface [m]')

    def validate(self) -> None:
        """The chosen rule has a threshold."""
        if self.rule == 'size' and self.width_deg <= 0.0 and self.area_px <= 0:
            raise ValueError("rule 'size' needs width_deg or area_px above 0")
        if self.rule == 'range' and self.distance <= 0.0:
            raise ValueError(f"rule 'range' needs distance above 0, got {self.distance!r}")


@dataclass(frozen=True)
class EpisodeSpec:
    """Rewards and episodes from the robot's own sensors (section ``episode``)."""

    reached: Reached = param(doc='section episode.reached')
    collision_range: float = param(0.0, 10.0, doc='a new collision when a sector reads less; '
                                   '0 = none [m]')
    collision_sectors: tuple[Sector, ...] = param(doc='more sectors of the scan for the '
                                                  'collisions only (behind the robot, where '
                                                  'no module looks); [] = none')
    time_limit: float = param(1.0, 3600.0, doc='an episode ends (timeout) after this [s]')
    stale_timeout: float = param(0.01, 10.0, doc='odom, scan or camera older than this: the '
                                 'command is zero [s]')
    wander_time: float = param(0.0, 600.0, doc='the wander to the next start, through '
                               'cmd_vel [s]')


@dataclass(frozen=True)
class ArenaSpec:
    """The arena the robot runs in (section ``arena``)."""

    file: str = param(doc="arena file: a name in the config folder or a path; '' = "
                      'arena.yaml, the CR arena')
    size: float = param(0.0, 1000.0, doc="the floor's longer side the layout is scaled to; "
                        "0 = the file's own [m]")

    def path(self) -> Path:
        """The arena file: a bare name in the config folder, a path as given."""
        if not self.file:
            return config_dir() / 'arena.yaml'
        if '/' in self.file or os.sep in self.file:
            return Path(self.file)
        return config_dir() / self.file

    def scale(self, file_size: float) -> float:
        """Every length of the layout is multiplied by this (``file_size``: the file's
        :attr:`~cr_sim.core.arena.Arena.size` [m]); 1 for ``size`` 0."""
        return 1.0 if self.size == 0.0 else self.size / file_size


@dataclass(frozen=True)
class RobotProfile:
    """One robot, as ``config/robots/NAME.yaml`` describes it (module docstring)."""

    description: str = param(doc='one line: the robot and where it runs')
    simulator: str = param(choices=('', 'cr_sim'), doc="'' = a robot already on the ROS "
                           "graph; 'cr_sim' = our simulator, which clis run --robot ros starts "
                           "as a plain world (its episodes are the robot adapter's)")
    body: Body = param(doc='section body')
    topics: Topics = param(doc='section topics')
    scan: ScanSpec = param(doc='section scan')
    camera: CameraSpec = param(doc='section camera')
    colours: Colours = param(doc='section colours')
    episode: EpisodeSpec = param(doc='section episode')
    arena: ArenaSpec = param(doc='section arena')

    def validate(self) -> None:
        """The collision range is below what an empty sector reads."""
        c = self.episode.collision_range
        if c >= self.scan.range_max:
            raise ConfigError(f'episode.collision_range = {c!r} is not below scan.range_max = '
                              f'{self.scan.range_max!r}: every sector would read a collision')


def PROFILE_NAMES() -> tuple[str, ...]:  # noqa: N802 - the list of a folder, named as one
    """The profiles in ``config/robots`` of the config folder, sorted (file names without
    ``.yaml``)."""
    folder = config_dir() / ROBOTS_DIR
    return tuple(sorted(p.stem for p in folder.glob('*.yaml'))) if folder.is_dir() else ()


def profile_path(name_or_path: str | os.PathLike) -> tuple[str, Path]:
    """The name and the file of a profile.

    Parameters
    ----------
    name_or_path : str or path-like
        A name of :func:`PROFILE_NAMES`, or a file (a path with a ``/`` or ending in
        ``.yaml``), whose name is its stem.

    Raises
    ------
    ConfigError
        An unknown name, listing the known ones.
    """
    text = os.fspath(name_or_path)
    if text.endswith(('.yaml', '.yml')) or '/' in text or os.sep in text:
        return Path(text).stem, Path(text)
    names = PROFILE_NAMES()
    if text not in names:
        raise ConfigError(f'unknown robot profile {text!r}: known profiles: '
                          + (', '.join(names) or 'none')
                          + f' (the files {config_dir() / ROBOTS_DIR}/NAME.yaml)')
    return text, config_dir() / ROBOTS_DIR / f'{text}.yaml'


def _check_arena(profile: RobotProfile) -> None:
    """The robot fits the scaled layout; the colours name the arena's landmarks."""
    spec = profile.arena
    arena = load_arena(spec.path(), robot_radius=0.0)
    scale = spec.scale(arena.size)
    radius = profile.body.radius / scale
    try:
        arena.check(radius)
    except ArenaError as exc:
        raise ConfigError(f'arena.size = {spec.size!r}: the layout scaled by {scale:.4g} has '
                          f'no room for body.radius = {profile.body.radius!r} ({radius:.4g} m '
                          f'in the file): {exc}') from None
    names = tuple(mark.name for mark in arena.landmarks)
    if sorted(profile.colours.landmark_names) != sorted(names):
        raise ConfigError(f'colours.landmarks names {", ".join(profile.colours.landmark_names)}'
                          f': must be the landmarks of {spec.path()}: ' + ', '.join(names))


def load_profile(name_or_path: str | os.PathLike) -> RobotProfile:
    """Read and validate a robot profile.

    Parameters
    ----------
    name_or_path : str or path-like
        A name of :func:`PROFILE_NAMES` (``config/robots/NAME.yaml`` in the config folder) or
        a profile file.

    Returns
    -------
    RobotProfile

    Raises
    ------
    ConfigError
        ``profile NAME: KEY = VALUE ...`` for a missing, unknown or out-of-range key, with the
        file; an unknown name listing the known ones; a missing or malformed file; an arena
        the robot does not fit or whose landmarks the colours do not name.
    """
    name, path = profile_path(name_or_path)
    data = load_yaml(path)
    try:
        profile = build(RobotProfile, data)
        _check_arena(profile)
    except ConfigError as exc:
        raise ConfigError(f'profile {name}: {exc} ({path})') from None
    return profile
