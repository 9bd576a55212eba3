"""Clearpath's Husky in a PyBullet world: the CLIS arena, the drive, odometry, a lidar, a camera.

Pure PyBullet and numpy (no rclpy, no message types): :class:`HuskyWorld` is the world that
``ros2 run husky_world world`` (:mod:`husky_world.world_node`) wraps as a ROS 2 node.

The arena
---------
The project's layout (``config/arena.yaml``, read by :func:`cr_sim.core.arena.load_arena`),
every position and size scaled by ``size / arena.size`` about the layout's origin (the Cyber
Rodent's 3 m arena to 10 m by default, as ``config/robots/husky.yaml``'s ``arena.size``):

* the floor: a neutral grey box whose top is z = 0;
* the walls: grey boxes :data:`WALL_HEIGHT` high, :data:`WALL_THICKNESS` thick, outside the
  floor (their inner faces are the floor's border);
* the short obstacles: boxes :data:`SHORT_HEIGHT` high (above the lidar, so the scan sees
  them; below the camera, which sees over them); the tall ones :data:`TALL_HEIGHT` high (they
  hide what stands behind them from the camera);
* the landmarks: posts :data:`POST_HEIGHT` high of the layout's target radius (0.04 m) scaled,
  each at its layout position (on a wall: half in it) in its colour name's flat, saturated
  RGB (:data:`COLOURS`); the destination a magenta post. Posts are markers: they have no
  collision shape, so the robot and the lidar pass through them (the simulator's IR does not
  see them either).

The robot
---------
``husky/husky.urdf`` of ``pybullet_data`` (wheel cylinders as real cylinders). Its four wheel
joints are driven as a skid-steer base controller drives them (diff_drive_controller): a
command ``(v, omega)`` is clipped to ``v_max``, ``omega_max``, turned into the left and right
wheel speeds by the URDF's track and wheel radius (times ``wheel_separation_multiplier``) and
given to both wheels of a side under ``VELOCITY_CONTROL`` with the torque limit
``wheel_torque``. A command with NaN or inf is taken as zero. No command for ``cmd_timeout``
seconds of sim time sets the wheels to zero. The wheels' friction along their axle is
``lateral_friction_ratio`` times their rolling-direction friction: with the URDF's isotropic
friction the body resists turning in place and a commanded 0.3 rad/s turns at 0.06 rad/s;
with the default 0.1 it turns at about 0.9 times the command (as a skid-steer robot on
its tyres does).

Sensors
-------
* odometry as diff_drive_controller computes it: the wheels' joint velocities integrated at
  every physics step, starting at ``(0, 0, 0)``; never the body's true pose (:meth:`pose`,
  for tests);
* a lidar at the robot's centre :data:`LIDAR_HEIGHT` above the ground (frame ``lidar``):
  ``scan_rays`` rays over ``scan_fov_deg`` centred on the heading, by ``rayTestBatch``, that
  see the floor, walls and obstacles, never the robot; ``inf`` where nothing is within
  ``range_max``;
* a forward pinhole camera at the front top of the chassis (:data:`CAMERA_XZ`), horizontal
  field of view ``hfov_deg``, ``width`` x ``height`` RGB, rendered by PyBullet's TinyRenderer
  without shadows, lit mostly by ambient light so that each post keeps its hue and saturation
  (:data:`LIGHT`). Square pixels, ``fx = fy = (width / 2) / tan(hfov / 2)``; the principal
  point is where TinyRenderer puts the optical axis, ``(width / 2, height / 2 - 1)`` in the ROS
  convention (pixel ``i``'s value is the scene at ``i``): it samples each pixel at a corner.
  The robot's own meshes are not drawn (transparent): the camera, at the front looking
  forward, never sees them (the same image, :meth:`HuskyWorld.show_robot`), and TinyRenderer
  rasterises every triangle in view or not: they were two thirds of a 160 x 120 frame's cost.

Time: the physics runs at :data:`PHYSICS_HZ` (``setTimeStep(1 / 240)``); :attr:`HuskyWorld.t`
is the sim time of the state, ``steps / 240``, from 0.
"""

