"""Measure Marks in the plate frame with the calibrated vision system, for the nodes that
need positions rather than pixels (stage calibrator, aligner).

The vision calibration in force arrives as the latched ``/vision_calibrator/result``, so
the user may run on another host than the vision calibrator. For each Mark the gantry
parks on a lattice of commands, at the point whose calibrated camera position is nearest
the Mark's expected position, approached from below on both axes (the gantry's backlash is
then the same every time), the detector finds the one Mark
of the requested shape in the next image, and the Mark's position is the calibrated
camera position plus its calibrated pixel offset.
"""
from __future__ import annotations

import threading

import numpy as np
from alignment_msgs.msg import CalibrationResult
from alignment_msgs.srv import DetectMarks, MoveGantry, SelectView

from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.nodes.calibrator import call_service
from calib_core.nodes.qos import LATCHED
from printer_alignment.core.geometry import (
    NOMINAL_LEADS, CameraToPlate, GantryModel)
from printer_alignment.core.records import VISION_RESULT_TOPIC
from printer_alignment.nodes.conversions import marks_from_message

GANTRY_KEYS = ('lead_x', 'lead_y', 'axis_angle', 'non_orthogonality', 'offset_x', 'offset_y')


def vision_from_message(msg):
    """(CameraToPlate, GantryModel) from a vision CalibrationResult message."""
    values = dict(zip(msg.names, msg.values))
    missing = [k for k in ('pixel_size', 'camera_angle') + GANTRY_KEYS if k not in values]
    if missing:
        raise InvalidInputError(f'vision result lacks {", ".join(missing)}')
    return (CameraToPlate(values['pixel_size'], values['camera_angle']),
            GantryModel(**{k: values[k] for k in GANTRY_KEYS}))


class MarkLocator:
    """Plate positions of Marks for ``node``, through its own service clients."""

    def __init__(self, node, callback_group, timeout: float, lattice: float = 2e-3,
                 approach: float = 1e-3):
        if not (lattice > 0 and approach >= 0 and timeout > 0):
            raise ValueError('lattice and timeout must be positive, approach >= 0')
        self.node, self.timeout = node, timeout
        self.lattice, self.approach = lattice, approach
        self._vision = None
        self._lock = threading.Lock()
        self._vision_arrived = threading.Event()
        self.move_client = node.create_client(MoveGantry, 'gantry/move', callback_group=callback_group)
        self.detect_client = node.create_client(DetectMarks, 'mark_detector/detect',
                                                callback_group=callback_group)
        self.view_client = node.create_client(SelectView, 'camera/select_view',
                                              callback_group=callback_group)
        node.create_subscription(CalibrationResult, VISION_RESULT_TOPIC, self._on_vision,
                                 LATCHED, callback_group=callback_group)

    def _on_vision(self, msg):
        if not msg.success:
            return
        try:
            vision = vision_from_message(msg)
        except InvalidInputError as exc:
            self.node.get_logger().error(f'ignoring vision result: {exc}')
            return
        with self._lock:
            self._vision = vision
        self._vision_arrived.set()

    @property
    def vision(self):
        """The vision calibration in force. A latched message can arrive after the first
        service call when discovery is slow, so it is awaited up to the service timeout."""
        if not self._vision_arrived.wait(self.timeout):
            raise CalibrationError(
                'no vision calibration in force: vision_calibrator has not published '
                f'{VISION_RESULT_TOPIC} within {self.timeout:g} s (calibrate the vision '
                'system first)')
        with self._lock:
            return self._vision

    def select_view(self, view: str) -> None:
        call_service(self.view_client, SelectView.Request(view=view), 'camera view', self.timeout)

    def _park(self, x: float, y: float) -> np.ndarray:
        """Park the gantry at (x, y) m from below; returns the motor angles (rev)."""
        for target in ((x - self.approach, y - self.approach), (x, y)):
            reached = call_service(self.move_client, MoveGantry.Request(
                x=float(target[0]), y=float(target[1])), 'gantry move', self.timeout)
        return np.array([reached.x, reached.y]) / NOMINAL_LEADS

    def measure(self, expected, shape: str = 'circle') -> np.ndarray:
        """Plate positions (m, (k, 2)) of the one Mark of ``shape`` near each expected
        position ((k, 2), m).

        Raises
        ------
        CalibrationError
            No vision calibration yet, or a Mark is missing, clipped or not alone (the
            detector's reason is passed on), or a service does not answer.
        """
        camera2plate, gantry = self.vision
        expected = np.atleast_2d(np.asarray(expected, dtype=float))
        if not np.all(np.isfinite(expected)):
            raise InvalidInputError('expected Mark positions contain NaN or infinite values')
        out = []
        for x, y in expected:
            # The lattice is in gantry commands (repeatable motor angles); the calibrated
            # model says which command brings the camera over the Mark: the plate frame can
            # sit millimetres from the command frame.
            command = gantry.revs_for([[x, y]])[0] * NOMINAL_LEADS
            park = np.round(command / self.lattice) * self.lattice
            revs = self._park(*park)
            try:
                detected = call_service(self.detect_client, DetectMarks.Request(
                    shape=shape, expected_count=1), 'detection', self.timeout)
            except CalibrationError as exc:
                raise CalibrationError(f'{shape} Mark near ({x * 1e3:.3f}, {y * 1e3:.3f}) mm: '
                                       f'{exc}') from None
            mark = marks_from_message(detected.marks)[0]
            out.append(gantry.camera_position(revs)[0]
                       + camera2plate.offset([[mark.u, mark.v]])[0])
        return np.array(out)
