"""Message conversions of the colour-blob detector: camera images in, named bearings out.

The detector's own (:mod:`clis_modules.detector_node`), apart from
:mod:`clis_modules.conversions` (the graph's records) so that the modules' nodes load neither
the image types nor the blob detector's scipy:

* ``sensor_msgs/Image`` <-> numpy: :func:`image_array` reads the 8-bit colour encodings of
  :data:`~clis_modules.core.blobs.ENCODINGS` (rows of ``step`` bytes, padding dropped),
  :func:`image_msg` writes ``rgb8``;
* ``sensor_msgs/CameraInfo`` -> the intrinsics: :func:`camera_info_k`;
* the ``camera`` topic (docs/robot.md#topics): :func:`camera_msg`, a ``sensor_msgs/JointState``
  with ``name`` = the targets, ``position`` = bearing [rad] and ``effort`` = apparent angular
  width [rad], NaN = not seen.
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence

from builtin_interfaces.msg import Time
import numpy as np
from numpy.typing import ArrayLike
from sensor_msgs.msg import CameraInfo, Image, JointState

from clis_modules.core.blobs import check_encoding

__all__ = ['image_array', 'image_msg', 'camera_info_k', 'camera_msg']


def image_array(msg: Image) -> np.ndarray:
    """The pixels of an Image message.

    Parameters
    ----------
    msg : sensor_msgs/Image
        Encoding ``rgb8``, ``bgr8`` or ``rgba8``.

    Returns
    -------
    np.ndarray, shape (height, width, C), uint8
        A read-only view of the message's buffer (C = 3 or 4).

    Raises
    ------
    ValueError
        One line: an unsupported encoding (naming it and the supported ones), or a ``step``
        or data length that does not hold ``height`` rows of ``width`` pixels.
    """
    channels = check_encoding(msg.encoding)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if h < 1 or w < 1 or step < w * channels or data.size < h * step:
        raise ValueError(f'a {msg.encoding} image of {w} x {h} px needs step >= '
                         f'{w * channels} and {h} rows of step bytes: got step {step} and '
                         f'{data.size} bytes')
    return data[:h * step].reshape(h, step)[:, :w * channels].reshape(h, w, channels)


def image_msg(rgb: np.ndarray, stamp: Time, frame: str) -> Image:
    """An ``rgb8`` Image of ``rgb``.

    Parameters
    ----------
    rgb : np.ndarray, shape (H, W, 3), uint8
    stamp : builtin_interfaces/Time
    frame : str
    """
    a = np.ascontiguousarray(rgb, dtype=np.uint8)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f'an rgb8 image is of shape (H, W, 3), got {a.shape}')
    msg = Image(height=a.shape[0], width=a.shape[1], encoding='rgb8', is_bigendian=0,
                step=3 * a.shape[1])
    msg.header.stamp, msg.header.frame_id = stamp, frame
    msg.data = array('B', a.tobytes())
    return msg


def camera_info_k(msg: CameraInfo) -> tuple[int, int, np.ndarray]:
    """``(width, height, k)`` of a CameraInfo: the image size and the intrinsic matrix,
    shape (9,), row-major."""
    return int(msg.width), int(msg.height), np.asarray(msg.k, dtype=np.float64).reshape(9)


def camera_msg(names: Sequence[str], bearings: ArrayLike, widths: ArrayLike, stamp: Time,
               frame: str) -> JointState:
    """The ``camera`` topic: ``position`` = bearing, ``effort`` = apparent angular width
    (both [rad], NaN = not seen) of each of ``names``, stamped ``stamp``."""
    msg = JointState(name=list(names))
    msg.header.stamp, msg.header.frame_id = stamp, frame
    msg.position = array('d', np.asarray(bearings, dtype=np.float64).tobytes())
    msg.effort = array('d', np.asarray(widths, dtype=np.float64).tobytes())
    return msg
