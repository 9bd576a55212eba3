"""The arena: floor, walls, destination, obstacles, landmarks and start poses, from a YAML file.

The layout is data (``config/arena.yaml``, format documented at the top of that file), never
code. :func:`load_arena` reads and validates a file; :func:`parse_arena` does the same for a
mapping already in memory. Every error is an :class:`ArenaError` (a ``ConfigError``) whose
message names the file, the key and the object at fault.

Frame: metres, x to the east, y to the north, headings counter-clockwise from +x. The floor
is either a square of side ``size`` centred at the origin (``size: 3.0``), or any rectangle
measured in the lab's own frame (``floor: {width, height, origin: [x, y]}``, origin = the
lab coordinates of the floor's south-west corner); every position in the file is in that
frame. The walls are the border of the floor, :attr:`Arena.bounds`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import math
import os
from pathlib import Path
from typing import Any

from clis_base.params import ConfigError, config_dir, load_yaml
import numpy as np

from cr_sim.core.geometry import disc_gap
from cr_sim.core.robot import load_robot_params

__all__ = [
    'ArenaError', 'Box', 'Destination', 'Landmark', 'Start', 'Arena', 'load_arena',
    'parse_arena', 'scaled_arena', 'arena_data', 'ARENA_KEYS', 'FLOOR_KEYS',
]

#: Top-level keys of an arena file (all required; ``floor`` may replace ``size``).
ARENA_KEYS = ('size', 'destination', 'short_obstacles', 'tall_obstacles', 'landmarks', 'starts')
#: Keys of ``floor`` (a rectangle in the lab's frame).
FLOOR_KEYS = ('width', 'height', 'origin')


class ArenaError(ConfigError):
    """The arena file is missing a key, malformed, or describes an impossible layout."""


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned box obstacle. Short ones block IR and motion; tall ones also the camera."""

    name: str
    center: tuple[float, float]
    size: tuple[float, float]
    tall: bool

    @property
    def lo(self) -> tuple[float, float]:
        """South-west corner ``(x, y)`` [m]."""
        return (self.center[0] - 0.5 * self.size[0], self.center[1] - 0.5 * self.size[1])

    @property
    def hi(self) -> tuple[float, float]:
        """North-east corner ``(x, y)`` [m]."""
        return (self.center[0] + 0.5 * self.size[0], self.center[1] + 0.5 * self.size[1])


@dataclass(frozen=True, slots=True)
class Destination:
    """The goal marker on the floor (not an obstacle)."""

    x: float
    y: float
    goal_radius: float   # the goal is reached when the robot centre is within this [m]


@dataclass(frozen=True, slots=True)
class Landmark:
    """A coloured blob seen by the omni-camera (used for localization)."""

    name: str
    colour: str
    x: float
    y: float


@dataclass(frozen=True, slots=True)
class Start:
    """A named start pose (A..E in the paper)."""

    name: str
    x: float
    y: float
    heading_deg: float

    @property
    def heading(self) -> float:
        """Heading [rad]."""
        return math.radians(self.heading_deg)

    @property
    def pose(self) -> np.ndarray:
        """``(x, y, heading_rad)``, shape (3,)."""
        return np.array((self.x, self.y, self.heading))


