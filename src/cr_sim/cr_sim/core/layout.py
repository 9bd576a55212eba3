"""Arena layouts drawn from a seed, and the paper's start situations checked geometrically.

:func:`generate_layout` draws a layout of the paper's kind (Sec. III, Fig. 2c) from a
:class:`numpy.random.Generator`: a 3 m x 3 m floor, 4 short and 2 tall box obstacles, one
coloured landmark on each wall, a destination, and five starts A-E in the paper's situations;
:func:`layout_yaml` writes it in the format of ``config/arena.yaml`` (read back by
:func:`cr_sim.core.arena.parse_arena`). The same seed gives the same text, to the byte.

The situations (:func:`start_situations`), with "visible" meaning what the simulator's
omni-camera means: the segment robot -> destination enters no tall obstacle (short obstacles
and walls hide nothing; :func:`cr_sim.core.geometry.segments_blocked`, the same slab test as
the camera kernel) and the destination is within ``camera_range``:

* A, B, C: the destination is visible and the robot's disc can drive the straight line to it
  (the segment is at least the robot radius from every obstacle);
* D: the destination is visible, but the straight line crosses a short obstacle (the innate
  policy, "head straight", bumps into it), and it is at least the robot radius from every
  tall one;
* E: a tall obstacle stands on the straight line: the destination is hidden at the start.

Beyond the situations the generator keeps every obstacle at least :func:`passage` (the robot's
diameter and a margin) from every other obstacle and from the walls, so the obstacles never
overlap and the free floor is one connected region: every start can reach the destination.
Positions are on a 1 cm grid and headings (toward the destination) on 0.1 degree, so the text
holds the exact values that were checked.

:func:`hidden_share` is the share of the free floor (where the robot's disc fits) from which
the destination is hidden: how much of the task the view module cannot see.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from cr_sim.core.arena import Arena, ArenaError, parse_arena
from cr_sim.core.geometry import segment_box_distance, segments_blocked

__all__ = ['SIZE', 'GOAL_RADIUS', 'LANDMARKS', 'Layout', 'passage', 'generate_layout',
           'layout_for_seed', 'layout_yaml', 'start_situations', 'situation_problems',
           'hidden_share', 'SITUATIONS']

#: Side of the square floor [m] (the paper's 3 m x 3 m field).
SIZE = 3.0
#: Goal radius of the destination [m] (config/arena.yaml's).
GOAL_RADIUS = 0.15
#: Landmarks, one per wall: (name, colour, wall), in the order of config/arena.yaml.
LANDMARKS = (('L1', 'red', 'east'), ('L2', 'green', 'north'), ('L3', 'blue', 'west'),
             ('L4', 'yellow', 'south'))
#: The situation each start name stands for (what :func:`start_situations` checks).
SITUATIONS = {'A': 'clear', 'B': 'clear', 'C': 'clear', 'D': 'short_across', 'E': 'hidden'}
#: Margin beyond the robot's diameter between obstacles, and between an obstacle and a wall [m].
_MARGIN = 0.08
#: Smallest distance of a start to the destination [m] (A-E of arena.yaml: 1.2-1.6 m).
_MIN_TO_GOAL = 0.9
#: Smallest distance between two starts [m].
_MIN_BETWEEN = 0.6
#: Free room around a start beyond the robot radius [m] (room to turn).
_START_ROOM = 0.05
#: Tries per object before the layout is drawn again, and layouts before giving up.
_TRIES, _ATTEMPTS = 400, 200


def passage(robot_radius: float) -> float:
    """Smallest gap between two obstacles and between an obstacle and a wall [m]: the robot's
    diameter and a margin, so that the disc passes everywhere between them."""
    return 2.0 * robot_radius + _MARGIN


@dataclass(frozen=True)
class Layout:
    """A generated layout: the arena-file mapping and what the generator knows of it.

    Attributes
    ----------
    data : dict
        The mapping of an arena file (``config/arena.yaml``'s keys).
    seed : int or None
        The seed it was drawn from (None: an injected generator).
    crossing : tuple of str
        The short obstacles the straight line D -> destination crosses.
    hiding : tuple of str
        The tall obstacles that hide the destination from E.
    hidden : float
        :func:`hidden_share` of the layout.
    """

    data: dict
    seed: int | None
    crossing: tuple[str, ...]
    hiding: tuple[str, ...]
    hidden: float


# ------------------------------------------------------------------------------------------
# geometry of a candidate layout

def _box(center: tuple[float, float], size: tuple[float, float]) -> np.ndarray:
    """``[[lo_x, lo_y], [hi_x, hi_y]]`` of a box."""
    return np.array([[center[0] - size[0] / 2, center[1] - size[1] / 2],
                     [center[0] + size[0] / 2, center[1] + size[1] / 2]])


def _box_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between two axis-aligned boxes (0 when they touch or overlap)."""
    dx = max(b[0, 0] - a[1, 0], a[0, 0] - b[1, 0], 0.0)
    dy = max(b[0, 1] - a[1, 1], a[0, 1] - b[1, 1], 0.0)
    return math.hypot(dx, dy)


def _wall_gap(box: np.ndarray, half: float) -> float:
    """Distance from a box to the nearest wall of the square floor ``[-half, half]^2``."""
    return float(min(box[0, 0] + half, box[0, 1] + half, half - box[1, 0], half - box[1, 1]))


def _point_gap(x: float, y: float, box: np.ndarray) -> float:
    """Distance from a point to a box (0 inside)."""
    dx = max(box[0, 0] - x, 0.0, x - box[1, 0])
    dy = max(box[0, 1] - y, 0.0, y - box[1, 1])
    return math.hypot(dx, dy)


def _cm(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A value on the 1 cm grid in ``[lo, hi]`` (k / 100 is the double the text reads back)."""
    return int(rng.integers(math.ceil(lo * 100 - 1e-9), math.floor(hi * 100 + 1e-9) + 1)) / 100


# ------------------------------------------------------------------------------------------
# the situations

def _blocked(x: float, y: float, dest: tuple[float, float], boxes: np.ndarray) -> bool:
    return bool(len(boxes)) and bool(segments_blocked(x, y, np.array([dest]), boxes)[0])


def _clearance(x: float, y: float, dest: tuple[float, float], boxes: np.ndarray) -> float:
    """Distance from the segment (x, y) -> dest to the nearest of ``boxes`` (inf: none)."""
    return min((segment_box_distance((x, y), dest, b[0], b[1]) for b in boxes),
               default=math.inf)


def _situation(kind: str, x: float, y: float, dest: tuple[float, float], tall: np.ndarray,
               short: np.ndarray, radius: float, camera_range: float) -> str:
    """'' when (x, y) is in situation ``kind`` (:data:`SITUATIONS`), else why not."""
    far = math.hypot(dest[0] - x, dest[1] - y) > camera_range
    hidden = far or _blocked(x, y, dest, tall)
    if kind == 'hidden':
        return '' if _blocked(x, y, dest, tall) else 'no tall obstacle hides the destination'
    if hidden:
        return 'the destination is hidden'
    if kind == 'clear':
        c = _clearance(x, y, dest, np.concatenate([tall, short]))
        return '' if c >= radius else (f'the straight line passes {c:.3f} m from an obstacle '
                                       f'(< the robot radius {radius} m)')
    if kind == 'short_across':
        if not _blocked(x, y, dest, short):
            return 'the straight line crosses no short obstacle'
        c = _clearance(x, y, dest, tall)
        return '' if c >= radius else (f'the straight line passes {c:.3f} m from a tall '
                                       f'obstacle (< the robot radius {radius} m)')
    raise ValueError(f'unknown situation {kind!r}: one of {", ".join(set(SITUATIONS.values()))}')


def start_situations(arena: Arena, robot_radius: float, camera_range: float = math.inf
                     ) -> dict[str, str]:
    """Check each start named in :data:`SITUATIONS` against its situation.

    Parameters
    ----------
    arena : Arena
    robot_radius : float
        Radius of the robot's disc [m] (the clearance of a straight line).
    camera_range : float
        Targets farther than this are not seen [m] (``sensors.camera_range``).

    Returns
    -------
    dict
        ``{start: ''}`` when it is in its situation, ``{start: why not}`` otherwise; a start of
        :data:`SITUATIONS` missing from the arena is reported as missing.
    """
    d = arena.destination
    tall = arena.box_array(tall_only=True)
    short = arena.box_array()[len(arena.tall_obstacles):]
    out = {}
    for name, kind in SITUATIONS.items():
        if name not in arena.start_names:
            out[name] = 'no such start'
            continue
        s = arena.start(name)
        out[name] = _situation(kind, s.x, s.y, (d.x, d.y), tall, short, robot_radius,
                               camera_range)
    return out


def situation_problems(arena: Arena, robot_radius: float, camera_range: float = math.inf
                       ) -> list[str]:
    """The starts not in their situation, as ``'D: why'`` lines (empty: all are)."""
    return [f'{name} ({SITUATIONS[name]}): {why}' for name, why in
            start_situations(arena, robot_radius, camera_range).items() if why]


def hidden_share(arena: Arena, robot_radius: float, resolution: float = 0.05,
                 camera_range: float = math.inf) -> float:
    """Share of the free floor from which the destination is hidden from the camera.

    The floor is sampled at the centres of ``resolution`` cells; a cell is free when the
    robot's disc centred there touches no obstacle and no wall, and the destination is hidden
    from it when the segment between them enters a tall obstacle (or is longer than
    ``camera_range``).

    Returns
    -------
    float
        Hidden free cells / free cells, in [0, 1].
    """
    x0, y0, x1, y1 = arena.bounds
    xs = np.arange(x0 + resolution / 2, x1, resolution)
    ys = np.arange(y0 + resolution / 2, y1, resolution)
    px, py = (a.ravel() for a in np.meshgrid(xs, ys))
    gap = np.minimum(np.minimum(px - x0, x1 - px), np.minimum(py - y0, y1 - py))
    for b in arena.box_array():
        dx = np.maximum(np.maximum(b[0, 0] - px, px - b[1, 0]), 0.0)
        dy = np.maximum(np.maximum(b[0, 1] - py, py - b[1, 1]), 0.0)
        gap = np.minimum(gap, np.hypot(dx, dy))
    free = gap >= robot_radius
    d = arena.destination
    cells = np.stack([px[free], py[free]], axis=1)
    tall = arena.box_array(tall_only=True)
    hidden = (segments_blocked(d.x, d.y, cells, tall) if len(tall)
              else np.zeros(len(cells), bool))
    hidden |= np.hypot(cells[:, 0] - d.x, cells[:, 1] - d.y) > camera_range
    return float(hidden.sum() / max(len(cells), 1))


# ------------------------------------------------------------------------------------------
# the generator

def _place_box(rng: np.random.Generator, placed: list[np.ndarray], dest: tuple[float, float],
               radius: float, size: tuple[float, float],
               near: tuple[float, float] | None) -> np.ndarray | None:
    """A box of ``size`` at least :func:`passage` from the walls, the boxes ``placed`` and the
    destination's disc; centred 0.35-0.7 m from the destination when ``near`` (a unit
    direction: the box then stands on that side of it), else anywhere. None: no room found."""
    half, gap = SIZE / 2, passage(radius)
    for _ in range(_TRIES):
        if near is None:
            c = (_cm(rng, -half, half), _cm(rng, -half, half))
        else:
            r = _cm(rng, 0.35, 0.7)
            c = (round(dest[0] + r * near[0], 2), round(dest[1] + r * near[1], 2))
        box = _box(c, size)
        if _wall_gap(box, half) < gap or _point_gap(*dest, box) < gap:
            continue
        if all(_box_gap(box, other) >= gap for other in placed):
            return box
    return None


def _draw_start(rng: np.random.Generator, kind: str, dest: tuple[float, float],
                tall: np.ndarray, short: np.ndarray, taken: list[tuple[float, float]],
                radius: float) -> tuple[float, float] | None:
    """A start position in situation ``kind``, free, far enough from the destination and from
    the starts ``taken``; None when none was found."""
    half = SIZE / 2
    boxes = np.concatenate([tall, short])
    lim = half - radius - _START_ROOM
    for _ in range(_TRIES):
        x, y = _cm(rng, -lim, lim), _cm(rng, -lim, lim)
        if math.hypot(x - dest[0], y - dest[1]) < _MIN_TO_GOAL:
            continue
        if any(math.hypot(x - a, y - b) < _MIN_BETWEEN for a, b in taken):
            continue
        if min(_point_gap(x, y, b) for b in boxes) < radius + _START_ROOM:
            continue
        if not _situation(kind, x, y, dest, tall, short, radius, math.inf):
            return x, y
    return None


def _heading(x: float, y: float, dest: tuple[float, float]) -> float:
    """Heading toward the destination [deg], on 0.1 degree."""
    return round(math.degrees(math.atan2(dest[1] - y, dest[0] - x)), 1) + 0.0


def _attempt(rng: np.random.Generator, radius: float) -> dict | None:
    """One draw of a whole layout (None: some object found no room; draw again)."""
    dest = (_cm(rng, -0.8, 0.8), _cm(rng, -0.8, 0.8))
    # T1 and S1 on two sides of the destination (E's and D's situations nearby), then the
    # others anywhere
    a_t = float(rng.uniform(-math.pi, math.pi))
    a_s = a_t + float(rng.uniform(math.pi / 2, 3 * math.pi / 2))
    placed: list[np.ndarray] = []
    tall, short = [], []
    for k in range(2):
        size = (_cm(rng, 0.15, 0.3), _cm(rng, 0.15, 0.3))
        near = (math.cos(a_t), math.sin(a_t)) if k == 0 else None
        box = _place_box(rng, placed, dest, radius, size, near)
        if box is None:
            return None
        placed.append(box)
        tall.append((f'T{k + 1}', box, size))
    for k in range(4):
        length, thick = _cm(rng, 0.3, 0.6), 0.1
        if k == 0:       # across the direction a_s: the long side perpendicular to it
            near = (math.cos(a_s), math.sin(a_s))
            vertical = abs(near[0]) >= abs(near[1])
        else:
            near, vertical = None, bool(rng.integers(2))
        size = (thick, length) if vertical else (length, thick)
        box = _place_box(rng, placed, dest, radius, size, near)
        if box is None:
            return None
        placed.append(box)
        short.append((f'S{k + 1}', box, size))
    tall_arr = np.array([b for _, b, _ in tall])
    short_arr = np.array([b for _, b, _ in short])
    starts: dict[str, tuple[float, float]] = {}
    for name in ('E', 'D', 'A', 'B', 'C'):
        p = _draw_start(rng, SITUATIONS[name], dest, tall_arr, short_arr,
                        list(starts.values()), radius)
        if p is None:
            return None
        starts[name] = p
    landmarks = []
    for name, colour, wall in LANDMARKS:
        along = round(float(rng.integers(-24, 25)) * 0.05, 2) + 0.0     # 5 cm steps, +-1.2 m
        x, y = {'east': (SIZE / 2, along), 'north': (along, SIZE / 2),
                'west': (-SIZE / 2, along), 'south': (along, -SIZE / 2)}[wall]
        landmarks.append({'name': name, 'colour': colour, 'x': x, 'y': y})

    def boxes(items: list) -> list[dict]:
        return [{'name': n, 'center': [round(float(b[:, 0].mean()), 2) + 0.0,
                                       round(float(b[:, 1].mean()), 2) + 0.0],
                 'size': [s[0], s[1]]} for n, b, s in items]

    return {
        'size': SIZE,
        'destination': {'x': dest[0], 'y': dest[1], 'goal_radius': GOAL_RADIUS},
        'short_obstacles': boxes(short), 'tall_obstacles': boxes(tall), 'landmarks': landmarks,
        'starts': {n: {'x': starts[n][0], 'y': starts[n][1],
                       'heading_deg': _heading(*starts[n], dest)} for n in 'ABCDE'}}


def generate_layout(rng: np.random.Generator, robot_radius: float,
                    seed: int | None = None) -> Layout:
    """Draw a layout (module docstring) from ``rng``.

    Parameters
    ----------
    rng : np.random.Generator
        Every random choice comes from it, in a fixed order.
    robot_radius : float
        Radius of the robot's disc [m]: the passages and the straight lines' clearance.
    seed : int, optional
        Recorded in the :class:`Layout` (and the file's header).

    Returns
    -------
    Layout
        Validated by :func:`~cr_sim.core.arena.parse_arena` and by :func:`start_situations`.

    Raises
    ------
    ArenaError
        No layout found in a few hundred attempts (a robot too big for the floor).
    """
    for _ in range(_ATTEMPTS):
        data = _attempt(rng, robot_radius)
        if data is None:
            continue
        # what the text will hold: the center of a box is read back from the file
        arena = parse_arena(data, robot_radius, source=f'layout seed {seed}')
        problems = situation_problems(arena, robot_radius)
        if problems:
            continue        # a box centre rounded onto the line: draw again
        d = arena.destination
        s, e = arena.start('D'), arena.start('E')
        short = arena.box_array()[len(arena.tall_obstacles):]
        crossing = tuple(b.name for b, lohi in zip(arena.short_obstacles, short)
                         if _blocked(s.x, s.y, (d.x, d.y), lohi[None]))
        hiding = tuple(b.name for b in arena.tall_obstacles
                       if _blocked(e.x, e.y, (d.x, d.y), np.array([[b.lo, b.hi]])))
        return Layout(data=data, seed=seed, crossing=crossing, hiding=hiding,
                      hidden=hidden_share(arena, robot_radius))
    raise ArenaError(f'no layout found for seed {seed} with a robot of radius {robot_radius} m '
                     f'in {_ATTEMPTS} attempts')


def layout_for_seed(seed: int, robot_radius: float) -> Layout:
    """:func:`generate_layout` with the generator of ``seed``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f'a layout seed is an integer >= 0, not {seed!r}')
    return generate_layout(np.random.default_rng(int(seed)), robot_radius, seed=int(seed))


def _num(v: float) -> str:
    """A coordinate as the text holds it (2 decimals: the 1 cm grid)."""
    return f'{v:.2f}'


def _box_line(b: Mapping[str, Any]) -> str:
    return (f'  - {{name: {b["name"]}, center: [{_num(b["center"][0])}, {_num(b["center"][1])}]'
            f', size: [{_num(b["size"][0])}, {_num(b["size"][1])}]}}')


def layout_yaml(layout: Layout, command: str = 'clis arena generate') -> str:
    """The layout as an arena file (``config/arena.yaml``'s format), with a header comment
    naming the seed, the command that writes it and the situations of its starts."""
    d = layout.data
    seed = '' if layout.seed is None else f' --seed {layout.seed}'
    crossing, hiding = layout.crossing, layout.hiding
    lines = [
        f'# Arena generated by `{command}{seed}` (cr_sim.core.layout), in the format',
        '# of config/arena.yaml. The same seed gives this file again, to the byte.',
        '#',
        f'# A {SIZE:g} m x {SIZE:g} m floor; {len(d["short_obstacles"])} short and '
        f'{len(d["tall_obstacles"])} tall obstacles, each at least',
        "# the robot's diameter from the others and from the walls (the free floor is",
        "# connected); a landmark on each wall. The starts are in the paper's situations:",
        '#   A, B, C  the straight line to the destination is clear, the destination visible',
        f'#   D        the straight line to the destination crosses short obstacle'
        f'{"s" if len(crossing) > 1 else ""} {", ".join(crossing)}',
        f'#   E        tall obstacle{"s" if len(hiding) > 1 else ""} {", ".join(hiding)} '
        f'hide{"" if len(hiding) > 1 else "s"} the destination',
        f'# The destination is hidden from {100 * layout.hidden:.1f}% of the free floor.',
        '',
        f'size: {d["size"]:.1f}',
        '',
        'destination:',
        f'  x: {_num(d["destination"]["x"])}',
        f'  y: {_num(d["destination"]["y"])}',
        f'  goal_radius: {_num(d["destination"]["goal_radius"])}',
        '',
        'short_obstacles:',
        *(_box_line(b) for b in d['short_obstacles']),
        '',
        'tall_obstacles:',
        *(_box_line(b) for b in d['tall_obstacles']),
        '',
        'landmarks:',
        *(f'  - {{name: {lm["name"]}, colour: {lm["colour"]}, x: {_num(lm["x"])}, '
          f'y: {_num(lm["y"])}}}' for lm in d['landmarks']),
        '',
        'starts:',
        *(f'  {n}: {{x: {_num(s["x"])}, y: {_num(s["y"])}, heading_deg: '
          f'{s["heading_deg"]:.1f}}}' for n, s in d['starts'].items()),
    ]
    return '\n'.join(lines) + '\n'