from __future__ import annotations

import contextlib
import ctypes
from dataclasses import dataclass, field, fields
import math
import os
import sys
from typing import Any, NamedTuple

from clis_base.params import ConfigError, param
from cr_sim.core.arena import Arena, load_arena
import numpy as np
import pybullet
import pybullet_data
from pybullet_utils import bullet_client

__all__ = [
    'PHYSICS_HZ', 'COLOURS', 'HUSKY_RADIUS', 'LIDAR_HEIGHT', 'CAMERA_XZ', 'WALL_HEIGHT',
    'WALL_THICKNESS', 'SHORT_HEIGHT', 'TALL_HEIGHT', 'POST_HEIGHT', 'TARGET_RADIUS', 'LIGHT',
    'RANGE_MIN', 'HuskyWorldParams',
    'Odom', 'Intrinsics', 'Every', 'HuskyWorld', 'colour_rgb', 'opt', 'param_fields',
]

#: Physics rate [Hz of sim time].
PHYSICS_HZ = 240
#: Flat, saturated RGB of the colour names of the arena file and the robot profiles.
COLOURS: dict[str, tuple[int, int, int]] = {
    'red': (255, 0, 0), 'orange': (255, 128, 0), 'yellow': (255, 255, 0),
    'green': (0, 255, 0), 'cyan': (0, 255, 255), 'blue': (0, 0, 255),
    'purple': (128, 0, 255), 'magenta': (255, 0, 255),
}
#: The destination post's colour.
DESTINATION_COLOUR = 'magenta'
#: [m] the disc around the Husky's footprint (config/robots/husky.yaml body.radius): a start
#: pose must leave it free.
HUSKY_RADIUS = 0.6
#: [m] the lidar's height above the ground (on the top plate, at the robot's centre).
LIDAR_HEIGHT = 0.42
#: [m] the camera's position in the robot's frame (x forward, z up from the ground): the front
#: top of the chassis (the chassis ends at x = 0.50 m, its top plate is 0.40 m high).
CAMERA_XZ = (0.45, 0.55)
#: [m] heights and thickness of the arena's boxes, and the posts' height.
WALL_HEIGHT = 0.8
WALL_THICKNESS = 0.2
SHORT_HEIGHT = 0.5
TALL_HEIGHT = 1.5
POST_HEIGHT = 1.0
#: [m] the layout's target radius (the Cyber Rodent simulator's camera posts), scaled with it.
TARGET_RADIUS = 0.04
#: Greys (RGB 0-1) of the floor, the walls, the short and the tall obstacles.
GREYS = {'floor': 0.5, 'wall': 0.75, 'short': 0.62, 'tall': 0.35}
#: TinyRenderer lighting: mostly ambient (a flat colour stays flat: hue and saturation are
#: kept, only the value varies by at most the diffuse part), no specular highlight (white).
LIGHT = {'lightDirection': (0.4, 0.3, 1.0), 'lightColor': (1.0, 1.0, 1.0),
         'lightAmbientCoeff': 0.6, 'lightDiffuseCoeff': 0.4, 'lightSpecularCoeff': 0.0}
#: [m] the camera's near and far planes.
NEAR, FAR = 0.05, 100.0
#: [m] the lidar's minimum range (LaserScan.range_min; a nearer return reads -inf, REP 117).
RANGE_MIN = 0.1
#: Collision filter groups: the world's bodies, and the robot's links (the lidar's rays test
#: the world's group only).
WORLD_GROUP, ROBOT_GROUP = 0x1, 0x2
_WHEELS = ('front_left_wheel', 'front_right_wheel', 'rear_left_wheel', 'rear_right_wheel')


def opt(default: Any, lo: float | None = None, hi: float | None = None, *, doc: str,
        choices: tuple | None = None) -> Any:
    """A parameter field with a default and its allowed range (:func:`clis_base.params.param`
    with a default: the example's parameters live in code, not in a config file)."""
    return field(default=default, metadata=param(lo, hi, doc=doc, choices=choices).metadata)


