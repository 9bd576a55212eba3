"""Colour blobs in a camera image: each target's bearing from the pixels of its colour.

Model
-----
* Colour: each target has a range in HSV (:class:`ColourRange`), the hexcone model of the
  pixel's RGB / 255: hue ``H`` in degrees [0, 360), saturation ``S`` and value ``V`` in
  [0, 1]. A pixel matches when ::

      hue_lo <= H <= hue_hi   (hue_lo > hue_hi: H >= hue_lo or H <= hue_hi, through 0: red)
      sat_lo <= S <= sat_hi   and   val_lo <= V <= val_hi

  HSV rather than RGB bounds: dimming the light scales RGB and leaves H and S unchanged, so
  one range holds over the shading of a cylinder and the exposure of a camera; a grey pixel
  (S = 0) matches no range with ``sat_lo > 0``. :data:`NAMED_RANGES` holds a range per colour
  name of an arena file (the renderer's colours, :mod:`cr_sim.core.render`).
* Blob: the matching pixels are labelled in 8-connected components
  (``scipy.ndimage.label``); on a strip that closes on itself (``camera.wraps``, the
  panoramic camera) two components touching across the seam (columns ``W - 1`` and 0) are
  one. The largest component (the first label on a tie) is the target's blob; a target with
  no matching pixel or whose blob has fewer than ``min_area`` pixels is not seen.
* Bearing: the blob's column centroid ``u_c`` (the mean column of its pixels, unwrapped
  across the seam: the strip is cut at the widest run of columns without the blob) through
  ``camera.bearing_of_column``. Angular width: the angle between the blob's outer column
  edges, ``|bearing(u_min - 0.5) - bearing(u_max + 0.5)|``; on a strip, the columns spanned
  times ``2 pi / W``.
* Box: the rows and columns the blob spans (:attr:`Blob.box`), for drawing it
  (:func:`draw_boxes`, in each target's display colour :meth:`ColourRange.rgb`).

A frame of another size than the camera model's nominal one (a camera whose ``camera_info``
gives its intrinsics, a strip of another width) is read with :func:`camera_for_frame`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math

from cr_sim.core.camera import CameraModel, Panoramic, Pinhole
import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

__all__ = [
    'ENCODINGS', 'ColourRange', 'NAMED_RANGES', 'BlobParams', 'Blob', 'check_encoding', 'hsv',
    'to_rgb', 'candidates', 'target_pixels', 'target_masks', 'blob_of', 'detect', 'bearings',
    'widths', 'draw_boxes', 'camera_for_frame',
]

#: Accepted image encodings (sensor_msgs/Image names) and their channel count.
ENCODINGS = {'rgb8': 3, 'bgr8': 3, 'rgba8': 4}

_EIGHT = np.ones((3, 3), dtype=bool)          # 8-connectivity of ndimage.label


def _check(name: str, value: float, lo: float, hi: float) -> None:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, bool) and lo <= value <= hi
    if not ok:
        raise ValueError(f'{name} = {value!r} is out of range: must be in [{lo:g}, {hi:g}]')


@dataclass(frozen=True)
class ColourRange:
    """A box in HSV space (module docstring): the pixels of one target's colour.

    Attributes
    ----------
    hue_lo, hue_hi : float
        Hue bounds [deg], in [0, 360]; ``hue_lo > hue_hi`` wraps through 0.
    sat_lo, sat_hi : float
        Saturation bounds, in [0, 1], ``sat_lo <= sat_hi``.
    val_lo, val_hi : float
        Value (brightness) bounds, in [0, 1], ``val_lo <= val_hi``.
    """

    hue_lo: float
    hue_hi: float
    sat_lo: float = 0.5
    sat_hi: float = 1.0
    val_lo: float = 0.2
    val_hi: float = 1.0

    def __post_init__(self) -> None:
        _check('hue_lo', self.hue_lo, 0.0, 360.0)
        _check('hue_hi', self.hue_hi, 0.0, 360.0)
        _check('sat_lo', self.sat_lo, 0.0, 1.0)
        _check('sat_hi', self.sat_hi, self.sat_lo, 1.0)
        _check('val_lo', self.val_lo, 0.0, 1.0)
        _check('val_hi', self.val_hi, self.val_lo, 1.0)

    def mask(self, h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Which pixels match.

        Parameters
        ----------
        h, s, v : np.ndarray, shape (H, W)
            From :func:`hsv`.

        Returns
        -------
        np.ndarray, shape (H, W), bool
        """
        if self.hue_lo <= self.hue_hi:
            hue = (h >= self.hue_lo) & (h <= self.hue_hi)
        else:
            hue = (h >= self.hue_lo) | (h <= self.hue_hi)
        return (hue & (s >= self.sat_lo) & (s <= self.sat_hi) & (v >= self.val_lo)
                & (v <= self.val_hi))

    def rgb(self) -> tuple[int, int, int]:
        """The display colour of the range: the hue in the middle of ``[hue_lo, hue_hi]``
        (through 0 when it wraps), full saturation and value, as 8-bit RGB."""
        span = (self.hue_hi - self.hue_lo) % 360.0 if self.hue_lo > self.hue_hi \
            else self.hue_hi - self.hue_lo
        h6 = ((self.hue_lo + 0.5 * span) % 360.0) / 60.0
        x = 1.0 - abs(h6 % 2.0 - 1.0)
        r, g, b = ((1, x, 0), (x, 1, 0), (0, 1, x), (0, x, 1), (x, 0, 1), (1, 0, x))[int(h6) % 6]
        return (round(255 * r), round(255 * g), round(255 * b))


