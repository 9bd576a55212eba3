"""Camera models: which bearing each image column looks along, and back.

A bearing is an angle in the floor plane relative to the robot's heading, counter-clockwise
positive (left of the heading > 0), wrapped to (-pi, pi], as the simulator's ``camera`` topic
gives it. Image columns ``u`` count from the left; pixel ``u`` covers ``[u - 0.5, u + 0.5]``
and its centre is the integer ``u`` (the convention of sensor_msgs/CameraInfo and OpenCV), so
a fractional column is any point in between. Both models look horizontally (optical axis in
the floor plane); rows are only used by the renderer (:mod:`cr_sim.core.render`).

Pinhole (:class:`Pinhole`), the optical axis at bearing ``yaw`` (the mounting yaw offset)::

    bearing(u) = yaw - atan((u - cx) / fx)          u(b) = cx - fx tan(b - yaw)
    row of a point at height z and depth D:   v = cy - fy (z - h) / D

with ``fx, cx, fy, cy`` the entries ``K[0, 0], K[0, 2], K[1, 1], K[1, 2]`` of CameraInfo's
intrinsic matrix ``K`` (row-major, 9 numbers), ``D`` the distance along the optical axis and
``h`` the camera's height. The field of view is the image, ``-0.5 <= u <= width - 0.5``; a
bearing outside it has no column (NaN).

Panoramic (:class:`Panoramic`), the unrolled image of an omni-directional camera (the Cyber
Rodent's): ``width`` columns of equal angle ``2 pi / width`` cover the full turn, column 0's
centre at bearing ``bearing0``, the columns running clockwise (to the right, as in a pinhole
image; ``clockwise=False`` for a mirrored strip)::

    bearing(u) = bearing0 - s (2 pi / width) u       s = +1 clockwise, -1 counter-clockwise
    row of a point at height z and range D:   v = cy - fy (z - h) / D,   fy = width / (2 pi)

The strip closes on itself (column ``width - 1`` neighbours column 0: :attr:`Panoramic.wraps`),
every bearing has a column, in ``[-0.5, width - 0.5)``. The vertical scale ``fy`` is that of
square pixels (a cylinder of radius ``width / (2 pi)`` pixels).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Union

import numpy as np
from numpy.typing import ArrayLike

from cr_sim.core.geometry import TWO_PI, wrap_angles

__all__ = ['Pinhole', 'Panoramic', 'CameraModel', 'MAX_PIXELS']

#: Largest width or height accepted [px].
MAX_PIXELS = 100_000


def _check(name: str, value: float, lo: float, hi: float, lo_open: bool = False,
           hi_open: bool = False) -> None:
    """ValueError naming the field and its allowed range unless ``lo <= value <= hi`` (or
    strict where open); NaN and inf are outside every range."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    bad = (not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo)
           or (hi_open and v == hi))
    if bad:
        left, right = '(' if lo_open else '[', ')' if hi_open else ']'
        raise ValueError(f'{name} = {value!r} is out of range: must be in {left}{_num(lo)}, '
                         f'{_num(hi)}{right}')


def _num(x: float) -> str:
    """A bound as the message writes it: pi for math.pi."""
    for k, text in ((1.0, 'pi'), (-1.0, '-pi')):
        if x == k * math.pi:
            return text
    return f'{x:g}'


def _check_size(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f'{name} = {value!r} must be an integer in [1, {MAX_PIXELS}]')
    _check(name, value, 1, MAX_PIXELS)


def _out(a: np.ndarray, like: ArrayLike) -> np.ndarray | float:
    """``a`` shaped as the input ``like``: a float for a scalar input."""
    return float(a.reshape(())) if np.ndim(like) == 0 else a.reshape(np.shape(like))


