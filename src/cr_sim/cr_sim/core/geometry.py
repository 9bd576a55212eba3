"""2-D geometry of the arena: angle wrapping, rays and segments against boxes, disc contacts.

Every obstacle, and every wall, is an axis-aligned box ``[lo_x, hi_x] x [lo_y, hi_y]``. Boxes
are passed as one array ``lohi`` of shape (B, 2, 2): ``lohi[b, 0] = (lo_x, lo_y)`` and
``lohi[b, 1] = (hi_x, hi_y)``. The walls are four thick boxes just outside the floor
(:func:`wall_boxes`), so one routine handles obstacles and walls alike.

Ray/box intersection (the *slab* method). A ray ``p + t d`` (t >= 0) is inside the x-slab
``lo_x <= x <= hi_x`` for t between ``(lo_x - p_x) / d_x`` and ``(hi_x - p_x) / d_x`` (in
either order), and likewise for y. It is inside the box where both slab intervals overlap::

    t_near = max(min(tx0, tx1), min(ty0, ty1))      entry parameter
    t_far  = min(max(tx0, tx1), max(ty0, ty1))      exit parameter
    the line meets the box  <=>  t_near <= t_far

For a unit ``d`` the parameter t is a distance in metres; for ``d = target - p`` the segment
to the target is t in [0, 1]. Exact zeros in ``d`` are replaced by a tiny number so the
division never produces ``0 * inf = nan`` (the result then differs by ~1e-300 m).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    'TWO_PI', 'wrap_angle', 'wrap_angles', 'wall_boxes', 'box_planes', 'slab_planes', 'slab',
    'raycast', 'segments_blocked', 'point_box_distances', 'segment_box_distance', 'disc_gap',
]

TWO_PI = 2.0 * math.pi


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi].

    ``a + 2 pi floor((pi - a) / (2 pi))`` is ``a`` shifted by whole turns into (-pi, pi]
    (``pi`` stays ``pi``, ``-pi`` becomes ``pi``); the last line repairs the one-ulp overshoot
    that rounding can cause right at the boundary.
    """
    r = a + TWO_PI * math.floor((math.pi - a) / TWO_PI)
    return r - TWO_PI if r > math.pi else r


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Vectorised :func:`wrap_angle` (NaN stays NaN).

    ``np.remainder(pi - a, 2 pi)`` lies in [0, 2 pi] (2 pi only by rounding of a tiny negative
    remainder), so ``pi - remainder`` lies in (-pi, pi] once that one case is mapped to pi.

    Parameters
    ----------
    a : np.ndarray, shape (N,)

    Returns
    -------
    np.ndarray, shape (N,)
    """
    r = np.remainder(np.pi - a, TWO_PI)
    r[r >= TWO_PI] = 0.0
    return np.pi - r


def wall_boxes(half: float, thickness: float = 1.0) -> np.ndarray:
    """The four walls of the square floor ``[-half, half]^2`` as boxes outside it.

    Returns
    -------
    np.ndarray, shape (4, 2, 2)
        West, east, south, north walls, each ``thickness`` thick; they overlap at the corners.
    """
    h, o = half, half + thickness
    return np.array([
        [[-o, -o], [-h, o]],   # west  x <= -h
        [[h, -o], [o, o]],     # east  x >= h
        [[-o, -o], [o, -h]],   # south y <= -h
        [[-o, h], [o, o]],     # north y >= h
    ], dtype=np.float64)


def box_planes(lohi: np.ndarray) -> np.ndarray:
    """Re-layout boxes for :func:`slab_planes`.

    Parameters
    ----------
    lohi : np.ndarray, shape (B, 2, 2)

    Returns
    -------
    np.ndarray, shape (2, 2, B), contiguous
        ``planes[axis, lo/hi, b]``: the coordinates of the two faces of each box per axis.
    """
    return np.ascontiguousarray(np.asarray(lohi, dtype=np.float64).transpose(2, 1, 0))


def slab_planes(px: float, py: float, d_t: np.ndarray, planes: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Fast core of :func:`slab` (hot path of the sensor model): same result, other layout.

    Parameters
    ----------
    px, py : float
        Common origin of the rays.
    d_t : np.ndarray, shape (2, R)
        Ray directions, x components then y components.
    planes : np.ndarray, shape (2, 2, B)
        Boxes from :func:`box_planes`.

    Returns
    -------
    t_near, t_far : np.ndarray, shape (R, B)
    """
    # adding 1e-300 turns an exact 0 into a tiny number and leaves every other value unchanged
    inv = 1.0 / (d_t + 1e-300)                                         # (2, R)
    rel = planes - np.array((px, py)).reshape(2, 1, 1)                 # (2, 2, B)
    t = inv[:, None, :, None] * rel[:, :, None, :]                     # (axis, lo/hi, R, B)
    t_in = np.minimum(t[:, 0], t[:, 1])                                # slab entry per axis
    t_out = np.maximum(t[:, 0], t[:, 1])                               # slab exit per axis
    return np.maximum(t_in[0], t_in[1]), np.minimum(t_out[0], t_out[1])