#: A range per colour name of an arena file (hues of :data:`cr_sim.core.render.COLOURS`).
NAMED_RANGES: dict[str, ColourRange] = {
    'red': ColourRange(345.0, 15.0), 'orange': ColourRange(18.0, 42.0),
    'yellow': ColourRange(45.0, 70.0), 'green': ColourRange(95.0, 160.0),
    'cyan': ColourRange(175.0, 200.0), 'blue': ColourRange(210.0, 250.0),
    'purple': ColourRange(255.0, 285.0), 'magenta': ColourRange(288.0, 325.0),
}


@dataclass(frozen=True)
class BlobParams:
    """What to look for: a colour range per target, and the smallest blob that counts.

    Attributes
    ----------
    targets : tuple of (str, ColourRange)
        Target name and its colour, in the order of the results (a mapping name ->
        ColourRange is taken too); names unique and non-empty.
    min_area : int
        Pixels of the smallest blob that is seen, in [1, 1e9].
    """

    targets: tuple[tuple[str, ColourRange], ...]
    min_area: int = 4

    def __post_init__(self) -> None:
        items = (tuple(self.targets.items()) if isinstance(self.targets, Mapping)
                 else tuple(tuple(t) for t in self.targets))
        object.__setattr__(self, 'targets', items)
        names = [n for n, _ in items]
        for name, rng in items:
            if not isinstance(name, str) or not name:
                raise ValueError(f'targets: name {name!r} must be a non-empty string')
            if not isinstance(rng, ColourRange):
                raise ValueError(f'targets[{name!r}] = {rng!r} must be a ColourRange')
        if len(set(names)) != len(names):
            raise ValueError(f'targets: a name is used twice: {names}')
        if not isinstance(self.min_area, (int, np.integer)):
            raise ValueError(f'min_area = {self.min_area!r} must be an integer in [1, 1e+09]')
        _check('min_area', self.min_area, 1, 1e9)


@dataclass(frozen=True)
class Blob:
    """One target in one image.

    Attributes
    ----------
    seen : bool
        A blob of at least ``min_area`` pixels.
    bearing : float
        Relative to the heading [rad], in (-pi, pi]; NaN when not seen.
    area : int
        Pixels of the largest component (reported below ``min_area`` too; 0: none).
    width : float
        Angular width [rad]; NaN when not seen.
    column : float
        Column centroid [px], in [-0.5, W - 0.5) on a strip; NaN when not seen.
    box : tuple of 4 int, or None
        ``(top, bottom, left, right)``: the first and last row and the first and last column
        of the blob's pixels, inclusive; on a strip the columns run from ``left`` rightwards
        to ``right``, across the seam when ``left > right``. None when not seen.
    """

    seen: bool
    bearing: float
    area: int
    width: float
    column: float
    box: tuple[int, int, int, int] | None = None