@dataclass(frozen=True)
class Pinhole:
    """A pinhole camera looking horizontally along bearing ``yaw`` (module docstring).

    Attributes
    ----------
    width, height : int
        Image size [px], in [1, MAX_PIXELS].
    fx, fy : float
        Focal lengths [px], > 0.
    cx, cy : float
        Principal point [px] (column, row), finite.
    yaw : float
        Mounting yaw offset: bearing of the optical axis from the heading [rad], in
        [-pi, pi].
    """

    width: int
    height: int
    fx: float
    cx: float
    fy: float
    cy: float
    yaw: float = 0.0

    def __post_init__(self) -> None:
        _check_size('width', self.width)
        _check_size('height', self.height)
        _check('fx', self.fx, 0.0, math.inf, lo_open=True, hi_open=True)
        _check('fy', self.fy, 0.0, math.inf, lo_open=True, hi_open=True)
        _check('cx', self.cx, -math.inf, math.inf, lo_open=True, hi_open=True)
        _check('cy', self.cy, -math.inf, math.inf, lo_open=True, hi_open=True)
        _check('yaw', self.yaw, -math.pi, math.pi)

    @classmethod
    def from_fov(cls, width: int, height: int, hfov: float, yaw: float = 0.0) -> Pinhole:
        """The camera whose image edges are at ``yaw +- hfov / 2``, square pixels, the
        principal point at the image centre.

        Parameters
        ----------
        width, height : int
            Image size [px].
        hfov : float
            Horizontal field of view [rad], in (0, pi).
        yaw : float
            Mounting yaw offset [rad], in [-pi, pi].
        """
        _check('hfov', hfov, 0.0, math.pi, lo_open=True, hi_open=True)
        _check_size('width', width)
        _check_size('height', height)
        f = 0.5 * width / math.tan(0.5 * hfov)
        return cls(width, height, f, 0.5 * (width - 1), f, 0.5 * (height - 1), yaw)

    @classmethod
    def from_k(cls, width: int, height: int, k: Sequence[float] | ArrayLike,
               yaw: float = 0.0) -> Pinhole:
        """The camera of a sensor_msgs/CameraInfo: its ``width``, ``height`` and ``k``.

        Parameters
        ----------
        width, height : int
            Image size [px].
        k : array_like, shape (9,) or (3, 3)
            Intrinsic matrix, row-major: ``fx = k[0]``, ``cx = k[2]``, ``fy = k[4]``,
            ``cy = k[5]`` (the skew ``k[1]`` is ignored).
        yaw : float
            Mounting yaw offset [rad], in [-pi, pi].
        """
        a = np.asarray(k, dtype=np.float64).reshape(-1)
        if a.shape != (9,):
            raise ValueError(f'k has {a.size} numbers: must be the 9 of a 3 x 3 matrix')
        return cls(width, height, float(a[0]), float(a[2]), float(a[4]), float(a[5]), yaw)

    @property
    def wraps(self) -> bool:
        """Column ``width - 1`` does not neighbour column 0."""
        return False

    @property
    def hfov(self) -> float:
        """Horizontal field of view [rad]: the angle between the two image edges."""
        return (math.atan((self.cx + 0.5) / self.fx)
                + math.atan((self.width - 0.5 - self.cx) / self.fx))

    @property
    def angle_per_pixel(self) -> float:
        """Angle of the widest pixel column [rad]: the one at the principal point,
        ``2 atan(1 / (2 fx))`` (the others subtend less)."""
        return 2.0 * math.atan(0.5 / self.fx)

    def bearing_of_column(self, u: ArrayLike) -> np.ndarray | float:
        """Bearing of the ray through column ``u``.

        Parameters
        ----------
        u : float or array_like, shape (N,)
            Columns [px], integer (pixel centres) or fractional.

        Returns
        -------
        float or np.ndarray, shape (N,)
            Bearing relative to the heading [rad], in (-pi, pi]; columns outside the image
            give the bearing of the same ray all the same.
        """
        uu = np.atleast_1d(np.asarray(u, dtype=np.float64))
        return _out(wrap_angles(self.yaw - np.arctan((uu - self.cx) / self.fx)), u)

    def column_of_bearing(self, b: ArrayLike) -> np.ndarray | float:
        """Column at which bearing ``b`` appears: the inverse of :meth:`bearing_of_column`.

        Parameters
        ----------
        b : float or array_like, shape (N,)
            Bearings relative to the heading [rad] (any turn).

        Returns
        -------
        float or np.ndarray, shape (N,)
            Fractional column in ``[-0.5, width - 0.5]``; NaN outside the field of view.
        """
        rel = wrap_angles(np.atleast_1d(np.asarray(b, dtype=np.float64)) - self.yaw)
        with np.errstate(invalid='ignore'):
            front = np.abs(rel) < 0.5 * math.pi
            u = self.cx - self.fx * np.tan(np.where(front, rel, 0.0))
            inside = front & (u >= -0.5) & (u <= self.width - 0.5)
        return _out(np.where(inside, u, np.nan), b)

    def depth_per_range(self, u: ArrayLike) -> np.ndarray | float:
        """Depth along the optical axis of a point one metre away along column ``u``'s ray:
        the cosine of the ray's angle off the axis (the ``D`` of the row formula per metre).

        Parameters
        ----------
        u : float or array_like, shape (N,)

        Returns
        -------
        float or np.ndarray, shape (N,)
        """
        uu = np.atleast_1d(np.asarray(u, dtype=np.float64))
        return _out(1.0 / np.hypot(1.0, (uu - self.cx) / self.fx), u)


