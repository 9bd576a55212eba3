"""The simulator's camera as an image: an RGB frame of the arena from a pose, one ray a column.

Model (2.5D: the world is the floor plane with vertical prisms standing on it)
------------------------------------------------------------------------------
* The walls (``wall_height``), the tall obstacles (``tall_height``, above the camera) and the
  short obstacles (``short_height``, below it) are the axis-aligned boxes of the
  :class:`~cr_sim.core.arena.Arena`; the destination and each landmark are vertical cylinders
  of radius ``target_radius`` (heights ``destination_height``, ``landmark_height``), coloured
  by the arena file's colour name (:data:`COLOURS`; '#rrggbb' also reads; any other name: the
  landmark's colour of :data:`PALETTE`, by its index), the destination
  :data:`DESTINATION_COLOUR`.
* The camera stands at ``camera_height`` on the robot's centre and looks horizontally through
  a :mod:`cr_sim.core.camera` model. Column ``u`` casts one ray from ``(x, y)`` at
  ``theta + bearing(u)`` (:func:`cr_sim.core.geometry.slab`): ``t_wall``, ``t_tall``,
  ``t_short``, the range [m] to the first wall, tall and short obstacle, and ``t_k`` to the
  entry into each target's disc ``|p - c_k| <= r``::

      t_k = (c_k - o) . d - sqrt(r^2 - |(c_k - o) x d|^2)     (d a unit vector)

* A surface of height ``z1`` standing on the floor at range ``t`` covers the rows (pinhole
  height model: ``rows = f * height / depth``, depth ``D = t * depth_per_range(u)``, camera
  height ``h``)::

      cy - fy (z1 - h) / D  <=  v  <=  cy + fy h / D

* Painted far to near in each column: the sky above the horizon and the floor below it (two
  tones in 0.5 m squares, darker with range), the wall, the tall obstacle where
  ``t_tall < t_wall``, the short obstacle where nearer than both, then the targets from the
  farthest to the nearest, each where ``t_k < t_tall`` and its centre is within
  ``camera_range`` (the destination: ``destination_range``, when not 0), shaded across the
  cylinder (the colour scaled by 0.55 to 1: hue and saturation unchanged).

Occlusion as in the simulator's camera (:mod:`cr_sim.core.sim`): a tall obstacle hides what
stands behind it in its columns; short obstacles hide nothing (they are drawn before the
targets, so never over one); the walls are the backdrop: a landmark on a wall is a post
against it, drawn whole, as the simulator's walls hide nothing. Deterministic: no randomness.
The camera inside a target's disc does not see that target.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from cr_sim.core.arena import Arena
from cr_sim.core.camera import CameraModel
from cr_sim.core.geometry import slab

__all__ = [
    'COLOURS', 'PALETTE', 'DESTINATION_COLOUR', 'RenderParams', 'Scene', 'colour_rgb',
    'render',
]

#: RGB of the colour names of an arena file (saturated: a blob detector's hues).
COLOURS: dict[str, tuple[int, int, int]] = {
    'red': (220, 40, 40), 'orange': (245, 140, 30), 'yellow': (235, 210, 40),
    'green': (40, 170, 60), 'cyan': (40, 200, 220), 'blue': (40, 80, 230),
    'purple': (130, 50, 200), 'magenta': (220, 50, 220),
}
#: Landmark k's colour when the arena's name is none of :data:`COLOURS` (k modulo 7).
PALETTE = ('red', 'green', 'blue', 'yellow', 'cyan', 'orange', 'purple')
#: The destination's colour (no landmark's of :data:`PALETTE`).
DESTINATION_COLOUR = 'magenta'

_SKY = np.array((200, 206, 216), dtype=np.float64)
_FLOOR = np.array(((150, 140, 122), (132, 123, 108)), dtype=np.float64)   # two tones
_WALL = np.array((175.0, 145.0))         # grey of the walls facing x, facing y
_TALL = np.array(((72, 74, 92), (56, 58, 74)), dtype=np.float64)
_SHORT = np.array(((128, 116, 96), (108, 98, 82)), dtype=np.float64)
_SQUARE = 0.5                            # [m] side of the floor's squares
_FADE = 6.0                              # [m] range at which a shade reaches 60 %


@dataclass(frozen=True)
class RenderParams:
    """Heights and sizes of the rendered world [m], and how far the camera sees a target.

    Attributes
    ----------
    target_radius : float
        Radius of the landmark and destination cylinders, in (0, 1].
    camera_height : float
        Height of the camera's centre, between ``short_height`` and ``tall_height``.
    wall_height, tall_height, short_height : float
        Heights of the walls and of the obstacles, in (0, 10].
    landmark_height, destination_height : float
        Heights of the target cylinders, in (0, 10]. Both above the camera by default: a
        post that crosses the horizon is in the image at any range, as the simulator's camera
        sees its bearing (a destination lower than the camera would leave the strip's rows
        near the goal, where the reached rule of a profile measures its apparent width).
    camera_range : float
        A target whose centre is farther is not drawn, in [0.1, 100] (the simulator's
        ``sensors.camera_range``).
    destination_range : float
        The same for the destination, in [0, 100]; 0: ``camera_range``.
    """

    target_radius: float = 0.04
    camera_height: float = 0.15
    wall_height: float = 0.3
    tall_height: float = 0.5
    short_height: float = 0.1
    landmark_height: float = 0.5
    destination_height: float = 0.3
    camera_range: float = 5.0
    destination_range: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            lo, hi, lo_open = _RANGES[f.name]
            v = getattr(self, f.name)
            number = isinstance(v, (int, float)) and not isinstance(v, bool)
            if not number or not (lo < v <= hi if lo_open else lo <= v <= hi):
                raise ValueError(f'{f.name} = {v!r} is out of range: must be in '
                                 f'{"(" if lo_open else "["}{lo:g}, {hi:g}]')
        if not self.short_height < self.camera_height < self.tall_height:
            raise ValueError(f'camera_height = {self.camera_height!r} is out of range: must '
                             f'be in (short_height, tall_height) = ({self.short_height:g}, '
                             f'{self.tall_height:g})')


#: Allowed range of each field of RenderParams: (lo, hi, lo excluded).
_RANGES = {'target_radius': (0.0, 1.0, True), 'camera_height': (0.0, 10.0, True),
           'wall_height': (0.0, 10.0, True), 'tall_height': (0.0, 10.0, True),
           'short_height': (0.0, 10.0, True), 'landmark_height': (0.0, 10.0, True),
           'destination_height': (0.0, 10.0, True), 'camera_range': (0.1, 100.0, False),
           'destination_range': (0.0, 100.0, False)}


def colour_rgb(name: str, index: int = 0) -> tuple[int, int, int]:
    """RGB of an arena file's colour: a name of :data:`COLOURS`, or '#rrggbb'; any other
    name: ``PALETTE[index % 7]``."""
    key = name.strip().lower()
    if key in COLOURS:
        return COLOURS[key]
    if len(key) == 7 and key[0] == '#':
        try:
            return (int(key[1:3], 16), int(key[3:5], 16), int(key[5:7], 16))
        except ValueError:
            pass
    return COLOURS[PALETTE[index % len(PALETTE)]]


@dataclass(frozen=True, eq=False)
class Scene:
    """What the renderer reads of an arena (:meth:`from_arena`).

    Attributes
    ----------
    names : tuple of str, length T
        ``'destination'``, then the landmarks' names (the order of the ``camera`` topic).
    centres : np.ndarray, shape (T, 2)
        Cylinder axes ``(x, y)`` [m].
    heights, ranges : np.ndarray, shape (T,)
        Cylinder heights; the farthest each is drawn [m].
    colours : np.ndarray, shape (T, 3), float
        RGB in [0, 255].
    walls, tall, short : np.ndarray, shapes (4, 2, 2), (Bt, 2, 2), (Bs, 2, 2)
        Boxes ``lohi`` (:mod:`cr_sim.core.geometry`).
    params : RenderParams
    """

    names: tuple[str, ...]
    centres: np.ndarray
    heights: np.ndarray
    ranges: np.ndarray
    colours: np.ndarray
    walls: np.ndarray
    tall: np.ndarray
    short: np.ndarray
    params: RenderParams

    @classmethod
    def from_arena(cls, arena: Arena, params: RenderParams | None = None) -> Scene:
        """The scene of ``arena`` with ``params`` (default :class:`RenderParams`)."""
        p = params if params is not None else RenderParams()
        d = arena.destination
        lms = arena.landmarks
        n_obst = len(arena.obstacles)
        return cls(
            names=('destination',) + tuple(lm.name for lm in lms),
            centres=np.array([[d.x, d.y]] + [[lm.x, lm.y] for lm in lms], dtype=np.float64),
            heights=np.array([p.destination_height] + [p.landmark_height] * len(lms)),
            ranges=np.array([p.destination_range or p.camera_range]
                            + [p.camera_range] * len(lms)),
            colours=np.array([COLOURS[DESTINATION_COLOUR]]
                             + [colour_rgb(lm.colour, k) for k, lm in enumerate(lms)],
                             dtype=np.float64),
            walls=arena.box_array(walls=True)[n_obst:],
            tall=arena.box_array(tall_only=True),
            short=np.array(arena.short_boxes(), dtype=np.float64).reshape(-1, 2, 2),
            params=p)


@lru_cache(maxsize=32)
def _columns(camera: CameraModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per column: bearing [rad], depth per metre of range; the rows, shape (H, 1); the
    column indices, shape (W,)."""
    u = np.arange(camera.width)
    out = (np.asarray(camera.bearing_of_column(u)), np.asarray(camera.depth_per_range(u)),
           np.arange(camera.height, dtype=np.float64)[:, None], u)
    for a in out:
        a.flags.writeable = False                 # shared by every frame of this camera
    return out


