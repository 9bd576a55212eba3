"""The colour-blob detector of a camera stream: per frame, each target's bearing and width.

The pure core of ``clis_modules.detector_node``: which camera model reads a frame, and what
the frame gives (:mod:`clis_modules.core.blobs` for the model of one image).

* Camera model: the nominal one (a robot profile's field of view,
  ``CameraSpec.camera_model()``) until intrinsics arrive (:meth:`Detector.set_intrinsics`,
  a camera_info message's ``k``); from then on a pinhole frame of the intrinsics' size is read
  with ``Pinhole.from_k`` (:func:`~clis_modules.core.blobs.camera_for_frame`). A panoramic
  strip has no intrinsics: its model is the full turn over the frame's columns.
* A frame: the targets' blobs (:func:`~clis_modules.core.blobs.detect`), their bearings
  [rad] and apparent angular widths [rad] in the order of ``names``, NaN for a target not
  seen (:class:`Detection`), and the frame with each blob's box drawn in its target's
  colour (:meth:`Detector.overlay`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from cr_sim.core.camera import CameraModel, Panoramic
import numpy as np
from numpy.typing import ArrayLike

from clis_modules.core.blobs import (
    Blob,
    BlobParams,
    ColourRange,
    bearings,
    camera_for_frame,
    detect,
    draw_boxes,
    to_rgb,
    widths,
)

__all__ = ['Detection', 'Detector']


@dataclass(frozen=True)
class Detection:
    """What one frame gives.

    Attributes
    ----------
    names : tuple of str, length T
        The targets, in the order of the ``camera`` topic (``destination`` first).
    bearings : np.ndarray, shape (T,)
        Bearing relative to the heading [rad], in (-pi, pi]; NaN = not seen.
    widths : np.ndarray, shape (T,)
        Apparent angular width [rad]; NaN = not seen.
    blobs : dict of str to Blob
    camera : Pinhole or Panoramic
        The model the frame was read with.
    """

    names: tuple[str, ...]
    bearings: np.ndarray
    widths: np.ndarray
    blobs: dict[str, Blob]
    camera: CameraModel


class Detector:
    """Targets found by colour in the frames of one camera (module docstring).

    Parameters
    ----------
    nominal : Pinhole or Panoramic
        The camera without calibration.
    targets : Mapping of str to ColourRange
        Each target's colour, in the order of the results (``destination``, the landmarks).
    min_area : int
        Pixels of the smallest blob that is seen, in [1, 1e9].
    """

    def __init__(self, nominal: CameraModel, targets: Mapping[str, ColourRange],
                 min_area: int = 4) -> None:
        self.nominal = nominal
        self.params = BlobParams(dict(targets), min_area)
        self.names = tuple(name for name, _ in self.params.targets)
        self.colours = {name: rng.rgb() for name, rng in self.params.targets}
        self._k: tuple[int, int, np.ndarray] | None = None
        self._models: dict[tuple[int, int], CameraModel] = {}

    @property
    def calibrated(self) -> bool:
        """Intrinsics were set (a pinhole camera only)."""
        return self._k is not None

    def set_intrinsics(self, width: int, height: int, k: ArrayLike) -> bool:
        """Read frames of ``width`` x ``height`` with the intrinsic matrix ``k`` from now on.

        Parameters
        ----------
        width, height : int
            The size the intrinsics are for [px].
        k : array_like, shape (9,) or (3, 3)
            Row-major (sensor_msgs/CameraInfo ``k``).

        Returns
        -------
        bool
            Whether the model changed (False: the same intrinsics again, or a panoramic
            camera, which ignores them).

        Raises
        ------
        ValueError
            Intrinsics no pinhole has (``fx`` not above 0, ...), naming the field and its
            range; the model in force is kept.
        """
        if isinstance(self.nominal, Panoramic):
            return False
        a = np.asarray(k, dtype=np.float64).reshape(-1)
        if (self._k is not None and (width, height) == self._k[:2]
                and np.array_equal(a, self._k[2])):
            return False
        camera_for_frame(self.nominal, width, height, a)          # raises if unusable
        self._k = (width, height, a.copy())
        self._models.clear()
        return True

    def camera(self, width: int, height: int) -> CameraModel:
        """The model of a frame of ``width`` x ``height`` [px]: with the intrinsics when they
        are for that size, else the nominal field of view over it.

        Raises
        ------
        ValueError
            A size out of [1, MAX_PIXELS].
        """
        key = (width, height)
        model = self._models.get(key)
        if model is None:
            k = self._k[2] if self._k is not None and self._k[:2] == key else None
            model = self._models[key] = camera_for_frame(self.nominal, width, height, k)
        return model

    def frame(self, image: np.ndarray, encoding: str) -> Detection:
        """Detect every target in one frame.

        Parameters
        ----------
        image : np.ndarray, shape (H, W, C), uint8
            In ``encoding`` (:data:`~clis_modules.core.blobs.ENCODINGS`).
        encoding : str

        Returns
        -------
        Detection

        Raises
        ------
        ValueError
            An unsupported encoding (one line naming it and the supported ones), or an image
            of the wrong dtype or channel count.
        """
        camera = self.camera(int(np.shape(image)[1]), int(np.shape(image)[0]))
        blobs = detect(image, encoding, camera, self.params)
        return Detection(self.names, bearings(blobs, self.names), widths(blobs, self.names),
                         blobs, camera)

    def overlay(self, image: np.ndarray, encoding: str, detection: Detection) -> np.ndarray:
        """The frame in RGB with each seen blob's box in its target's colour.

        Parameters
        ----------
        image : np.ndarray, shape (H, W, C), uint8
            The frame ``detection`` was made from.
        encoding : str
        detection : Detection

        Returns
        -------
        np.ndarray, shape (H, W, 3), uint8
        """
        return draw_boxes(to_rgb(image, encoding), detection.blobs, self.colours,
                          detection.camera.wraps)