@dataclass(frozen=True)
class Panoramic:
    """The unrolled strip of an omni-directional camera: 360 degrees in ``width`` columns.

    Attributes
    ----------
    width, height : int
        Strip size [px], in [1, MAX_PIXELS].
    bearing0 : float
        Bearing of column 0's centre [rad], in [-pi, pi]; the default pi puts the heading
        at column ``width / 2``, the middle of the strip.
    clockwise : bool
        The columns run clockwise (bearing decreasing to the right); False for a mirrored
        strip.
    cy : float or None
        Row of the horizon [px], finite; None: the middle row ``(height - 1) / 2``.
    """

    width: int
    height: int
    bearing0: float = math.pi
    clockwise: bool = True
    cy: float | None = None

    def __post_init__(self) -> None:
        _check_size('width', self.width)
        _check_size('height', self.height)
        _check('bearing0', self.bearing0, -math.pi, math.pi)
        if not isinstance(self.clockwise, (bool, np.bool_)):
            raise ValueError(f'clockwise = {self.clockwise!r} must be true or false')
        if self.cy is None:
            object.__setattr__(self, 'cy', 0.5 * (self.height - 1))
        _check('cy', self.cy, -math.inf, math.inf, lo_open=True, hi_open=True)

    @property
    def wraps(self) -> bool:
        """Column ``width - 1`` neighbours column 0 (the strip closes on itself)."""
        return True

    @property
    def hfov(self) -> float:
        """Horizontal field of view [rad]: the full turn."""
        return TWO_PI

    @property
    def angle_per_pixel(self) -> float:
        """Angle of every column [rad]: ``2 pi / width``."""
        return TWO_PI / self.width

    @property
    def fy(self) -> float:
        """Vertical scale [px per unit of ``(z - h) / D``]: ``width / (2 pi)``, square
        pixels."""
        return self.width / TWO_PI

    def bearing_of_column(self, u: ArrayLike) -> np.ndarray | float:
        """Bearing of the ray through column ``u``.

        Parameters
        ----------
        u : float or array_like, shape (N,)
            Columns [px], integer (pixel centres) or fractional, any value (taken round the
            strip).

        Returns
        -------
        float or np.ndarray, shape (N,)
            Bearing relative to the heading [rad], in (-pi, pi].
        """
        s = 1.0 if self.clockwise else -1.0
        uu = np.atleast_1d(np.asarray(u, dtype=np.float64))
        return _out(wrap_angles(self.bearing0 - s * self.angle_per_pixel * uu), u)

    def column_of_bearing(self, b: ArrayLike) -> np.ndarray | float:
        """Column at which bearing ``b`` appears: the inverse of :meth:`bearing_of_column`.

        Parameters
        ----------
        b : float or array_like, shape (N,)
            Bearings relative to the heading [rad] (any turn).

        Returns
        -------
        float or np.ndarray, shape (N,)
            Fractional column in ``[-0.5, width - 0.5)``; NaN only for a NaN bearing.
        """
        s = 1.0 if self.clockwise else -1.0
        bb = np.atleast_1d(np.asarray(b, dtype=np.float64))
        u = np.remainder(s * (self.bearing0 - bb) / self.angle_per_pixel + 0.5, self.width)
        u[u >= self.width] = 0.0              # a remainder rounded up to the modulus
        return _out(u - 0.5, b)

    def depth_per_range(self, u: ArrayLike) -> np.ndarray | float:
        """Depth per metre of range along column ``u``'s ray: 1 (the strip is a cylinder
        round the camera; rows scale with the range itself).

        Parameters
        ----------
        u : float or array_like, shape (N,)

        Returns
        -------
        float or np.ndarray, shape (N,)
        """
        return _out(np.ones(np.shape(np.atleast_1d(u))), u)


#: Either camera model.
CameraModel = Union[Pinhole, Panoramic]