@dataclass(frozen=True, slots=True)
class Arena:
    """A validated arena layout (see ``config/arena.yaml``).

    ``bounds`` = ``(xmin, ymin, xmax, ymax)`` of the floor [m]: the walls are its border.
    """

    bounds: tuple[float, float, float, float]
    destination: Destination
    short_obstacles: tuple[Box, ...]
    tall_obstacles: tuple[Box, ...]
    landmarks: tuple[Landmark, ...]
    starts: tuple[Start, ...]
    source: str = '<memory>'

    @property
    def width(self) -> float:
        """Extent of the floor along x [m]."""
        return self.bounds[2] - self.bounds[0]

    @property
    def height(self) -> float:
        """Extent of the floor along y [m]."""
        return self.bounds[3] - self.bounds[1]

    @property
    def size(self) -> float:
        """The longer side of the floor [m] (the side of a square one)."""
        return max(self.width, self.height)

    @property
    def centred_square(self) -> bool:
        """Whether the floor is a square centred at the origin (the paper's arena)."""
        x0, y0, x1, y1 = self.bounds
        return x0 == y0 == -x1 == -y1

    @property
    def half(self) -> float:
        """Half the side of a square floor centred at the origin: the walls are at x, y =
        +-half [m]. Any other floor has none: use :attr:`bounds` (ValueError)."""
        if not self.centred_square:
            raise ValueError(f'{self.source}: the floor {self.bounds} is not a square centred '
                             'at the origin: use Arena.bounds')
        return self.bounds[2]

    def floor(self) -> float | tuple[float, float, float, float]:
        """The floor as the geometry and localization cores take it: the half side of a
        centred square (the fast, exact path of the paper's arena), else :attr:`bounds`."""
        return self.half if self.centred_square else self.bounds

    def gap_boxes(self) -> tuple[tuple[tuple[float, float, float, float], ...], float]:
        """``(boxes, half)`` for :func:`disc_gap`: the obstacles and the half side of a
        centred square; for any other floor the obstacles plus its 4 walls as boxes, with
        ``half = inf`` (the same gap, the walls found among the boxes)."""
        if self.centred_square:
            return self.box_tuples(), self.half
        return self.box_tuples() + self.wall_boxes(thickness=1.0), math.inf

    @property
    def obstacles(self) -> tuple[Box, ...]:
        """All obstacles, tall ones first."""
        return self.tall_obstacles + self.short_obstacles

    @property
    def start_names(self) -> tuple[str, ...]:
        """Names of the start poses, in file order."""
        return tuple(s.name for s in self.starts)

    def start(self, name: str) -> Start:
        """The start pose called ``name``; ``KeyError`` naming the known ones otherwise."""
        for s in self.starts:
            if s.name == name:
                return s
        raise KeyError(f'no start {name!r} in {self.source}; known: '
                       + ', '.join(self.start_names))

    def box_array(self, tall_only: bool = False, walls: bool = False) -> np.ndarray:
        """Obstacles (tall first, then short, then optionally the 4 walls) as (B, 2, 2) array."""
        boxes = self.tall_obstacles if tall_only else self.obstacles
        arr = np.array([[b.lo, b.hi] for b in boxes], dtype=np.float64).reshape(-1, 2, 2)
        return np.concatenate([arr, _walls(self.bounds, 1.0)]) if walls else arr

    def box_tuples(self) -> tuple[tuple[float, float, float, float], ...]:
        """Obstacles as ``(lo_x, lo_y, hi_x, hi_y)`` tuples (for :func:`disc_gap`)."""
        return tuple((*b.lo, *b.hi) for b in self.obstacles)

    def short_boxes(self) -> tuple[tuple[float, float, float, float], ...]:
        """Short obstacles as ``(xmin, ymin, xmax, ymax)`` [m] (display)."""
        return tuple((*b.lo, *b.hi) for b in self.short_obstacles)

    def tall_boxes(self) -> tuple[tuple[float, float, float, float], ...]:
        """Tall obstacles as ``(xmin, ymin, xmax, ymax)`` [m] (display)."""
        return tuple((*b.lo, *b.hi) for b in self.tall_obstacles)

    def wall_boxes(self, thickness: float = 0.05) -> tuple[tuple[float, float, float, float],
                                                           ...]:
        """The 4 walls as ``(xmin, ymin, xmax, ymax)`` [m], ``thickness`` outside the floor.

        For display; the physics treats the walls as infinitely thick.
        """
        return tuple(tuple(float(v) for v in (*b[0], *b[1]))
                     for b in _walls(self.bounds, thickness))

    def gap(self, x: float, y: float, radius: float) -> float:
        """Free distance of a disc at (x, y) to the nearest obstacle or wall [m] (< 0: overlap)."""
        return disc_gap(x, y, radius, *self.gap_boxes())

    def check(self, robot_radius: float) -> None:
        """Check the layout against a robot of radius ``robot_radius``.

        Raises
        ------
        ArenaError
            If a start pose or the destination leaves no room for the robot's disc.
        """
        where = self.source
        for s in self.starts:
            culprit = self._blocker(s.x, s.y, robot_radius)
            if culprit:
                raise ArenaError(f'{where}: start {s.name!r} at ({s.x}, {s.y}) is inside or '
                                 f'within the robot radius {robot_radius} m of {culprit}')
        d = self.destination
        culprit = self._blocker(d.x, d.y, robot_radius)
        if culprit:
            raise ArenaError(f'{where}: destination at ({d.x}, {d.y}) is inside or within the '
                             f'robot radius {robot_radius} m of {culprit}: it cannot be reached')

    def _blocker(self, x: float, y: float, radius: float) -> str:
        x0, y0, x1, y1 = self.bounds
        if min(x - x0, x1 - x, y - y0, y1 - y) < radius:
            return 'the wall'
        for b in self.obstacles:
            if disc_gap(x, y, radius, ((*b.lo, *b.hi),), math.inf) < 0.0:
                return f'{"tall" if b.tall else "short"} obstacle {b.name!r}'
        return ''


