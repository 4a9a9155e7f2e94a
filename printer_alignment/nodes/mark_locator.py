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

import json
import threading
import time

import numpy as np
from alignment_msgs.msg import CalibrationResult
from alignment_msgs.srv import DetectMarks, MoveGantry, SelectView

from calib_core.errors import CalibrationError, InvalidInputError, MachineAlignmentError
from calib_core.nodes.calibrator import call_service
from calib_core.nodes.qos import LATCHED
from printer_alignment.core.geometry import (
    NOMINAL_LEADS, CameraToPlate, GantryModel)
from printer_alignment.core.records import VISION_RESULT_TOPIC
from printer_alignment.core.vision_calibration import VISION_UNITS
from printer_alignment.core.vision_procedure import check_vision_parameters
from printer_alignment.nodes.conversions import marks_from_message

GANTRY_KEYS = ('lead_x', 'lead_y', 'axis_angle', 'non_orthogonality', 'offset_x', 'offset_y')


# The only node whose vision results are used.
VISION_PUBLISHER = 'vision_calibrator'
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'     # rmw's name for an endpoint not yet matched to a node


def vision_from_message(msg):
    """(CameraToPlate, GantryModel, the drive's leads (2,) m/rev) from a vision
    CalibrationResult message, checked: its kind, every value present, finite and in the
    units vision_calibrator states, and within the bounds of the vision gate that hold
    without the nominal lens and screws. The drive's leads (what it converts motor angles
    with) are the nominal ones the calibration recorded in its report, else the shipped
    gantry's.

    Raises
    ------
    InvalidInputError, CalibrationError
        Any of these fails (the message says which)."""
    # A result in units other than vision_calibrator's (VISION_UNITS) is another node's,
    # or a forgery.
    if msg.kind != 'vision':
        raise InvalidInputError(f'a {msg.kind!r} result on the vision topic, not a vision one')
    values = dict(zip(msg.names, msg.values))
    units = dict(zip(msg.names, msg.units))
    missing = [k for k in ('pixel_size', 'camera_angle') + GANTRY_KEYS if k not in values]
    if missing:
        raise InvalidInputError(f'vision result lacks {", ".join(missing)}')
    wrong = [f'{k} in {units.get(k)!r}' for k, unit in VISION_UNITS.items()
             if units.get(k) != unit]
    if wrong:
        raise InvalidInputError(f'vision result in other units: {", ".join(wrong)} (SI '
                                'expected: ' + ', '.join(f'{k} {u}' for k, u in VISION_UNITS.items())
                                + ')')
    if not all(np.isfinite(values[k]) for k in VISION_UNITS):
        raise InvalidInputError('vision result holds values that are not finite')
    if msg.residual_unit != 'm':
        raise InvalidInputError(f'vision result residual in {msg.residual_unit!r}, not m')
    check_vision_parameters(values, msg.rms_residual)
    return (CameraToPlate(values['pixel_size'], values['camera_angle']),
            GantryModel(**{k: values[k] for k in GANTRY_KEYS}), drive_leads(msg.report_json))


def drive_leads(report_json: str) -> np.ndarray:
    """The nominal leads (2,) m/rev a vision report recorded, else the shipped gantry's.

    Raises
    ------
    InvalidInputError
        Recorded leads that are not two positive finite numbers."""
    try:
        recorded = json.loads(report_json or '{}').get('nominal', {}).get('leads_m_per_rev')
    except (ValueError, AttributeError):
        recorded = None
    if recorded is None:
        return NOMINAL_LEADS
    leads = np.asarray(recorded, dtype=float) if isinstance(recorded, list) else np.zeros(0)
    if leads.shape != (2,) or not np.all(np.isfinite(leads)) or not np.all(leads > 0):
        raise InvalidInputError(f'vision result records nominal leads {recorded!r}, not two '
                                'positive values in m/rev')
    return leads


