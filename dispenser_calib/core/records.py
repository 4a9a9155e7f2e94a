"""Reading a recorded five-axis run into core values (attribute access only: live messages
and messages decoded from a bag alike). The topic names are the contract between the node
that records a run and the tools that replay it."""
from __future__ import annotations

import numpy as np

from calib_core.errors import InvalidInputError
from dispenser_calib.core.data import Image

OBSERVATIONS_TOPIC = '/five_axis_calibrator/observations'
RESULT_TOPIC = '/five_axis_calibrator/result'


def image_from_message(msg) -> tuple[Image, str]:
    """(Image, phase) of a FiveAxisObservation."""
    pose = np.asarray(msg.pose, dtype=float)
    indices = np.column_stack([np.asarray(msg.i, int), np.asarray(msg.j, int)])
    pixels = np.column_stack([np.asarray(msg.u, float), np.asarray(msg.v, float)])
    if pose.shape != (5,) or not np.all(np.isfinite(pose)) or not np.all(np.isfinite(pixels)):
        raise InvalidInputError(f'image {msg.image!r}: a five-axis observation needs a finite '
                                'pose of 5 values and finite dot centres')
    return Image(str(msg.image), pose, indices, pixels), str(msg.phase)