def _first_hit(px: float, py: float, d: np.ndarray, lohi: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Range to the first box along each ray, and whether it enters through an x face.

    Returns
    -------
    t : np.ndarray, shape (R,)
        ``inf`` where the ray meets no box.
    x_face : np.ndarray, shape (R,), bool
    """
    if len(lohi) == 0:
        return np.full(len(d), np.inf), np.zeros(len(d), dtype=bool)
    t_near, t_far = slab(px, py, d, lohi)
    t_all = np.where((t_near <= t_far) & (t_near >= 0.0), t_near, np.inf)
    k = np.argmin(t_all, axis=1)
    t = t_all[np.arange(len(d)), k]
    hx = px + np.where(np.isfinite(t), t, 0.0) * d[:, 0]
    hy = py + np.where(np.isfinite(t), t, 0.0) * d[:, 1]
    box = lohi[k]                                                       # (R, 2, 2)
    gap_x = np.minimum(np.abs(hx - box[:, 0, 0]), np.abs(hx - box[:, 1, 0]))
    gap_y = np.minimum(np.abs(hy - box[:, 0, 1]), np.abs(hy - box[:, 1, 1]))
    return t, gap_x < gap_y


def _span(rows: np.ndarray, cy: float, fy: float, depth: np.ndarray, z1: float, h: float
          ) -> np.ndarray:
    """Pixels covered by a vertical span from the floor to ``z1`` at ``depth`` in each
    column (camera at height ``h``).

    Parameters
    ----------
    rows : np.ndarray, shape (H, 1)
    depth : np.ndarray, shape (W,)
        ``inf`` or NaN: nothing covered.

    Returns
    -------
    np.ndarray, shape (H, W), bool
    """
    with np.errstate(invalid='ignore', divide='ignore'):
        inv = np.where(np.isfinite(depth), 1.0 / np.maximum(depth, 1e-9), np.nan)
        top = cy - fy * (z1 - h) * inv
        bottom = cy + fy * h * inv
        return (rows >= top) & (rows <= bottom)


def _shade(fade: np.ndarray) -> np.ndarray:
    """Brightness factor of a surface at range ``fade`` [m]: 1 near, 0.6 at ``_FADE``."""
    return 1.0 - 0.4 * np.minimum(fade / _FADE, 1.0)


def render(scene: Scene, camera: CameraModel, pose: ArrayLike) -> np.ndarray:
    """The camera's image of ``scene`` from ``pose`` (module docstring for the model).

    Parameters
    ----------
    scene : Scene
        From :meth:`Scene.from_arena`.
    camera : Pinhole or Panoramic
        Image size, column bearings and vertical scale (:mod:`cr_sim.core.camera`).
    pose : array_like, shape (3,)
        ``(x, y, theta)`` of the robot [m, m, rad].

    Returns
    -------
    np.ndarray, shape (H, W, 3), uint8
        RGB, row 0 at the top, column 0 at the left (``camera.height``, ``camera.width``).
    """
    px, py, th = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(3))
    p = scene.params
    h, fy, cy = p.camera_height, float(camera.fy), float(camera.cy)
    bearing, per_range, rows, u = _columns(camera)
    phi = th + bearing
    d = np.stack((np.cos(phi), np.sin(phi)), axis=1)                      # (W, 2)

    # sky and floor: the floor point of row v is at depth fy h / (v - cy)
    floor = rows > cy
    with np.errstate(divide='ignore'):
        floor_t = np.where(floor, fy * h / np.where(floor, rows - cy, 1.0), 0.0) / per_range
    floor_x = px + floor_t * d[:, 0]
    floor_y = py + floor_t * d[:, 1]
    tone = (np.floor(floor_x / _SQUARE) + np.floor(floor_y / _SQUARE)).astype(np.int64) & 1
    base = np.where(floor[..., None], _FLOOR[tone] * _shade(floor_t)[..., None], _SKY)

    # the surfaces: layer[v, u] = which one covers the pixel (-1: sky or floor), painted far
    # to near; colours[layer, u] its colour in that column
    layer = np.full((camera.height, camera.width), -1, dtype=np.int64)
    colours = []

    def paint(t: np.ndarray, z1: float, colour: np.ndarray) -> None:
        layer[_span(rows, cy, fy, t * per_range, z1, h)] = len(colours)
        colours.append(colour)

    t_wall, wall_x = _first_hit(px, py, d, scene.walls)
    grey = np.where(wall_x, _WALL[0], _WALL[1]) * _shade(t_wall)
    paint(t_wall, p.wall_height, np.repeat(grey[:, None], 3, axis=1))

    t_tall, tall_x = _first_hit(px, py, d, scene.tall)
    t_tall = np.where(t_tall < t_wall, t_tall, np.inf)
    paint(t_tall, p.tall_height, _TALL[np.where(tall_x, 0, 1)] * _shade(t_tall)[:, None])

    t_short, short_x = _first_hit(px, py, d, scene.short)
    t_short = np.where(t_short < np.minimum(t_wall, t_tall), t_short, np.inf)
    paint(t_short, p.short_height, _SHORT[np.where(short_x, 0, 1)] * _shade(t_short)[:, None])

    # targets: entry into each disc along each ray, painted from the farthest to the nearest
    rel = scene.centres - np.array((px, py))                              # (T, 2)
    dist = np.hypot(rel[:, 0], rel[:, 1])
    proj = d @ rel.T                                                      # (W, T)
    r = p.target_radius
    chord2 = r * r - (dist * dist - proj * proj)
    with np.errstate(invalid='ignore'):
        t_in = proj - np.sqrt(chord2)
    for k in np.argsort(-dist, kind='stable'):
        if dist[k] <= r or dist[k] > scene.ranges[k]:
            continue
        seen = (chord2[:, k] >= 0.0) & (t_in[:, k] > 0.0) & (t_in[:, k] < t_tall)
        if not seen.any():
            continue
        t = np.where(seen, t_in[:, k], np.inf)
        hit = d * np.where(seen, t, 0.0)[:, None] - rel[k]                # from the axis
        lambert = np.clip(-(hit * d).sum(axis=1) / r, 0.0, 1.0)
        paint(t, scene.heights[k], scene.colours[k] * (0.55 + 0.45 * lambert)[:, None])

    table = np.stack(colours)                                             # (L, W, 3)
    img = np.where((layer >= 0)[..., None], table[layer, u], base)
    return np.rint(img).astype(np.uint8)