class MarkLocator:
    """Plate positions of Marks for ``node``, through its own service clients."""

    def __init__(self, node, callback_group, timeout: float, lattice: float = 2e-3,
                 approach: float = 1e-3):
        if not (lattice > 0 and approach >= 0 and timeout > 0):
            raise ValueError('lattice and timeout must be positive, approach >= 0')
        self.node, self.timeout = node, timeout
        self.lattice, self.approach = lattice, approach
        self._vision = None
        self.source: dict = {}       # file and version of the vision calibration in use
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
            self._only_the_vision_calibrator()
            vision = vision_from_message(msg)
        except MachineAlignmentError as exc:
            self.node.get_logger().error(f'ignoring vision result: {exc}')
            return
        with self._lock:
            self._vision = vision
            self.source = {'file': msg.file_path, 'version': int(msg.version)}
        self._vision_arrived.set()

    def _only_the_vision_calibrator(self, wait: float = 0.0) -> None:
        """CalibrationError while a node other than vision_calibrator publishes on the
        vision result topic: whose latched result arrived cannot be told apart then. A
        publisher just discovered may not have its node's name yet; it is waited for up to
        ``wait`` s, and not counted if it has none by then."""
        deadline = time.monotonic() + wait
        while True:
            names = {info.node_name for info in
                     self.node.get_publishers_info_by_topic(VISION_RESULT_TOPIC)}
            if UNKNOWN_NODE not in names or time.monotonic() >= deadline:
                break
            time.sleep(0.1)
        others = sorted(names - {VISION_PUBLISHER, UNKNOWN_NODE})
        if others:
            raise CalibrationError(
                f'{", ".join(others)} also publish(es) on {VISION_RESULT_TOPIC}: a vision '
                f'calibration is taken from {VISION_PUBLISHER} alone; stop the other '
                'publisher')

    @property
    def vision(self):
        """The vision calibration in force, checked (:func:`vision_from_message`) and from
        vision_calibrator alone. A latched message can arrive after the first service call
        when discovery is slow, so it is awaited up to the service timeout."""
        if not self._vision_arrived.wait(self.timeout):
            raise CalibrationError(
                'no vision calibration in force: vision_calibrator has not published '
                f'{VISION_RESULT_TOPIC} within {self.timeout:g} s (calibrate the vision '
                'system first)')
        self._only_the_vision_calibrator(wait=2.0)
        with self._lock:
            return self._vision

    def select_view(self, view: str) -> None:
        call_service(self.view_client, SelectView.Request(view=view), 'camera view', self.timeout)

    def _park(self, x: float, y: float, leads: np.ndarray) -> np.ndarray:
        """Park the gantry at (x, y) m from below; returns the motor angles (rev) as the
        drive converts them with ``leads`` (2,) m/rev."""
        for target in ((x - self.approach, y - self.approach), (x, y)):
            reached = call_service(self.move_client, MoveGantry.Request(
                x=float(target[0]), y=float(target[1])), 'gantry move', self.timeout)
        return np.array([reached.x, reached.y]) / leads

    def measure(self, expected, shape: str = 'circle') -> np.ndarray:
        """Plate positions (m, (k, 2)) of the one Mark of ``shape`` near each expected
        position ((k, 2), m).

        Raises
        ------
        CalibrationError
            No vision calibration yet, or a Mark is missing, clipped or not alone (the
            detector's reason is passed on), or a service does not answer.
        """
        camera2plate, gantry, leads = self.vision
        expected = np.atleast_2d(np.asarray(expected, dtype=float))
        if not np.all(np.isfinite(expected)):
            raise InvalidInputError('expected Mark positions contain NaN or infinite values')
        out = []
        for x, y in expected:
            # The lattice is in gantry commands (repeatable motor angles); the calibrated
            # model says which command brings the camera over the Mark: the plate frame can
            # sit millimetres from the command frame.
            command = gantry.revs_for([[x, y]])[0] * leads
            park = np.round(command / self.lattice) * self.lattice
            revs = self._park(*park, leads)
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
