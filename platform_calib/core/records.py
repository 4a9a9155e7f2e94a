"""Reading the platform's recorded runs into core values (attribute access only: live
messages and messages decoded from a bag alike). The topic names are the contract between
the node that records a run and the tools that replay it."""
from __future__ import annotations

import numpy as np

from calib_core.errors import InvalidInputError
from platform_calib.core.procedure import Stop

MEASUREMENTS_TOPIC = '/platform_calibrator/measurements'
RESULT_TOPIC = '/platform_calibrator/result'


def stop_from_message(msg) -> Stop:
    """A Stop from a PlatformMeasurement."""
    values = [np.asarray(getattr(msg, k), dtype=float)
              for k in ('target', 'feeds', 'direction', 'measured')]
    if any(v.shape != (3,) for v in values) or not all(np.all(np.isfinite(v)) for v in values):
        raise InvalidInputError('a platform measurement needs three finite values in each '
                                'of target, feeds, direction, measured')
    return Stop(str(msg.phase), *values)


def planar_pose_from_quaternion(x, y, qz, qw) -> np.ndarray:
    """(x, y, theta) of a pose rotated about z only (a planar platform)."""
    return np.array([x, y, 2 * np.arctan2(qz, qw)])
