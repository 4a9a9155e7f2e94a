"""aligner: align the substrate to the stencil with the calibrated XY-Theta stage.

Service ``aligner/align`` (Align) measures the substrate's fiducials (circles, camera
looking down) and the stencil's (crosses, looking up) near their expected plate positions,
finds the rigid motion that carries one set onto the other (least squares over >= 2
pairs), turns it into chain inputs with the chosen stage model (``parametric``,
``stepwise`` with the paper's interpolation, or ``nominal``), moves the stage approached
from below on every chain, and verifies by measuring the substrate again. The stage
model in force arrives as the latched ``/stage_calibrator/result``. A target outside the
workspace (the stroke; a stage ``description``'s, else the shipped [-5, 5] mm) is refused
without moving; ``description`` also sets the ``nominal`` model. Each alignment is recorded to an MCAP bag (the
stage calibration in force and the report, enough to plan it again offline) and its
report published on ``/aligner/report``.
"""
import json
import threading

import numpy as np
from alignment_msgs.msg import CalibrationResult, StageState
from alignment_msgs.srv import Align, MoveStage
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import String

from calib_core.errors import CalibrationError, InvalidInputError, MachineAlignmentError
from calib_core.nodes.calibrator import call_service, declare_paths
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.recording import RecordedRun
from calib_core.nodes.spin import run_node
from printer_alignment.core.alignment import plan_alignment, rigid_fit
from printer_alignment.core.stage import NOMINAL_STAGE, STROKE, path_from_below
from printer_alignment.core.stage_description import read_description
from printer_alignment.core.stage_calibration import ParametricModel, models_from_dict
from printer_alignment.core.records import (
    ALIGNER_REPORT_TOPIC as REPORT_TOPIC, STAGE_RESULT_TOPIC)
from printer_alignment.nodes.mark_locator import MarkLocator

MODELS = ('parametric', 'stepwise', 'nominal')
STATE_TOPIC = '/stage/state'
MODEL_WAIT_S = 3.0     # s, how long an alignment waits for a stage model it has not seen


def _pairs(values, name):
    values = [float(v) for v in values]
    if len(values) < 4 or len(values) % 2 or not np.all(np.isfinite(values)):
        raise ValueError(f'{name} must be finite x, y pairs (m), at least two Marks')
    return np.reshape(values, (-1, 2))