def check_encoding(encoding: str) -> int:
    """The channel count of ``encoding``.

    Raises
    ------
    ValueError
        One line naming the encoding and the supported ones (:data:`ENCODINGS`).
    """
    if encoding not in ENCODINGS:
        raise ValueError(f'image encoding {encoding!r} is not supported: use one of '
                         + ', '.join(repr(e) for e in ENCODINGS))
    return ENCODINGS[encoding]


def _checked(image: np.ndarray, encoding: str) -> np.ndarray:
    """``image`` as an array, after checking its encoding, dtype and shape."""
    n = check_encoding(encoding)
    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != n:
        raise ValueError(f'a {encoding} image is uint8 of shape (H, W, {n}), got {a.dtype} '
                         f'of shape {a.shape}')
    return a


def hsv(image: np.ndarray, encoding: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hue [deg], saturation and value of each pixel (hexcone model, module docstring).

    Parameters
    ----------
    image : np.ndarray, shape (H, W, 3) or (H, W, 4), uint8
        In ``encoding`` (one of :data:`ENCODINGS`; alpha is ignored).
    encoding : str

    Returns
    -------
    h, s, v : np.ndarray, shape (H, W)
        ``h`` in [0, 360) (0 for grey), ``s`` and ``v`` in [0, 1].

    Raises
    ------
    ValueError
        An encoding not in :data:`ENCODINGS`, or an image of another shape or dtype.
    """
    a = _checked(image, encoding)
    i_r, i_b = (2, 0) if encoding == 'bgr8' else (0, 2)
    r, g, b = (a[..., i].astype(np.float64) * (1.0 / 255.0) for i in (i_r, 1, i_b))
    v = np.maximum(np.maximum(r, g), b)
    c = v - np.minimum(np.minimum(r, g), b)
    with np.errstate(invalid='ignore', divide='ignore'):
        s = np.where(v > 0.0, c / v, 0.0)
        ic = np.where(c > 0.0, 1.0 / c, 0.0)
    h = np.where(v == r, np.remainder((g - b) * ic, 6.0),
                 np.where(v == g, (b - r) * ic + 2.0, (r - g) * ic + 4.0))
    h = np.where(c > 0.0, 60.0 * h, 0.0)
    h[h >= 360.0] = 0.0
    return h, s, v


def to_rgb(image: np.ndarray, encoding: str) -> np.ndarray:
    """The image in RGB order, without alpha.

    Parameters
    ----------
    image : np.ndarray, shape (H, W, 3) or (H, W, 4), uint8
        In ``encoding`` (one of :data:`ENCODINGS`).
    encoding : str

    Returns
    -------
    np.ndarray, shape (H, W, 3), uint8
        A new array (the input is never written to).

    Raises
    ------
    ValueError
        As :func:`hsv`.
    """
    a = _checked(image, encoding)
    if encoding == 'bgr8':
        return np.ascontiguousarray(a[..., ::-1])
    return np.array(a[..., :3])


def _merge_seam(labels: np.ndarray, n: int) -> np.ndarray:
    """``labels`` with components that touch across the seam (last column, first column;
    8-connected) given one label (the smallest of them)."""
    left, right = labels[:, 0], labels[:, -1]
    if not (left.any() and right.any()):
        return labels
    pairs = [np.stack((right[a], left[b]), axis=1)
             for a, b in ((slice(None), slice(None)), (slice(1, None), slice(None, -1)),
                          (slice(None, -1), slice(1, None)))]
    pairs = np.concatenate(pairs)
    pairs = np.unique(pairs[(pairs[:, 0] > 0) & (pairs[:, 1] > 0)], axis=0)
    if len(pairs) == 0:
        return labels
    root = np.arange(n + 1)

    def find(i: int) -> int:
        while root[i] != i:
            i = root[i]
        return int(i)

    for i, j in pairs:
        a, b = find(int(i)), find(int(j))
        root[max(a, b)] = min(a, b)
    return np.array([find(i) for i in range(n + 1)])[labels]


def _columns_unwrapped(cols: np.ndarray, width: int) -> np.ndarray:
    """Columns of a blob on a closed strip, shifted by ``width`` where needed so that the
    blob is one run: the cut is at the widest gap between its occupied columns."""
    occupied = np.unique(cols)
    gaps = np.diff(np.append(occupied, occupied[0] + width))
    start = occupied[(int(np.argmax(gaps)) + 1) % len(occupied)]
    return np.where(cols < start, cols + width, cols)


def candidates(image: np.ndarray, ranges: list[ColourRange] | tuple[ColourRange, ...]
               ) -> np.ndarray:
    """The pixels that may match one of ``ranges``: a superset of their matches, from the
    8-bit channels alone (a cheap test before :func:`hsv`'s floating point).

    A pixel matches a range only if ``V >= val_lo`` and ``S >= sat_lo`` (module docstring),
    with ``V = M / 255`` and ``S = (M - m) / M`` for its largest and smallest channel ``M``
    and ``m``; a pixel is dropped only when it fails both by more than one grey level for the
    lowest ``val_lo`` and ``sat_lo`` of all ranges, far beyond the rounding of :func:`hsv`.

    Parameters
    ----------
    image : np.ndarray, shape (H, W, 3) or (H, W, 4), uint8
        Checked already; the channel order does not matter (alpha is ignored).
    ranges : sequence of ColourRange

    Returns
    -------
    np.ndarray, shape (H, W), bool
    """
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    big = np.maximum(np.maximum(r, g), b)
    val_lo = min((r.val_lo for r in ranges), default=0.0)
    sat_lo = min((r.sat_lo for r in ranges), default=0.0)
    keep = big.astype(np.float32) + np.float32(1.0) >= np.float32(val_lo * 255.0)
    if sat_lo > 0.0:
        chroma = (big - np.minimum(np.minimum(r, g), b)).astype(np.float32)
        keep &= chroma + np.float32(1.0) >= np.float32(sat_lo) * big
    return keep


def target_pixels(image: np.ndarray, encoding: str, params: BlobParams
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The pixels that match each target's range (:meth:`ColourRange.mask` of :func:`hsv`), in
    the order of ``params.targets``, with :func:`hsv` computed only on the :func:`candidates`
    (most pixels of a scene, floor and walls, are grey or dark).

    Parameters
    ----------
    image : np.ndarray, shape (H, W, 3) or (H, W, 4), uint8
        In ``encoding``.
    encoding : str
    params : BlobParams

    Returns
    -------
    list of (rows, cols)
        Per target, the row and column indices (int arrays, raster order) of its matches.
    """
    a = _checked(image, encoding)
    keep = candidates(a, [rng for _, rng in params.targets])
    rows, cols = np.nonzero(keep)
    h, s, v = hsv(a[rows, cols][np.newaxis], encoding)
    out = []
    for _, rng in params.targets:
        match = rng.mask(h, s, v)[0]
        out.append((rows[match], cols[match]))
    return out


def target_masks(image: np.ndarray, encoding: str, params: BlobParams) -> list[np.ndarray]:
    """:func:`target_pixels` as masks: ``ColourRange.mask(*hsv(image))`` of each target.

    Returns
    -------
    list of np.ndarray, shape (H, W), bool
    """
    out = []
    for rows, cols in target_pixels(image, encoding, params):
        mask = np.zeros(np.shape(image)[:2], dtype=bool)
        mask[rows, cols] = True
        out.append(mask)
    return out


def blob_of(mask: np.ndarray, camera: CameraModel, min_area: int, r0: int = 0, c0: int = 0
            ) -> Blob:
    """The blob of one target's matches (module docstring): the largest 8-connected
    component of ``mask``, its bearing, width and box.

    Parameters
    ----------
    mask : np.ndarray, shape (h, w), bool
        The matches, in the window of the image whose first row and column are ``r0`` and
        ``c0`` (the whole image by default; all of its columns on a strip).
    camera : Pinhole or Panoramic
    min_area : int
        Pixels of the smallest blob that is seen.

    Returns
    -------
    Blob
    """
    labels, n = ndimage.label(mask, structure=_EIGHT)
    if n == 0:
        return Blob(False, math.nan, 0, math.nan, math.nan)
    if camera.wraps and camera.width > 1:
        labels = _merge_seam(labels, n)
    area = np.bincount(labels.ravel(), minlength=n + 1)
    area[0] = 0
    best = int(np.argmax(area))
    if area[best] < min_area:
        return Blob(False, math.nan, int(area[best]), math.nan, math.nan)
    rows, cols = np.nonzero(labels == best)
    rows, cols = rows + r0, (cols + c0).astype(np.float64)
    if camera.wraps:
        cols = _columns_unwrapped(cols, camera.width)
        u = float(np.mean(cols))
        width = (cols.max() - cols.min() + 1.0) * camera.angle_per_pixel
        u = (u + 0.5) % camera.width - 0.5
    else:
        u = float(np.mean(cols))
        edges = camera.bearing_of_column(np.array((cols.min() - 0.5, cols.max() + 0.5)))
        width = abs(float(edges[0] - edges[1]))
    box = (int(rows.min()), int(rows.max()), int(cols.min()) % camera.width,
           int(cols.max()) % camera.width)
    return Blob(True, float(camera.bearing_of_column(u)), int(area[best]), float(width), u,
                box)


def detect(image: np.ndarray, encoding: str, camera: CameraModel, params: BlobParams
           ) -> dict[str, Blob]:
    """Find each target's blob (module docstring for the model).

    Parameters
    ----------
    image : np.ndarray, shape (H, W, 3) or (H, W, 4), uint8
        ``H, W = camera.height, camera.width``.
    encoding : str
        ``'rgb8'``, ``'bgr8'`` or ``'rgba8'`` (:data:`ENCODINGS`).
    camera : Pinhole or Panoramic
        The model of the camera that took the image (:mod:`cr_sim.core.camera`).
    params : BlobParams

    Returns
    -------
    dict of str to Blob
        One per target, in the order of ``params.targets``.

    Raises
    ------
    ValueError
        An unsupported encoding (one line naming it and the accepted ones), or an image
        whose shape is not the camera's.
    """
    a = _checked(image, encoding)
    if a.shape[:2] != (camera.height, camera.width):
        raise ValueError(f'the image is {a.shape[0]} x {a.shape[1]} (H x W), the camera '
                         f'{camera.height} x {camera.width}')
    out = {}
    for (name, _), (rows, cols) in zip(params.targets, target_pixels(a, encoding, params)):
        if len(rows) == 0:
            out[name] = Blob(False, math.nan, 0, math.nan, math.nan)
            continue
        # labelled within the box of the matches (all the columns on a strip, for its
        # seam): the components and their raster-order labels are the whole image's
        r0, c0 = int(rows.min()), 0 if camera.wraps else int(cols.min())
        c1 = camera.width - 1 if camera.wraps else int(cols.max())
        mask = np.zeros((int(rows.max()) - r0 + 1, c1 - c0 + 1), dtype=bool)
        mask[rows - r0, cols - c0] = True
        out[name] = blob_of(mask, camera, params.min_area, r0, c0)
    return out


def bearings(blobs: Mapping[str, Blob], names: tuple[str, ...] | list[str]) -> np.ndarray:
    """The bearings of ``names`` in that order, as the ``camera`` topic's positions.

    Parameters
    ----------
    blobs : Mapping of str to Blob
        From :func:`detect`.
    names : sequence of str, length T
        E.g. ``('destination', 'L1', ...)``; a name without a blob is not seen.

    Returns
    -------
    np.ndarray, shape (T,)
        Bearing [rad], NaN = not seen.
    """
    return np.array([blobs[n].bearing if n in blobs else math.nan for n in names],
                    dtype=np.float64)


def widths(blobs: Mapping[str, Blob], names: tuple[str, ...] | list[str]) -> np.ndarray:
    """The apparent angular widths of ``names`` in that order (:attr:`Blob.width`).

    Parameters
    ----------
    blobs : Mapping of str to Blob
        From :func:`detect`.
    names : sequence of str, length T

    Returns
    -------
    np.ndarray, shape (T,)
        Angular width [rad], NaN = not seen.
    """
    return np.array([blobs[n].width if n in blobs else math.nan for n in names],
                    dtype=np.float64)


def draw_boxes(rgb: np.ndarray, blobs: Mapping[str, Blob],
               colours: Mapping[str, tuple[int, int, int]], wraps: bool = False) -> np.ndarray:
    """The image with a one-pixel rectangle round each seen blob, one pixel outside its
    :attr:`Blob.box`, in its target's colour.

    Parameters
    ----------
    rgb : np.ndarray, shape (H, W, 3), uint8
        Not written to.
    blobs : Mapping of str to Blob
        From :func:`detect` on this image.
    colours : Mapping of str to (int, int, int)
        RGB of each target's rectangle (e.g. :meth:`ColourRange.rgb`); a target missing here
        is drawn in white.
    wraps : bool
        The image is a strip closing on itself (``camera.wraps``): a rectangle crosses the
        seam when its blob does.

    Returns
    -------
    np.ndarray, shape (H, W, 3), uint8
        A copy with the rectangles drawn; a rectangle reaching past an edge is cut there.
    """
    out = np.array(rgb, dtype=np.uint8)
    n_rows, n_cols = out.shape[:2]
    for name, blob in blobs.items():
        if not blob.seen or blob.box is None:
            continue
        top, bottom, left, right = blob.box
        colour = np.asarray(colours.get(name, (255, 255, 255)), dtype=np.uint8)
        r0, r1 = max(top - 1, 0), min(bottom + 1, n_rows - 1)
        if wraps:
            span = min((right - left) % n_cols + 3, n_cols)
            cols = (left - 1 + np.arange(span)) % n_cols
        else:
            cols = np.arange(max(left - 1, 0), min(right + 1, n_cols - 1) + 1)
        out[r0, cols] = colour
        out[r1, cols] = colour
        out[r0:r1 + 1, cols[0]] = colour
        out[r0:r1 + 1, cols[-1]] = colour
    return out


def camera_for_frame(nominal: CameraModel, width: int, height: int,
                     k: ArrayLike | None = None) -> CameraModel:
    """The model of a frame of ``width`` x ``height`` from the camera ``nominal`` describes.

    Parameters
    ----------
    nominal : Pinhole or Panoramic
        The camera as described without calibration (a robot profile's field of view).
    width, height : int
        The frame's size [px].
    k : array_like, shape (9,) or (3, 3), optional
        A pinhole's intrinsic matrix for this size (sensor_msgs/CameraInfo ``k``); ignored
        for a panoramic strip.

    Returns
    -------
    Pinhole or Panoramic
        ``nominal`` itself for its own size and no ``k``; with ``k``,
        ``Pinhole.from_k(width, height, k, nominal.yaw)``; a pinhole of another size, the
        nominal field of view over it; a strip of another size, the full turn over its
        ``width`` columns (the nominal ``bearing0`` and direction, the middle row as horizon).

    Raises
    ------
    ValueError
        A size or a ``k`` the models reject, naming the field and its range.
    """
    if isinstance(nominal, Panoramic):
        if (width, height) == (nominal.width, nominal.height):
            return nominal
        return Panoramic(width, height, nominal.bearing0, nominal.clockwise)
    if k is not None:
        return Pinhole.from_k(width, height, k, nominal.yaw)
    if (width, height) == (nominal.width, nominal.height):
        return nominal
    return Pinhole.from_fov(width, height, nominal.hfov, nominal.yaw)
