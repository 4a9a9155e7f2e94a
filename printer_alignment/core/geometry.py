"""Camera-over-plate and XY gantry models of the vision screen printer.

Frames: ``plate`` is the reference frame (the calibration plate on the machine, m);
``camera2plate`` maps pixels of the gantry camera into it; ``gantry2plate`` maps the
gantry's motor angles (rev) to the camera's position in it. Pixels follow OpenCV.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The camera-over-plane model is shared (calib_core); the printer's modules name it from here.
from calib_core.image_plane import NOMINAL_PIXEL_SIZE, CameraToPlate, rotate_points, rotation  # noqa: F401

NOMINAL_LEAD_X = 0.016         # m/rev (Rx)
NOMINAL_LEAD_Y = 0.040         # m/rev (Ry)
# The drive's axis positions (commands and encoder readings, m) are motor angles times
# these nominal leads.
NOMINAL_LEADS = np.array([NOMINAL_LEAD_X, NOMINAL_LEAD_Y])


@dataclass(frozen=True)
class GantryModel:
    """The paper's gantry model: camera position in the plate frame

    ``[xc, yc] = [[cos a, -sin(a + t)], [sin a, cos(a + t)]] [Rx px, Ry py] + [x0, y0]``

    with motor angles px, py (rev), leads Rx, Ry (m/rev), axis angle a (rad, of the gantry X
    axis in the plate frame) and non-orthogonality t (rad).
    """

    lead_x: float = NOMINAL_LEAD_X
    lead_y: float = NOMINAL_LEAD_Y
    axis_angle: float = 0.0
    non_orthogonality: float = 0.0
    offset_x: float = 0.0
    offset_y: float = 0.0

    def matrix(self) -> np.ndarray:
        a, t = self.axis_angle, self.non_orthogonality
        return np.array([[np.cos(a), -np.sin(a + t)], [np.sin(a), np.cos(a + t)]])

    def camera_position(self, revs: np.ndarray) -> np.ndarray:
        """Camera positions (m, shape (n, 2)) for motor angles ``revs`` (rev, shape (n, 2))."""
        revs = np.atleast_2d(np.asarray(revs, dtype=float))
        travel = revs * np.array([self.lead_x, self.lead_y])
        return travel @ self.matrix().T + np.array([self.offset_x, self.offset_y])

    def revs_for(self, positions: np.ndarray) -> np.ndarray:
        """Motor angles (rev, shape (n, 2)) that put the camera at ``positions`` (m, shape
        (n, 2)): the inverse of :meth:`camera_position`."""
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        travel = np.linalg.solve(self.matrix(), (positions - [self.offset_x, self.offset_y]).T).T
        return travel / np.array([self.lead_x, self.lead_y])

    def as_dict(self) -> dict:
        return {'lead_x': self.lead_x, 'lead_y': self.lead_y, 'axis_angle': self.axis_angle,
                'non_orthogonality': self.non_orthogonality, 'offset_x': self.offset_x,
                'offset_y': self.offset_y}


def calibrated_frames(content: dict) -> list:
    """The frames a vision calibration file's ``content`` fixes, for ``/tf_static`` (z up
    from the plate): ``plate`` -> ``gantry`` (where the gantry's zero lies on the plate, x
    along its X axis: offset and axis angle) and ``carriage`` -> ``camera`` (the image axes
    against the carriage's, which move with the gantry's axes: camera angle less axis
    angle); m, rad. The gantry's non-orthogonality and leads are not rigid frames and stay
    in the calibration file; the moving ``gantry`` -> ``carriage`` comes from the machine."""
    from calib_core.frames import planar
    gantry, camera = content['gantry2plate'], content['camera2plate']
    return [('plate', 'gantry', *planar(gantry['offset_x'], gantry['offset_y'],
                                        gantry['axis_angle'])),
            ('carriage', 'camera', *planar(0.0, 0.0, camera['angle'] - gantry['axis_angle']))]
