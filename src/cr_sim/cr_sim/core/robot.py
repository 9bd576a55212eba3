"""Cyber Rodent body: parameters, differential-drive kinematics and the wheel safety clamp.

The CR is modelled as a disc of radius ``radius`` driven by two wheels ``wheel_base`` apart.
The command is the pair of wheel (rim) velocities ``u = (v_left, v_right)`` in m/s.

The body is described once, in ``config/robot.yaml`` (:func:`load_robot_params`,
:class:`RobotParams`): the simulator, the real robot's bridge, the module and arbiter nodes and
the headless runner all read it there.

Kinematics (unicycle form of a differential drive)::

    v     = (v_right + v_left) / 2              forward speed of the centre      [m/s]
    omega = (v_right - v_left) / wheel_base     yaw rate, counter-clockwise > 0  [rad/s]

With ``(v, omega)`` held for ``dt`` the centre moves along a circular arc. The exact pose
update is written with the chord of that arc, which stays accurate for ``omega -> 0``::

    a      = omega * dt / 2                     half the heading change
    chord  = v * dt * sin(a) / a                length of the chord (v * dt when a = 0)
    x'     = x + chord * cos(theta + a)         the chord points along the mean heading
    y'     = y + chord * sin(theta + a)
    theta' = theta + omega * dt

No rclpy or message types here: the bridge and the ROS node reuse these functions.
"""

from __future__ import annotations

from collections.abc import Mapping
import math
import os
from typing import Any

from clis_base.params import config_dir, dataclass, load_params, param, ros_parameters
import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    'ROBOT_FILE', 'RobotParams', 'load_robot_params', 'robot_defaults', 'wheels_to_twist',
    'twist_to_wheels', 'clamp_wheel', 'clamp_wheels', 'integrate_arc',
]

#: The file in :func:`~clis_base.params.config_dir` that describes the body, a ROS 2
#: parameter file for every node (``/**: ros__parameters: robot: ...``).
ROBOT_FILE = 'robot.yaml'


@dataclass(frozen=True)
class RobotParams:
    """Body and drive of the Cyber Rodent (``robot.yaml`` section ``robot``)."""

    radius: float = param(0.01, 0.5, doc='body radius: the robot is a disc for collisions [m]')
    wheel_base: float = param(0.01, 1.0, doc='distance between the two wheels [m]')
    v_wheel_max: float = param(0.01, 1.3, doc='hard limit of each wheel velocity [m/s]')


@dataclass(frozen=True)
class _RobotFile:
    """The sections of ``robot.yaml``."""

    robot: RobotParams = param(doc='section robot')


def load_robot_params(path: str | os.PathLike | None = None,
                      overrides: Mapping[str, Any] | None = None) -> RobotParams:
    """Read the body from ``/**: ros__parameters: robot:`` of ``robot.yaml``.

    Parameters
    ----------
    path : path-like, optional
        Default ``config_dir() / 'robot.yaml'``.
    overrides : Mapping, optional
        Values replacing the file's, nested and/or dotted (``{'robot.radius': 0.1}``).

    Raises
    ------
    ConfigError
        Naming the file and the key: missing, unknown, wrong type or out of range.
    """
    return load_params(_RobotFile, ROBOT_FILE, '/**', path, overrides).robot


def robot_defaults(path: str | os.PathLike | None = None) -> dict:
    """The ``robot`` section of ``robot.yaml`` as read (``{'robot': {...}}``): the defaults of
    the ``robot.*`` parameters a node declares (the simulator's, the bridge's)."""
    p = path if path is not None else config_dir() / ROBOT_FILE
    return {'robot': ros_parameters(p, '/**')['robot']}


def wheels_to_twist(v_left: float, v_right: float, wheel_base: float) -> tuple[float, float]:
    """Forward speed and yaw rate of a differential drive.

    Parameters
    ----------
    v_left, v_right : float or np.ndarray
        Wheel velocities [m/s] (arrays broadcast elementwise).
    wheel_base : float
        Distance between the wheels [m].

    Returns
    -------
    v : float or np.ndarray
        Forward speed ``(v_left + v_right) / 2`` [m/s].
    omega : float or np.ndarray
        Yaw rate ``(v_right - v_left) / wheel_base`` [rad/s], counter-clockwise positive.
    """
    return 0.5 * (v_left + v_right), (v_right - v_left) / wheel_base


def twist_to_wheels(v: float, omega: float, wheel_base: float) -> tuple[float, float]:
    """Wheel velocities that realise a twist: the inverse of :func:`wheels_to_twist`.

    Parameters
    ----------
    v : float or np.ndarray
        Forward speed [m/s].
    omega : float or np.ndarray
        Yaw rate [rad/s], counter-clockwise positive.
    wheel_base : float
        Distance between the wheels [m].

    Returns
    -------
    v_left, v_right : float or np.ndarray
        ``v -/+ omega * wheel_base / 2`` [m/s]. Not clamped: apply :func:`clamp_wheels`.
    """
    half = 0.5 * omega * wheel_base
    return v - half, v + half


def clamp_wheel(v: float, v_max: float) -> float:
    """Safety clamp of one wheel velocity: non-finite -> 0, then clipped to ``+-v_max``."""
    if not math.isfinite(v):
        v = 0.0
    return v_max if v > v_max else (-v_max if v < -v_max else v)


def clamp_wheels(u: ArrayLike, v_max: float) -> np.ndarray:
    """Safety clamp of a wheel command: never lets a bad value through.

    Parameters
    ----------
    u : array_like, shape (2,)
        Requested ``(v_left, v_right)`` [m/s].
    v_max : float
        Limit of each wheel [m/s], > 0.

    Returns
    -------
    np.ndarray, shape (2,), float64
        The command with every non-finite entry (NaN, +-inf) replaced by 0 (that wheel stops;
        a NaN never propagates) and every entry clipped to ``[-v_max, v_max]``.

    Raises
    ------
    ValueError
        If ``u`` does not hold exactly two numbers.
    """
    try:
        a = np.asarray(u, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f'wheel command must be two numbers (v_left, v_right), got {u!r}') \
            from None
    if a.shape != (2,):
        raise ValueError(f'wheel command must be two numbers (v_left, v_right), got {u!r}')
    return np.array((clamp_wheel(float(a[0]), v_max), clamp_wheel(float(a[1]), v_max)))


def integrate_arc(x: float, y: float, theta: float, v: float, omega: float,
                  dt: float) -> tuple[float, float, float]:
    """Exact pose after holding the twist ``(v, omega)`` for ``dt`` (module docstring).

    Parameters
    ----------
    x, y : float
        Position of the centre [m].
    theta : float
        Heading [rad] (not wrapped here).
    v, omega : float
        Forward speed [m/s] and yaw rate [rad/s].
    dt : float
        Duration [s].

    Returns
    -------
    tuple of float
        ``(x', y', theta')``; ``theta' = theta + omega * dt`` is not wrapped.
    """
    a = 0.5 * omega * dt
    # sin(a)/a: the chord of an arc of length v*dt turning by 2a; series near 0 (error < a^4/120)
    f = 1.0 - a * a / 6.0 if abs(a) < 1e-4 else math.sin(a) / a
    chord = v * dt * f
    mid = theta + a
    return x + chord * math.cos(mid), y + chord * math.sin(mid), theta + 2.0 * a
