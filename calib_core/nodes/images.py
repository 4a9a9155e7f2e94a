"""sensor_msgs/Image to and from arrays, at the node boundary of every machine's camera."""
from __future__ import annotations

import cv2
import numpy as np
from sensor_msgs.msg import Image

from calib_core.errors import InvalidInputError

_ENCODINGS = {'mono8': (np.uint8, 1), '8UC1': (np.uint8, 1), 'mono16': (np.uint16, 1),
              '16UC1': (np.uint16, 1), 'bgr8': (np.uint8, 3), 'rgb8': (np.uint8, 3)}


def image_from_message(msg) -> np.ndarray:
    """Single-channel array (H, W) from a sensor_msgs/Image; colour is converted to grey.

    Raises InvalidInputError on an unsupported encoding or inconsistent size."""
    if msg.encoding not in _ENCODINGS:
        raise InvalidInputError(f'unsupported image encoding {msg.encoding!r}; '
                                f'use one of {", ".join(_ENCODINGS)}')
    dtype, channels = _ENCODINGS[msg.encoding]
    itemsize = np.dtype(dtype).itemsize
    row = msg.width * channels * itemsize
    if msg.height == 0 or msg.width == 0 or msg.step < row or len(msg.data) < msg.step * msg.height:
        raise InvalidInputError(f'image data ({len(msg.data)} bytes) does not match '
                                f'{msg.width}x{msg.height} {msg.encoding} with step {msg.step}')
    buffer = np.frombuffer(bytes(msg.data), dtype=np.uint8)[:msg.step * msg.height]
    rows = buffer.reshape(msg.height, msg.step)[:, :row]
    pixels = rows.copy().view(np.dtype(dtype).newbyteorder('>' if msg.is_bigendian else '<'))
    pixels = pixels.reshape(msg.height, msg.width, channels).astype(dtype)
    if channels == 3:
        code = cv2.COLOR_BGR2GRAY if msg.encoding == 'bgr8' else cv2.COLOR_RGB2GRAY
        return cv2.cvtColor(pixels, code)
    return pixels[:, :, 0]


def image_as_message(pixels: np.ndarray, header) -> Image:
    """sensor_msgs/Image (mono8) from a uint8 array (H, W)."""
    msg = Image()
    msg.header = header
    msg.height, msg.width = pixels.shape
    msg.encoding = 'mono8'
    msg.is_bigendian = 0
    msg.step = msg.width
    msg.data = np.ascontiguousarray(pixels, dtype=np.uint8).tobytes()
    return msg