def _walls(bounds: tuple[float, float, float, float], thickness: float) -> np.ndarray:
    """The four walls of the floor ``bounds`` as boxes outside it, shape (4, 2, 2): west,
    east, south, north, each ``thickness`` thick (for a centred square exactly
    :func:`cr_sim.core.geometry.wall_boxes`)."""
    x0, y0, x1, y1 = bounds
    t = thickness
    return np.array([
        [[x0 - t, y0 - t], [x0, y1 + t]],     # west  x <= xmin
        [[x1, y0 - t], [x1 + t, y1 + t]],     # east  x >= xmax
        [[x0 - t, y0 - t], [x1 + t, y0]],     # south y <= ymin
        [[x0 - t, y1], [x1 + t, y1 + t]],     # north y >= ymax
    ], dtype=np.float64)


# ------------------------------------------------------------------------------------------
# loading and validation

def _number(value: Any, where: str, lo: float = -math.inf, hi: float = math.inf,
            lo_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ArenaError(f'{where} = {value!r} must be a number')
    v = float(value)
    if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo):
        bracket = '(' if lo_open else '['
        raise ArenaError(f'{where} = {value!r} is out of range: must be in {bracket}{lo}, {hi}]')
    return v


def _pair(value: Any, where: str, lo: float = -math.inf, lo_open: bool = False
          ) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ArenaError(f'{where} = {value!r} must be a list of two numbers [x, y]')
    return (_number(value[0], f'{where}[0]', lo=lo, lo_open=lo_open),
            _number(value[1], f'{where}[1]', lo=lo, lo_open=lo_open))


def _fields(mapping: Any, where: str, keys: tuple[str, ...]) -> Mapping[str, Any]:
    if not isinstance(mapping, Mapping):
        raise ArenaError(f'{where} must be a mapping with keys ' + ', '.join(keys))
    for k in keys:
        if k not in mapping:
            raise ArenaError(f'missing key {where}.{k}' if where else f'missing key {k}')
    unknown = sorted(set(mapping) - set(keys))
    if unknown:
        raise ArenaError(f'unknown key {where + "." if where else ""}{unknown[0]}; allowed keys: '
                         + ', '.join(keys))
    return mapping


