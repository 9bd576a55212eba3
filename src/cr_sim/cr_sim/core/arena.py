"""The arena: floor, walls, destination, obstacles, landmarks and start poses, from a YAML file.

The layout is data (``config/arena.yaml``, format documented at the top of that file), never
code. :func:`load_arena` reads and validates a file; :func:`parse_arena` does the same for a
mapping already in memory. Every error is an :class:`ArenaError` (a ``ConfigError``) whose
message names the file, the key and the object at fault.

Frame: metres, floor centred at the origin, x to the east, y to the north, headings
counter-clockwise from +x. The walls are the border of ``[-size/2, size/2]^2``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from cr_sim.core.geometry import disc_gap, wall_boxes
from cr_sim.core.params import ConfigError, config_dir, load_yaml

__all__ = [
    'ArenaError', 'Box', 'Destination', 'Landmark', 'Start', 'Arena', 'load_arena',
    'parse_arena', 'ARENA_KEYS',
]

#: Top-level keys of an arena file (all required).
ARENA_KEYS = ('size', 'destination', 'short_obstacles', 'tall_obstacles', 'landmarks', 'starts')


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
    """A validated arena layout (see ``config/arena.yaml``)."""

    size: float
    destination: Destination
    short_obstacles: tuple[Box, ...]
    tall_obstacles: tuple[Box, ...]
    landmarks: tuple[Landmark, ...]
    starts: tuple[Start, ...]
    source: str = '<memory>'

    @property
    def half(self) -> float:
        """Half the side: the walls are at x, y = +-half [m]."""
        return 0.5 * self.size

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
        return np.concatenate([arr, wall_boxes(self.half)]) if walls else arr

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
                     for b in wall_boxes(self.half, thickness))

    def gap(self, x: float, y: float, radius: float) -> float:
        """Free distance of a disc at (x, y) to the nearest obstacle or wall [m] (< 0: overlap)."""
        return disc_gap(x, y, radius, self.box_tuples(), self.half)

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
        if min(self.half - abs(x), self.half - abs(y)) < radius:
            return 'the wall'
        for b in self.obstacles:
            if disc_gap(x, y, radius, ((*b.lo, *b.hi),), math.inf) < 0.0:
                return f'{"tall" if b.tall else "short"} obstacle {b.name!r}'
        return ''


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


def _boxes(items: Any, key: str, tall: bool, half: float) -> tuple[Box, ...]:
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
        if min(box.lo) < -half - eps or max(box.hi) > half + eps:
            raise ArenaError(
                f'{"tall" if tall else "short"} obstacle {box.name!r} ({key}[{i}]) spans '
                f'x in [{box.lo[0]:g}, {box.hi[0]:g}], y in [{box.lo[1]:g}, {box.hi[1]:g}]: '
                f'(partly) outside the walls at +-{half:g} m')
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


def _parse(data: Mapping[str, Any], robot_radius: float, source: str) -> Arena:
    top = _fields(data, '', ARENA_KEYS)
    size = _number(top['size'], 'size', lo=0.0, hi=100.0, lo_open=True)
    half = 0.5 * size

    d = _fields(top['destination'], 'destination', ('x', 'y', 'goal_radius'))
    dest = Destination(x=_number(d['x'], 'destination.x', -half, half),
                       y=_number(d['y'], 'destination.y', -half, half),
                       goal_radius=_number(d['goal_radius'], 'destination.goal_radius',
                                           0.0, size, lo_open=True))

    short = _boxes(top['short_obstacles'], 'short_obstacles', False, half)
    tall = _boxes(top['tall_obstacles'], 'tall_obstacles', True, half)
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
        if max(abs(lm.x), abs(lm.y)) > half + 1e-12:
            raise ArenaError(f'landmark {lm.name!r} at ({lm.x}, {lm.y}) is outside the walls '
                             f'at +-{half:g} m (put it on or inside the wall)')
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

    arena = Arena(size=size, destination=dest, short_obstacles=short, tall_obstacles=tall,
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
        ``sim.yaml``.

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
        from cr_sim.core.sim import load_sim_params  # lazy: sim imports this module
        robot_radius = load_sim_params().robot.radius
    try:
        data = load_yaml(p)
    except ArenaError:
        raise
    except ConfigError as exc:
        raise ArenaError(str(exc)) from None
    return parse_arena(data, robot_radius, source=str(p))