def slab(px: float, py: float, d: np.ndarray, lohi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit parameters of rays from one point through many boxes (module docstring).

    Parameters
    ----------
    px, py : float
        Common origin of the rays.
    d : np.ndarray, shape (R, 2)
        Ray directions (any length; the parameter t is in units of ``|d|``).
    lohi : np.ndarray, shape (B, 2, 2)
        Boxes.

    Returns
    -------
    t_near, t_far : np.ndarray, shape (R, B)
        The line ``p + t d`` is inside box b for ``t_near[r, b] <= t <= t_far[r, b]``; it
        misses the box when ``t_near > t_far``.
    """
    d = np.asarray(d, dtype=np.float64)
    return slab_planes(px, py, np.ascontiguousarray(d.T), box_planes(lohi))


def raycast(px: float, py: float, d: np.ndarray, lohi: np.ndarray) -> np.ndarray:
    """Parameter of the first box surface hit by each ray from a point outside every box.

    Parameters
    ----------
    px, py : float
        Origin, outside all boxes.
    d : np.ndarray, shape (R, 2)
        Directions; use unit vectors to get distances in metres.
    lohi : np.ndarray, shape (B, 2, 2)
        Boxes.

    Returns
    -------
    np.ndarray, shape (R,)
        Smallest ``t >= 0`` at which the ray enters a box; ``inf`` if it hits none.
    """
    t_near, t_far = slab(px, py, d, lohi)
    hit = (t_near <= t_far) & (t_near >= 0.0)
    return np.where(hit, t_near, np.inf).min(axis=1, initial=np.inf)


def segments_blocked(px: float, py: float, targets: np.ndarray,
                     lohi: np.ndarray) -> np.ndarray:
    """Whether the segment from a point to each target crosses any box (line of sight).

    Parameters
    ----------
    px, py : float
        Viewpoint.
    targets : np.ndarray, shape (T, 2)
        Target points.
    lohi : np.ndarray, shape (B, 2, 2)
        Occluding boxes.

    Returns
    -------
    np.ndarray, shape (T,), bool
        True where the closed segment meets a box, i.e. the entry/exit interval of the line
        overlaps [0, 1].
    """
    d = np.asarray(targets, dtype=np.float64) - np.array((px, py))
    t_near, t_far = slab(px, py, d, lohi)
    return ((t_near <= t_far) & (t_near <= 1.0) & (t_far >= 0.0)).any(axis=1)


def point_box_distances(x: float, y: float, lohi: np.ndarray) -> np.ndarray:
    """Euclidean distance from a point to each box (0 inside).

    The nearest point of a box is the point clamped into it; per axis the gap is
    ``max(lo - x, 0, x - hi)``.

    Returns
    -------
    np.ndarray, shape (B,)
    """
    p = np.array((x, y))
    gap = np.maximum(np.maximum(lohi[:, 0] - p, p - lohi[:, 1]), 0.0)   # (B, 2)
    return np.hypot(gap[:, 0], gap[:, 1])


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    den = float(ab @ ab)
    s = 0.0 if den == 0.0 else min(1.0, max(0.0, float((p - a) @ ab) / den))
    return float(np.hypot(*(a + s * ab - p)))


def segment_box_distance(p0: ArrayLike, p1: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> float:
    """Exact distance between a segment and an axis-aligned box (0 if they meet).

    Two disjoint convex polygons are closest at a vertex of one of them, so the distance is
    the smallest of: the segment's end points to the box, and the box corners to the segment.
    A robot of radius r can drive the segment without touching the box iff the result >= r.

    Parameters
    ----------
    p0, p1 : array_like, shape (2,)
        End points of the segment.
    lo, hi : array_like, shape (2,)
        Corners ``(lo_x, lo_y)`` and ``(hi_x, hi_y)`` of the box.
    """
    a, b = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    lohi = np.array([[lo, hi]], dtype=np.float64)
    if segments_blocked(a[0], a[1], b[None, :], lohi)[0]:
        return 0.0
    ends = min(point_box_distances(a[0], a[1], lohi)[0], point_box_distances(b[0], b[1], lohi)[0])
    corners = [np.array((cx, cy)) for cx in (lohi[0, 0, 0], lohi[0, 1, 0])
               for cy in (lohi[0, 0, 1], lohi[0, 1, 1])]
    return float(min([ends] + [_point_segment_distance(c, a, b) for c in corners]))


def disc_gap(x: float, y: float, radius: float, boxes: tuple[tuple[float, float, float, float],
             ...], half: float) -> float:
    """Free distance between a disc and the nearest obstacle or wall (negative = penetration).

    Pure Python on purpose: for a handful of boxes it is faster than numpy call overhead.

    Parameters
    ----------
    x, y, radius : float
        Disc centre and radius [m].
    boxes : tuple of (lo_x, lo_y, hi_x, hi_y)
        Obstacles (walls excluded).
    half : float
        Half side of the floor; the walls are at ``+-half``.

    Returns
    -------
    float
        ``min(distance from the centre to each box, half - |x|, half - |y|) - radius``.
    """
    best = min(half - abs(x), half - abs(y))
    for lx, ly, hx, hy in boxes:
        dx = lx - x if x < lx else (x - hx if x > hx else 0.0)
        dy = ly - y if y < ly else (y - hy if y > hy else 0.0)
        d2 = dx * dx + dy * dy
        if d2 < best * best or best < 0.0:
            d = math.sqrt(d2)
            if d < best:
                best = d
    return best - radius