def _name(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value:
        raise ArenaError(f'{where} = {value!r} must be a non-empty string')
    return value


def _boxes(items: Any, key: str, tall: bool, bounds: tuple[float, ...]) -> tuple[Box, ...]:
    if items is None:
        items = []
    if not isinstance(items, list):
        raise ArenaError(f'{key} must be a list of boxes (name, center, size)')
    boxes = []
    for i, item in enumerate(items):
        label = f'{key}[{i}]'
        if isinstance(item, Mapping) and isinstance(item.get('name'), str):
            label = f'{key}[{i}] ({item["name"]!r})'
        f = _fields(item, label, ('name', 'center', 'size'))
        box = Box(name=_name(f['name'], f'{label}.name'),
                  center=_pair(f['center'], f'{label}.center'),
                  size=_pair(f['size'], f'{label}.size', lo=0.0, lo_open=True), tall=tall)
        eps = 1e-12
        if (box.lo[0] < bounds[0] - eps or box.lo[1] < bounds[1] - eps
                or box.hi[0] > bounds[2] + eps or box.hi[1] > bounds[3] + eps):
            raise ArenaError(
                f'{"tall" if tall else "short"} obstacle {box.name!r} ({key}[{i}]) spans '
                f'x in [{box.lo[0]:g}, {box.hi[0]:g}], y in [{box.lo[1]:g}, {box.hi[1]:g}]: '
                f'(partly) outside the walls {_describe(bounds)}')
        boxes.append(box)
    return tuple(boxes)


def parse_arena(data: Mapping[str, Any], robot_radius: float, source: str = '<memory>'
                ) -> Arena:
    """Build and validate an :class:`Arena` from a mapping in the arena-file format.

    Parameters
    ----------
    data : Mapping
        Content of an arena file (see ``config/arena.yaml``).
    robot_radius : float
        Radius of the robot disc [m], to check that start poses and the destination are free.
    source : str
        Name used in error messages (the file path).

    Raises
    ------
    ArenaError
        Naming the missing/unknown key or the offending obstacle, landmark or start.
    """
    try:
        return _parse(data, robot_radius, source)
    except ArenaError as exc:
        if str(exc).startswith(source):
            raise
        raise ArenaError(f'{source}: {exc}') from None


def _describe(bounds: tuple[float, ...]) -> str:
    x0, y0, x1, y1 = bounds
    if x0 == y0 == -x1 == -y1:
        return f'at +-{x1:g} m'
    return f'x in [{x0:g}, {x1:g}], y in [{y0:g}, {y1:g}] m'


def _floor(top: Mapping[str, Any]) -> tuple[float, float, float, float]:
    """``bounds`` of ``size`` (a centred square) or ``floor`` (a rectangle in the lab frame)."""
    if ('size' in top) == ('floor' in top):
        raise ArenaError('give the floor either as size (a square centred at the origin) or '
                         'as floor: {width, height, origin: [x, y]} (a rectangle whose '
                         'south-west corner is at origin), not both')
    if 'size' in top:
        half = 0.5 * _number(top['size'], 'size', lo=0.0, hi=100.0, lo_open=True)
        return (-half, -half, half, half)
    f = _fields(top['floor'], 'floor', FLOOR_KEYS)
    w = _number(f['width'], 'floor.width', lo=0.0, hi=100.0, lo_open=True)
    h = _number(f['height'], 'floor.height', lo=0.0, hi=100.0, lo_open=True)
    x0, y0 = _pair(f['origin'], 'floor.origin')
    return (x0, y0, x0 + w, y0 + h)


def _parse(data: Mapping[str, Any], robot_radius: float, source: str) -> Arena:
    keys = ARENA_KEYS if 'floor' not in (data if isinstance(data, Mapping) else {}) \
        else ('floor',) + ARENA_KEYS[1:]
    if isinstance(data, Mapping) and 'floor' in data and 'size' in data:
        _floor(data)                                  # the message: not both
    top = _fields(data, '', keys)
    bounds = _floor(top)
    x0, y0, x1, y1 = bounds

    d = _fields(top['destination'], 'destination', ('x', 'y', 'goal_radius'))
    dest = Destination(x=_number(d['x'], 'destination.x', x0, x1),
                       y=_number(d['y'], 'destination.y', y0, y1),
                       goal_radius=_number(d['goal_radius'], 'destination.goal_radius',
                                           0.0, max(x1 - x0, y1 - y0), lo_open=True))

    short = _boxes(top['short_obstacles'], 'short_obstacles', False, bounds)
    tall = _boxes(top['tall_obstacles'], 'tall_obstacles', True, bounds)
    names = [b.name for b in short + tall]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ArenaError(f'obstacle name {dup[0]!r} is used twice')

    lms = top['landmarks']
    if not isinstance(lms, list) or not lms:
        raise ArenaError('landmarks must be a non-empty list of (name, colour, x, y)')
    landmarks = []
    for i, item in enumerate(lms):
        label = f'landmarks[{i}]'
        if isinstance(item, Mapping) and isinstance(item.get('name'), str):
            label = f'landmarks[{i}] ({item["name"]!r})'
        f = _fields(item, label, ('name', 'colour', 'x', 'y'))
        lm = Landmark(name=_name(f['name'], f'{label}.name'),
                      colour=_name(f['colour'], f'{label}.colour'),
                      x=_number(f['x'], f'{label}.x'), y=_number(f['y'], f'{label}.y'))
        eps = 1e-12
        if not (x0 - eps <= lm.x <= x1 + eps and y0 - eps <= lm.y <= y1 + eps):
            raise ArenaError(f'landmark {lm.name!r} at ({lm.x}, {lm.y}) is outside the walls '
                             f'{_describe(bounds)} (put it on or inside the wall)')
        landmarks.append(lm)
    lnames = [lm.name for lm in landmarks]
    if len(set(lnames)) != len(lnames):
        raise ArenaError('two landmarks have the same name')

    st = top['starts']
    if not isinstance(st, Mapping) or not st:
        raise ArenaError('starts must be a non-empty mapping NAME: {x, y, heading_deg}')
    starts = []
    for name, item in st.items():
        label = f'starts.{name}'
        f = _fields(item, label, ('x', 'y', 'heading_deg'))
        starts.append(Start(name=str(name), x=_number(f['x'], f'{label}.x'),
                            y=_number(f['y'], f'{label}.y'),
                            heading_deg=_number(f['heading_deg'], f'{label}.heading_deg',
                                                -360.0, 360.0)))

    arena = Arena(bounds=bounds, destination=dest, short_obstacles=short, tall_obstacles=tall,
                  landmarks=tuple(landmarks), starts=tuple(starts), source=source)
    arena.check(robot_radius)
    return arena


def load_arena(path: str | os.PathLike | None = None, robot_radius: float | None = None
               ) -> Arena:
    """Read and validate an arena file.

    Parameters
    ----------
    path : path-like, optional
        The YAML file; default ``config_dir() / 'arena.yaml'``.
    robot_radius : float, optional
        Robot radius [m] for the free-space checks; default ``robot.radius`` of the default
        ``robot.yaml``.

    Returns
    -------
    Arena

    Raises
    ------
    ArenaError
        Missing file or key, bad value, obstacle outside the walls, start or destination
        inside an obstacle or a wall: the message names the file and the culprit.
    """
    p = Path(path) if path is not None else config_dir() / 'arena.yaml'
    if robot_radius is None:
        robot_radius = load_robot_params().radius
    try:
        data = load_yaml(p)
    except ArenaError:
        raise
    except ConfigError as exc:
        raise ArenaError(str(exc)) from None
    return parse_arena(data, robot_radius, source=str(p))


def scaled_arena(arena: Arena, scale: float) -> Arena:
    """``arena`` with every length multiplied by ``scale`` about the origin (the layout at a
    robot's size: a robot profile's ``arena.size``); the same object for ``scale`` 1."""
    if scale == 1.0:
        return arena
    s = float(scale)

    def box(b: Box) -> Box:
        return replace(b, center=(b.center[0] * s, b.center[1] * s),
                       size=(b.size[0] * s, b.size[1] * s))
    d = arena.destination
    return replace(
        arena, bounds=tuple(v * s for v in arena.bounds),
        destination=replace(d, x=d.x * s, y=d.y * s, goal_radius=d.goal_radius * s),
        short_obstacles=tuple(box(b) for b in arena.short_obstacles),
        tall_obstacles=tuple(box(b) for b in arena.tall_obstacles),
        landmarks=tuple(replace(m, x=m.x * s, y=m.y * s) for m in arena.landmarks),
        starts=tuple(replace(st, x=st.x * s, y=st.y * s) for st in arena.starts))


def arena_data(arena: Arena) -> dict[str, Any]:
    """``arena`` in the arena-file format (:func:`parse_arena` reads it back to an equal
    arena): the floor as a rectangle, then every object."""
    x0, y0, x1, y1 = arena.bounds

    def box(b: Box) -> dict[str, Any]:
        return {'name': b.name, 'center': list(b.center), 'size': list(b.size)}
    d = arena.destination
    square = x1 - x0 == y1 - y0 and x0 == -x1 and y0 == -y1
    return {
        **({'size': x1 - x0} if square else
           {'floor': {'width': x1 - x0, 'height': y1 - y0, 'origin': [x0, y0]}}),
        'destination': {'x': d.x, 'y': d.y, 'goal_radius': d.goal_radius},
        'short_obstacles': [box(b) for b in arena.short_obstacles],
        'tall_obstacles': [box(b) for b in arena.tall_obstacles],
        'landmarks': [{'name': m.name, 'colour': m.colour, 'x': m.x, 'y': m.y}
                      for m in arena.landmarks],
        'starts': {st.name: {'x': st.x, 'y': st.y, 'heading_deg': st.heading_deg}
                   for st in arena.starts},
    }