def param_fields(cls: type) -> list[tuple[str, Any, str]]:
    """``(name, default, 'range; doc')`` of every field of a parameter dataclass (``--help``)."""
    out = []
    for f in fields(cls):
        m = f.metadata
        if m.get('choices') is not None:
            rng = 'one of ' + ', '.join(repr(c) for c in m['choices'])
        elif m.get('lo') is not None or m.get('hi') is not None:
            rng = f'[{m.get("lo"):g}, {m.get("hi"):g}]'
        else:
            rng = 'any'
        out.append((f.name, f.default, f'{rng}; {m.get("doc", "")}'))
    return out


@dataclass(frozen=True)
class HuskyWorldParams:
    """The world's parameters (the node declares each as a ROS parameter of the same name)."""

    arena_file: str = opt('', doc="arena layout file; '' = config/arena.yaml")
    size: float = opt(10.0, 1.0, 100.0, doc="[m] the layout's longer side is scaled to this")
    start: str = opt('A', doc="the layout's start pose to begin at; '' = x, y, yaw")
    x: float = opt(0.0, -100.0, 100.0, doc='[m] start x when start is empty')
    y: float = opt(0.0, -100.0, 100.0, doc='[m] start y when start is empty')
    yaw: float = opt(0.0, -2 * math.pi, 2 * math.pi, doc='[rad] start heading when start is '
                     'empty')
    v_max: float = opt(1.0, 0.0, 2.0, doc='[m/s] |v| of a command is clipped to this')
    omega_max: float = opt(1.0, 0.0, 4.0, doc='[rad/s] |omega| of a command is clipped to this')
    cmd_timeout: float = opt(0.5, 0.01, 10.0, doc='[s sim] no command for this long: wheels '
                             'to zero')
    wheel_torque: float = opt(50.0, 1.0, 1000.0, doc='[N m] torque limit of each wheel motor')
    wheel_separation_multiplier: float = opt(1.0, 0.5, 3.0, doc='the track times this is the '
                                             "drive's wheel separation (skid-steer slip)")
    lateral_friction_ratio: float = opt(0.1, 0.01, 1.0, doc="wheels' friction along the "
                                        'axle / along the rolling direction')
    range_max: float = opt(5.0, 0.5, 100.0, doc="[m] the lidar's range")
    scan_rays: int = opt(360, 2, 3600, doc='rays of a scan')
    scan_fov_deg: float = opt(360.0, 1.0, 360.0, doc="[deg] the scan's field of view, centred "
                              'on the heading')
    width: int = opt(320, 16, 1920, doc='[px] image width')
    height: int = opt(240, 16, 1440, doc='[px] image height')
    hfov_deg: float = opt(90.0, 10.0, 170.0, doc="[deg] the camera's horizontal field of view")


class Odom(NamedTuple):
    """Wheel odometry: pose in the ``odom`` frame (the start pose is the origin) and twist."""

    x: float       # [m]
    y: float       # [m]
    yaw: float     # [rad] in (-pi, pi]
    v: float       # [m/s] forward
    omega: float   # [rad/s] counter-clockwise