class AlignerNode(Node):

    def __init__(self):
        super().__init__('aligner')
        # Where to look for the fiducials (plate frame, m), taught once by jogging the
        # camera; the measured positions are what counts.
        self.declare_parameter('substrate_marks', [0.0401, 0.0642, 0.1500, 0.0947])
        self.declare_parameter('stencil_marks', [0.0401, 0.0642, 0.1500, 0.0947])
        self.declare_parameter('model', 'parametric')
        declare_paths(self, 'record_dir')
        self.declare_parameter('call_timeout_s', 10.0)
        self.declare_parameter('description', '')   # '': the shipped stage
        path = self.get_parameter('description').value
        described = read_description(path) if path else None
        self.stroke = described.stroke if described else STROKE
        self.substrate_expected = _pairs(self.get_parameter('substrate_marks').value,
                                         'substrate_marks')
        self.stencil_expected = _pairs(self.get_parameter('stencil_marks').value,
                                       'stencil_marks')
        if len(self.substrate_expected) != len(self.stencil_expected):
            raise ValueError('substrate_marks and stencil_marks need the same number of Marks')
        if self.get_parameter('model').value not in MODELS:
            raise ValueError(f'model must be one of {MODELS}')
        self.timeout = float(self.get_parameter('call_timeout_s').value)
        group = ReentrantCallbackGroup()
        self.locator = MarkLocator(self, group, self.timeout)
        self.move_client = self.create_client(MoveStage, 'stage/move', callback_group=group)
        self._models = {'nominal': ParametricModel(described.nominal() if described
                                                   else NOMINAL_STAGE)}
        self._stage_result = None    # the calibration message in force, recorded with each run
        self._lock = threading.Condition()
        self._busy = threading.Lock()
        self.create_subscription(CalibrationResult, STAGE_RESULT_TOPIC, self._on_stage,
                                 LATCHED, callback_group=group)
        self._q = None
        self.create_subscription(StageState, STATE_TOPIC, self._on_state, 10,
                                 callback_group=group)
        self.report_pub = self.create_publisher(String, REPORT_TOPIC, LATCHED)
        self.create_service(Align, 'aligner/align', self.on_align, callback_group=group,
                            qos_profile=SERVICES)

    def _on_stage(self, msg):
        if not msg.success:
            return
        try:
            models = models_from_dict(json.loads(msg.report_json)['models'])
        except (InvalidInputError, KeyError, ValueError) as exc:
            self.get_logger().error(f'ignoring stage calibration: {exc}')
            return
        with self._lock:
            self._models.update(models)
            self._stage_result = msg
            self._lock.notify_all()
        self.get_logger().info(f'stage calibration v{msg.version} in force')

    def _on_state(self, msg):
        with self._lock:
            self._q = np.array(msg.q, dtype=float)

    def _model(self, name):
        with self._lock:
            # A calibration that just finished may still be in flight on the latched topic.
            if not self._lock.wait_for(lambda: name in self._models, MODEL_WAIT_S):
                raise CalibrationError(f'no {name} stage model in force: run '
                                       'stage_calibrator/calibrate first (or use nominal)')
            return self._models[name]

    def _move(self, q):
        return call_service(self.move_client, MoveStage.Request(q=[float(v) for v in q]),
                            'stage move', self.timeout)

    def on_align(self, request, response):
        if not self._busy.acquire(blocking=False):
            response.success, response.message = False, 'an alignment is already running'
            return response
        try:
            report = self._align(request.model or self.get_parameter('model').value)
            response.q = report['q_m']
            response.angle = report['angle_rad']
            response.shift_x, response.shift_y = report['shift_m']
            response.position_error = report['verification']['position_error_m']
            response.orientation_error = report['verification']['orientation_error_rad']
            response.report_json = json.dumps(report)
            response.success, response.message = True, 'ok'
        except MachineAlignmentError as exc:
            self.get_logger().error(f'alignment failed: {exc}')
            response.success, response.message = False, str(exc)
        except Exception as exc:  # log a bug, answer, keep serving
            self.get_logger().error(f'internal error in alignment: {exc!r}')
            response.success, response.message = False, f'internal error: {exc!r}'
        finally:
            self._busy.release()
        return response

    def _align(self, model_name: str) -> dict:
        if model_name not in MODELS:
            raise InvalidInputError(f'unknown model {model_name!r}; use one of {MODELS}')
        model = self._model(model_name)
        with self._lock:
            q_now = self._q
        if q_now is None:
            raise CalibrationError(f'no stage state on {STATE_TOPIC} yet')
        self.locator.select_view('stencil')
        stencil = self.locator.measure(self.stencil_expected, 'cross')
        self.locator.select_view('substrate')
        substrate = self.locator.measure(self.substrate_expected, 'circle')
        plan = plan_alignment(model, q_now, substrate, stencil, self.stroke)
        for waypoint in path_from_below(plan.q, stroke=self.stroke):
            reached = self._move(waypoint)
        # Verify where the moved substrate Marks are expected now.
        c, s = np.cos(plan.angle), np.sin(plan.angle)
        moved = substrate @ np.array([[c, s], [-s, c]]) + plan.translation
        after = self.locator.measure(moved, 'circle')
        angle_left, _ = rigid_fit(after, stencil)
        report = {
            'model': model_name, 'stroke_m': self.stroke, 'q_before_m': q_now.tolist(),
            'q_planned_m': plan.q.tolist(),
            'q_m': list(reached.q), 'target_pose': plan.target_pose.tolist(),
            'stencil_m': stencil.tolist(), 'substrate_before_m': substrate.tolist(),
            'substrate_after_m': after.tolist(), 'angle_rad': plan.angle,
            'shift_m': plan.translation.tolist(), 'pair_fit_rms_m': plan.fit_rms,
            'verification': {
                'position_error_m': float(np.linalg.norm(after.mean(axis=0)
                                                         - stencil.mean(axis=0))),
                'orientation_error_rad': float(abs(angle_left)),
                'mark_errors_m': np.linalg.norm(after - stencil, axis=1).tolist()},
            'vision_calibration': dict(self.locator.source)}
        with self._lock:
            calibration = self._stage_result
        if calibration is not None:
            report['stage_calibration_version'] = calibration.version
        self._record(report, calibration)
        v = report['verification']
        self.get_logger().info(
            f'aligned with the {model_name} model: {v["position_error_m"] * 1e6:.2f} um, '
            f'{np.rad2deg(v["orientation_error_rad"]) * 3600:.2f} arcsec left')
        return report

    def _record(self, report: dict, calibration) -> None:
        """Publish the report and record it with the stage calibration it used, so the
        alignment can be planned again offline (``machine-align evaluate alignment``)."""
        topics = {REPORT_TOPIC: 'std_msgs/msg/String'}
        if calibration is not None:
            topics[STAGE_RESULT_TOPIC] = 'alignment_msgs/msg/CalibrationResult'
        with RecordedRun(self, 'alignment', topics) as run:
            if calibration is not None:
                run.record(STAGE_RESULT_TOPIC, calibration)
            run.record(REPORT_TOPIC, String(data=json.dumps(report)), self.report_pub)


def main(args=None):
    run_node(AlignerNode, args, threads=4)


if __name__ == '__main__':
    main()