class Intrinsics(NamedTuple):
    """Pinhole intrinsics [px] (ROS convention: pixel ``i``'s value is the scene at ``i``)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


class Every:
    """A publication schedule on the physics steps: due at the first step at or after each
    multiple of ``1 / rate`` s of sim time (at 100 Hz on 240 Hz physics: every 2 or 3 steps,
    100 times a second), so that a message is stamped with the time of the state it
    describes."""

    def __init__(self, rate: float) -> None:
        if not 0.0 < rate <= PHYSICS_HZ:
            raise ValueError(f'rate = {rate!r} is out of range: must be in (0, {PHYSICS_HZ}]')
        self.rate = float(rate)
        self.k = 0                     # the next multiple of 1 / rate that is due

    def due(self, step: int) -> bool:
        """Whether a message is due at physics step ``step`` (called once per step, in
        order); if so, the schedule moves on."""
        if step * self.rate < self.k * PHYSICS_HZ - 1e-6:
            return False
        self.k = math.floor(step * self.rate / PHYSICS_HZ + 1e-9) + 1
        return True


def colour_rgb(name: str, where: str) -> tuple[float, float, float]:
    """RGB (0-1) of a colour name of :data:`COLOURS` or ``'#rrggbb'``; ConfigError otherwise."""
    if name in COLOURS:
        return tuple(c / 255.0 for c in COLOURS[name])
    if len(name) == 7 and name.startswith('#'):
        try:
            return tuple(int(name[i:i + 2], 16) / 255.0 for i in (1, 3, 5))
        except ValueError:
            pass
    raise ConfigError(f'{where} = {name!r} is not a colour: must be one of '
                      + ', '.join(COLOURS) + " or '#rrggbb'")


@contextlib.contextmanager
def _quiet_stdout():
    """Silence the C library's stdout (Bullet's URDF importer warns there about every link
    without an inertial, seven for the Husky) for the duration of the block."""
    sys.stdout.flush()
    libc = ctypes.CDLL(None)
    saved = os.dup(1)
    try:
        with open(os.devnull, 'wb') as devnull:
            os.dup2(devnull.fileno(), 1)
            try:
                yield
            finally:
                libc.fflush(None)
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _wrap(angle: float) -> float:
    """``angle`` in (-pi, pi]."""
    return -math.remainder(-angle, 2 * math.pi)


class HuskyWorld:
    """The Husky in the scaled CLIS arena, stepped by hand (module docstring).

    Parameters
    ----------
    params : HuskyWorldParams, optional
        Default: every field's default.
    arena : Arena, optional
        An arena already loaded (``params.arena_file`` is then not read).

    Raises
    ------
    ConfigError
        An unknown start name, a start pose that leaves no room for the robot, an arena file
        that cannot be read, an unknown colour name: naming the key.
    """

    DT = 1.0 / PHYSICS_HZ

    def __init__(self, params: HuskyWorldParams | None = None, arena: Arena | None = None
                 ) -> None:
        self.params = p = params if params is not None else HuskyWorldParams()
        self.arena = arena if arena is not None else load_arena(p.arena_file or None)
        self.scale = p.size / self.arena.size
        self.start_pose = self._start_pose()
        self.steps = 0
        self._odom = np.zeros(3)               # x, y, yaw in the odom frame
        self._twist = (0.0, 0.0)
        self._cmd = (0.0, 0.0)
        self._last_cmd_step: int | None = None  # None: no command in force
        self.rejected = 0                       # non-finite commands
        with _quiet_stdout():                  # connecting prints 'argv[0]='
            self._c = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        try:
            self._build()
        except Exception:
            self.close()
            raise
        self.intrinsics = self._intrinsics()
        self._projection = self._c.computeProjectionMatrixFOV(
            fov=math.degrees(2 * math.atan(0.5 * p.height / self.intrinsics.fy)),
            aspect=p.width / p.height, nearVal=NEAR, farVal=FAR)
        self.scan_angles = self._scan_angles()

    # ------------------------------------------------------------------ construction

    def _start_pose(self) -> tuple[float, float, float]:
        p, a, s = self.params, self.arena, self.scale
        if p.start:
            if p.start not in a.start_names:
                raise ConfigError(f'start = {p.start!r} is not a start of {a.source}: must be '
                                  'one of ' + ', '.join(a.start_names) + " or '' (x, y, yaw)")
            st = a.start(p.start)
            x, y, yaw, key = st.x * s, st.y * s, st.heading, f'start {p.start!r}'
        else:
            x, y, yaw, key = p.x, p.y, p.yaw, 'x, y'
        if a.gap(x / s, y / s, HUSKY_RADIUS / s) < 0.0:
            raise ConfigError(f'{key}: the pose ({x:.3f}, {y:.3f}) leaves no room for the '
                              f'robot (radius {HUSKY_RADIUS} m) in {a.source} scaled to '
                              f'{p.size} m: choose a free spot')
        return x, y, _wrap(yaw)

    def _box(self, lo: tuple[float, float], hi: tuple[float, float], z0: float, z1: float,
             grey: float) -> int:
        c = self._c
        half = (0.5 * (hi[0] - lo[0]), 0.5 * (hi[1] - lo[1]), 0.5 * (z1 - z0))
        centre = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (z0 + z1))
        body = c.createMultiBody(
            0, c.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half),
            c.createVisualShape(pybullet.GEOM_BOX, halfExtents=half,
                                rgbaColor=(grey, grey, grey, 1.0)), centre)
        c.setCollisionFilterGroupMask(body, -1, WORLD_GROUP, WORLD_GROUP | ROBOT_GROUP)
        return body

    def _post(self, x: float, y: float, rgb: tuple[float, float, float]) -> int:
        c = self._c
        visual = c.createVisualShape(pybullet.GEOM_CYLINDER, radius=TARGET_RADIUS * self.scale,
                                     length=POST_HEIGHT, rgbaColor=(*rgb, 1.0))
        return c.createMultiBody(0, -1, visual, (x, y, 0.5 * POST_HEIGHT))

    def _build(self) -> None:
        c, a, s, p = self._c, self.arena, self.scale, self.params
        c.setGravity(0.0, 0.0, -9.81)
        c.setTimeStep(self.DT)
        c.setAdditionalSearchPath(pybullet_data.getDataPath())
        x0, y0, x1, y1 = (b * s for b in a.bounds)
        t = WALL_THICKNESS
        self._box((x0 - t - 1.0, y0 - t - 1.0), (x1 + t + 1.0, y1 + t + 1.0), -0.1, 0.0,
                  GREYS['floor'])
        for lo, hi in (((x0 - t, y0 - t), (x0, y1 + t)), ((x1, y0 - t), (x1 + t, y1 + t)),
                       ((x0, y0 - t), (x1, y0)), ((x0, y1), (x1, y1 + t))):
            self._box(lo, hi, 0.0, WALL_HEIGHT, GREYS['wall'])
        for box in a.obstacles:
            self._box((box.lo[0] * s, box.lo[1] * s), (box.hi[0] * s, box.hi[1] * s), 0.0,
                      TALL_HEIGHT if box.tall else SHORT_HEIGHT,
                      GREYS['tall' if box.tall else 'short'])
        for i, lm in enumerate(a.landmarks):
            self._post(lm.x * s, lm.y * s, colour_rgb(lm.colour, f'landmarks[{i}].colour'))
        d = a.destination
        self._post(d.x * s, d.y * s, colour_rgb(DESTINATION_COLOUR, 'destination'))

        x, y, yaw = self.start_pose
        with _quiet_stdout():
            self.robot = c.loadURDF('husky/husky.urdf', (x, y, 0.0),
                                    c.getQuaternionFromEuler((0.0, 0.0, yaw)),
                                    flags=pybullet.URDF_USE_IMPLICIT_CYLINDER)
        joints = {c.getJointInfo(self.robot, j)[1].decode(): j
                  for j in range(c.getNumJoints(self.robot))}
        missing = [w for w in _WHEELS if w not in joints]
        if missing:
            raise RuntimeError(f'husky/husky.urdf has no joint {missing[0]}')
        self.wheels = [joints[w] for w in _WHEELS]          # FL, FR, RL, RR
        # the track: left minus right wheel centres along y (the joints' frames in the parent
        # link, whose inertial offset cancels); the radius: the wheels' collision cylinder
        ys = [c.getJointInfo(self.robot, j)[14][1] for j in self.wheels]
        self.track = 0.5 * (ys[0] + ys[2]) - 0.5 * (ys[1] + ys[3])
        shape = c.getCollisionShapeData(self.robot, self.wheels[0])[0]
        if shape[2] != pybullet.GEOM_CYLINDER:
            raise RuntimeError('husky/husky.urdf: the wheel collision is not a cylinder')
        self.wheel_radius = float(shape[3][1])
        self.separation = self.track * p.wheel_separation_multiplier
        for link in range(-1, c.getNumJoints(self.robot)):
            c.setCollisionFilterGroupMask(self.robot, link, ROBOT_GROUP, WORLD_GROUP)
        for j in self.wheels:
            c.changeDynamics(self.robot, j,
                             anisotropicFriction=(1.0, p.lateral_friction_ratio, 1.0))
        self._robot_rgba = [(v[1], v[7]) for v in c.getVisualShapeData(self.robot)]
        self.show_robot(False)
        self._drive(0.0, 0.0)

    def show_robot(self, show: bool) -> None:
        """Draw the robot's own meshes in the camera's images or not (not: the default; the
        camera never sees them, module docstring)."""
        for link, rgba in self._robot_rgba:
            self._c.changeVisualShape(self.robot, link,
                                      rgbaColor=rgba if show else (*rgba[:3], 0.0))

    def _intrinsics(self) -> Intrinsics:
        p = self.params
        f = 0.5 * p.width / math.tan(math.radians(p.hfov_deg) / 2)
        # TinyRenderer fills a pixel when a point at its corner is covered, not its centre:
        # the optical axis lands on column width / 2 and (the rows flipped) row height / 2 - 1
        # (measured: a vertical edge 0.25 px either side of the axis)
        return Intrinsics(p.width, p.height, f, f, 0.5 * p.width, 0.5 * p.height - 1.0)

    def _scan_angles(self) -> np.ndarray:
        p = self.params
        fov = math.radians(p.scan_fov_deg)
        inc = fov / p.scan_rays if p.scan_fov_deg >= 360.0 else fov / (p.scan_rays - 1)
        return -0.5 * fov + inc * np.arange(p.scan_rays)

    def close(self) -> None:
        """Disconnect from the physics server (idempotent)."""
        c, self._c = getattr(self, '_c', None), None
        if c is not None:
            with contextlib.suppress(pybullet.error):
                c.disconnect()

    def __enter__(self) -> HuskyWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ time and drive

    @property
    def t(self) -> float:
        """Sim time of the state [s]: ``steps / 240``."""
        return self.steps / PHYSICS_HZ

    @property
    def command(self) -> tuple[float, float]:
        """The ``(v, omega)`` in force (clipped; zero after the timeout)."""
        return self._cmd

    def set_command(self, v: float, omega: float) -> bool:
        """Drive at ``(v, omega)`` (clipped to ``v_max``, ``omega_max``) until the next command
        or ``cmd_timeout`` s of sim time. A non-finite value drives at zero; returns whether
        the command was finite."""
        p = self.params
        ok = math.isfinite(v) and math.isfinite(omega)
        if not ok:
            self.rejected += 1
            v = omega = 0.0
        self._drive(min(max(v, -p.v_max), p.v_max), min(max(omega, -p.omega_max), p.omega_max))
        self._last_cmd_step = self.steps
        return ok

    def _drive(self, v: float, omega: float) -> None:
        self._cmd = (float(v), float(omega))
        half = 0.5 * omega * self.separation
        wl, wr = (v - half) / self.wheel_radius, (v + half) / self.wheel_radius
        self._c.setJointMotorControlArray(self.robot, self.wheels, pybullet.VELOCITY_CONTROL,
                                          targetVelocities=(wl, wr, wl, wr),
                                          forces=(self.params.wheel_torque,) * 4)

    def step(self, n: int = 1) -> None:
        """Advance the physics ``n`` steps of 1/240 s, integrating the odometry at each."""
        timeout = round(self.params.cmd_timeout * PHYSICS_HZ)
        c = self._c
        for _ in range(n):
            if self._last_cmd_step is not None and self.steps - self._last_cmd_step >= timeout:
                self._drive(0.0, 0.0)
                self._last_cmd_step = None
            c.stepSimulation()
            self.steps += 1
            w = [s[1] for s in c.getJointStates(self.robot, self.wheels)]
            vl = 0.5 * (w[0] + w[2]) * self.wheel_radius
            vr = 0.5 * (w[1] + w[3]) * self.wheel_radius
            v, omega = 0.5 * (vl + vr), (vr - vl) / self.separation
            self._twist = (v, omega)
            x, y, th = self._odom
            mid = th + 0.5 * omega * self.DT          # second-order (midpoint) integration
            self._odom = np.array((x + v * self.DT * math.cos(mid),
                                   y + v * self.DT * math.sin(mid),
                                   _wrap(th + omega * self.DT)))

    # ------------------------------------------------------------------ sensors

    def odom(self) -> Odom:
        """Wheel odometry of the current state (module docstring)."""
        x, y, yaw = (float(a) for a in self._odom)
        return Odom(x, y, yaw, float(self._twist[0]), float(self._twist[1]))

    def pose(self) -> tuple[float, float, float]:
        """The body's true ``(x, y, yaw)`` in the arena [m, rad] (for tests: no sensor)."""
        pos, q = self._c.getBasePositionAndOrientation(self.robot)
        return float(pos[0]), float(pos[1]), float(self._c.getEulerFromQuaternion(q)[2])

    def _body_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """Position (3,) and rotation matrix (3, 3) of the robot's base (its footprint)."""
        pos, q = self._c.getBasePositionAndOrientation(self.robot)
        rot = np.array(self._c.getMatrixFromQuaternion(q)).reshape(3, 3)
        return np.array(pos), rot

    def scan(self) -> np.ndarray:
        """The lidar's ranges [m], shape ``(scan_rays,)``, at :attr:`scan_angles` from the
        heading (counter-clockwise): ``inf`` for no return within ``range_max``, ``-inf``
        for one nearer than :data:`RANGE_MIN`."""
        pos, rot = self._body_frame()
        origin = pos + rot @ np.array((0.0, 0.0, LIDAR_HEIGHT))
        local = np.stack((np.cos(self.scan_angles), np.sin(self.scan_angles),
                          np.zeros_like(self.scan_angles)), axis=1)
        rmax = self.params.range_max
        ends = origin + (local @ rot.T) * rmax
        starts = np.broadcast_to(origin, ends.shape)
        hits = self._c.rayTestBatch(starts.tolist(), ends.tolist(),
                                    collisionFilterMask=WORLD_GROUP)
        ranges = np.full(len(hits), np.inf)
        for i, h in enumerate(hits):
            if h[0] >= 0 and h[0] != self.robot:
                ranges[i] = h[2] * rmax
        ranges[ranges < RANGE_MIN] = -np.inf
        return ranges

    def image(self) -> np.ndarray:
        """The camera's RGB image, shape ``(height, width, 3)``, uint8, row 0 at the top."""
        p = self.params
        pos, rot = self._body_frame()
        eye = pos + rot @ np.array((CAMERA_XZ[0], 0.0, CAMERA_XZ[1]))
        view = self._c.computeViewMatrix(eye.tolist(), (eye + rot[:, 0]).tolist(),
                                         rot[:, 2].tolist())
        out = self._c.getCameraImage(p.width, p.height, view, self._projection,
                                     renderer=pybullet.ER_TINY_RENDERER, shadow=0,
                                     flags=pybullet.ER_NO_SEGMENTATION_MASK, **LIGHT)
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(p.height, p.width, 4)
        return np.ascontiguousarray(rgba[:, :, :3])

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The camera's position (3,) and axes (3, 3): columns forward, left, up, in the
        arena's frame [m] (for projecting a point into the image)."""
        pos, rot = self._body_frame()
        return pos + rot @ np.array((CAMERA_XZ[0], 0.0, CAMERA_XZ[1])), rot

    def project(self, point: np.ndarray) -> tuple[float, float]:
        """Pixel ``(u, v)`` of an arena point (3,) [m] through the camera's pinhole (ROS
        convention); NaN behind the camera."""
        eye, axes = self.camera_pose()
        fwd, left, up = axes.T @ (np.asarray(point, float) - eye)
        if fwd <= 0.0:
            return math.nan, math.nan
        k = self.intrinsics
        return k.cx - k.fx * left / fwd, k.cy - k.fy * up / fwd
