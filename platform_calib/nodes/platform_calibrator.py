"""platform_calibrator: the screen-registration platform's identification and registration
on the live graph.

Service ``platform_calibrator/calibrate`` (RunCalibration; plan keys ``poses``,
``evaluation_poses``, ``span`` (x m, y m, theta rad), ``seed``, ``design`` (random, or I /
D: planned here, the prediction in the report), ``targets`` (a planned set of x, y, theta
rows), ``target_error`` (m: adaptive, poses added ``step`` at a time until the predicted
mark error is below it or ``max_poses`` is reached or predicted to miss it)) plans random
poses (all
checked against the stroke before anything moves), commands each through the nominal
inverse kinematics (``platform/move``), reads the feed sensors and the laser tracker
(``laser_tracker/measure``), identifies the 18 parameters, then evaluates on separate poses
with the nominal and the calibrated commands (composite mark error measured by the
tracker). The geometry is written as an atomic, versioned ``platform`` file (readable by
``machine-align compensate platform --geometry``), published latched on
``/platform_calibrator/result``, and the run recorded to MCAP (``machine-align calibrate
platform --bag`` solves it again).

With ``description`` (a machine description YAML, docs/machine_description.md) the nominal
geometry and the identification's gate are the described platform's, and the poses are
planned in its workspace box: its ``home`` and half-widths replace the ``home`` and
``span`` parameters (a request's keys override them).

Service ``platform_calibrator/register`` (RegisterScreen) measures the screen's two marks
(``platform/measure_marks``), computes the pose that puts them on target (the marks of the
screen at the platform's zero) and the feeds by ``method`` (exact, lm, pso: the source's
swarm, refused when it has not converged), moves, and measures again.

Service ``platform_calibrator/analyze_residuals`` (AnalyzeResiduals) runs the closed loop
on the last run's identification poses (feed effects: screw error, backlash, drift), each
with its time and, where a sensor publishes it on ``temperature_topic``, the machine's
temperature (recorded in the run's bag); the report is written and published, never put
in force (the compensation has no place for
feed effects: ``apply`` is refused).
"""
import dataclasses
import json

import numpy as np
from alignment_msgs.msg import CalibrationResult, PlatformMeasurement, Progress
from alignment_msgs.srv import (
    AnalyzeResiduals, MeasureMarks, MeasurePose, MovePlatform, RegisterScreen, RunCalibration)
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Header

from calib_core.errors import CalibrationError, InvalidInputError, MachineAlignmentError
from calib_core.frames import planar
from calib_core.nodes.analysis import AnalysisService
from calib_core.nodes.calibrator import (
    READ_ONLY, CalibrationService, call_service, check_when_set, declare_paths,
    described_machine, one_of, publish_calibration_in_force)
from calib_core.nodes.conversions import calibration_result_as_message
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.recording import RecordedRun
from calib_core.nodes.scene import POSE_TYPE, pose_stamped
from calib_core.nodes.spin import run_node
from calib_core.nodes.status import CalibratorStatus
from calib_core.nodes.temperature import TemperatureLog
from calib_core.temperature import TEMPERATURE_TOPIC, TEMPERATURE_TYPE, stamp_seconds
from platform_calib.core.compensation import METHODS, composite_error, mark_positions
from platform_calib.core.description import read_description
from platform_calib.core.geometry import (
    calibrated_frames, geometry_mapping, nominal_geometry, read_geometry)
from platform_calib.core.identification import check_identification
from platform_calib.core.kinematics import inverse
from platform_calib.core.loop_model import PlatformLoopModel
from platform_calib.core.procedure import PlatformPlan, data_of, run_platform_calibration
from platform_calib.core.records import MEASUREMENTS_TOPIC, RESULT_TOPIC
from platform_calib.core.registration import pose_of_marks, register
from platform_calib.nodes.conversions import planar_pose_from_message

PLAN_KEYS = ('poses', 'evaluation_poses', 'span', 'home', 'seed', 'design', 'targets',
             'target_error', 'max_poses', 'step')
ANALYSIS_TOPIC = '/platform_calibrator/analysis'
MEASURED_POSE_TOPIC = '/platform_calibrator/measured_pose'


def platform_result_message(content: dict, header, file_path='', version=0):
    report = content['report']
    units = report['units']
    return calibration_result_as_message(
        'platform', header, content['parameters'], report['std_devs'], units, report,
        report['residual_rms_m'], report['residual_max_m'], 'm', report['poses'], file_path,
        version)


class PlatformCalibratorNode(Node):

    def __init__(self):
        super().__init__('platform_calibrator')
        declare_paths(self, 'output_dir', 'record_dir')
        self.declare_parameter('poses', 20)
        self.declare_parameter('evaluation_poses', 10)
        self.declare_parameter('span', [5e-3, 5e-3, float(np.deg2rad(5.0))])
        self.declare_parameter('home', [0.0, 0.0, 0.0])      # x m, y m, theta rad
        self.declare_parameter('seed', 0)
        self.declare_parameter('design', 'random')
        self.declare_parameter('target_error', 0.0)     # m; 0: no adaptive rounds
        self.declare_parameter('max_poses', 60)
        self.declare_parameter('step', 4)
        self.declare_parameter('method', 'exact')
        self.declare_parameter('nominal_geometry', '', READ_ONLY)     # YAML; empty: the built-in
        self.declare_parameter('description', '', READ_ONLY)   # the user's machine description
        self.declare_parameter('call_timeout_s', 10.0)
        self.declare_parameter('temperature_topic', TEMPERATURE_TOPIC)  # '': no sensor
        # A described platform: its geometry, its workspace for plans and the gate from its
        # declared noise and size.
        self.description, self.nominal = described_machine(
            self, read_description, read_geometry, nominal_geometry)
        self._plan_from_parameters({})                      # a bad plan stops the start
        if self.get_parameter('method').value not in METHODS:
            raise ValueError(f'method must be one of {METHODS}')
        self.timeout = float(self.get_parameter('call_timeout_s').value)
        self.model, self.feeds = None, None
        group = ReentrantCallbackGroup()
        self.temperatures = TemperatureLog(self, self.get_parameter('temperature_topic').value,
                                           group)
        self._recorded = []       # the run's stops as recorded, each with its stamp (s)
        self.move_client = self.create_client(MovePlatform, 'platform/move', callback_group=group)
        self.tracker_client = self.create_client(MeasurePose, 'laser_tracker/measure',
                                                 callback_group=group)
        self.marks_client = self.create_client(MeasureMarks, 'platform/measure_marks',
                                               callback_group=group)
        self.status = CalibratorStatus(self, 'platform', calibrated_frames)
        self.result_pub = self.status.tap(
            self.create_publisher(CalibrationResult, RESULT_TOPIC, LATCHED))
        self.measurement_pub = self.create_publisher(PlatformMeasurement, MEASUREMENTS_TOPIC, 10)
        self.progress_pub = self.status.tap(
            self.create_publisher(Progress, '/platform_calibrator/progress', 10), 'progress')
        self.calibration_service = CalibrationService(
            self, 'platform', self._run, self._header, busy=self.status.busy, status=self.status)
        self.create_service(RunCalibration, 'platform_calibrator/calibrate',
                            self.calibration_service, callback_group=group, qos_profile=SERVICES)
        self.create_service(RegisterScreen, 'platform_calibrator/register', self.on_register,
                            callback_group=group, qos_profile=SERVICES)
        publish_calibration_in_force(self, 'platform', self.result_pub, self._in_force)
        # The identification stops of the last completed run and their covariates.
        self._identified, self._identified_covariates = [], {}
        self.create_service(AnalyzeResiduals, 'platform_calibrator/analyze_residuals',
                            AnalysisService(
                                self, 'platform', self.calibration_service.busy,
                                self._loop_model, 'the platform\'s compensation has no place '
                                'for feed effects', ANALYSIS_TOPIC, self._header, status=self.status),
                            callback_group=group, qos_profile=SERVICES)
        # A peer's `ros2 param set` meets the same checks as a request's plan.
        check_when_set(self, PLAN_KEYS, self._plan_from_parameters,
                       {'method': one_of('method', METHODS)})

    def _in_force(self, content, path):
        self.model = read_geometry(path)
        return platform_result_message(content, self._header(), path, content.get('version', 0))

    def _header(self):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id='base')

    def _plan_from_parameters(self, overrides: dict) -> PlatformPlan:
        unknown = set(overrides) - set(PLAN_KEYS)
        if unknown:
            raise InvalidInputError(f'unknown plan keys {sorted(unknown)}; known: {list(PLAN_KEYS)}')
        described = {}
        if self.description:
            box = self.description.box()
            described = {'home': box['home'], 'span': (*box['translation'], box['rotation'])}
        g = lambda n: overrides.get(n, described.get(n, self.get_parameter(n).value))  # noqa: E731
        return PlatformPlan(g('poses'), g('evaluation_poses'), tuple(g('span')), g('seed'),
                            g('design'), tuple(overrides.get('targets', ())),
                            g('target_error'), g('max_poses'), g('step'), tuple(g('home')))

    def _move(self, feeds):
        self.status.check_cancelled()       # the safe point: before the next move
        self._moved_at = self.get_clock().now()
        reached = call_service(self.move_client, MovePlatform.Request(
            feeds=[float(v) for v in feeds]), 'platform move', self.timeout)
        self.feeds = np.array(reached.feeds)
        return self.feeds, np.array(reached.direction, dtype=float)

    def _track(self):
        measured = call_service(self.tracker_client, MeasurePose.Request(
            not_before=self._moved_at.to_msg()), 'laser tracker', self.timeout)
        return planar_pose_from_message(measured.pose.pose.pose)

    def _marks(self):
        measured = call_service(self.marks_client, MeasureMarks.Request(), 'mark measurement',
                                self.timeout)
        return np.array(measured.marks, dtype=float).reshape(2, 2)

    def _progress(self, step, total, message):
        self.progress_pub.publish(Progress(header=self._header(), task='platform_calibration',
                                           step=step, total=total, message=message))
        self.get_logger().info(f'[{step}/{total}] {message}')

    def _record(self, run, stop):
        self.temperatures.record(run)
        measurement = PlatformMeasurement(
            header=self._header(), phase=stop.phase, target=[float(v) for v in stop.target],
            feeds=[float(v) for v in stop.feeds], direction=[int(v) for v in stop.direction],
            measured=[float(v) for v in stop.measured])
        run.record(MEASUREMENTS_TOPIC, measurement, self.measurement_pub)
        self._recorded.append((stop, stamp_seconds(measurement)))
        # What a viewer shows: the platform as the tracker measured it and where it was sent.
        measured = planar(*stop.measured)
        run.record(MEASURED_POSE_TOPIC, pose_stamped(self._header(), *measured))
        run.record_frames([('base', 'platform', *measured),
                           ('base', 'platform_target', *planar(*stop.target))])

    def _run(self, overrides: dict) -> CalibrationResult:
        plan = self._plan_from_parameters(overrides)
        self.temperatures.start()
        self._recorded = []
        with RecordedRun(self, 'platform', {
                MEASUREMENTS_TOPIC: 'alignment_msgs/msg/PlatformMeasurement',
                TEMPERATURE_TOPIC: TEMPERATURE_TYPE,
                MEASURED_POSE_TOPIC: POSE_TYPE,
                RESULT_TOPIC: 'alignment_msgs/msg/CalibrationResult'}) as run:
            result, evaluation, _, prediction = run_platform_calibration(
                plan, self.nominal, self._move, self._track,
                lambda stop: self._record(run, stop), self._progress)
            # else nothing is put in force
            check_identification(result, self.nominal, self.description)
            # The nominal it started from, so the run's bag solves again without it.
            report = {**result.report(), 'evaluation': evaluation,
                      **({'plan': prediction} if prediction else {}),
                      'nominal_geometry': geometry_mapping(self.nominal)}
            if self.description:
                report['description'] = self.description.gate_report()
            geometry = result.geometry
            path, version, content = run.save('platform', {**geometry_mapping(geometry),
                                                           'report': report})
            message = platform_result_message(content, self._header(), str(path), version)
            run.record(RESULT_TOPIC, message, self.result_pub)
            self.temperatures.record(run)
        self.model = geometry
        identified = [(stop, stamp) for stop, stamp in self._recorded if stop.phase == 'identify']
        self._identified = [stop for stop, _ in identified]
        self._identified_covariates, sentence = self.temperatures.covariates(
            [stamp for _, stamp in identified])
        self.get_logger().info(f'closed loop data: {len(identified)} identification poses; '
                               f'temperature: {sentence}')
        e = evaluation
        self._progress(1, 1, f'done: composite mark error (tracker) median '
                             f'{e["evaluate_nominal"]["median_m"] * 1e6:.1f} um nominal, '
                             f'{e["evaluate_calibrated"]["median_m"] * 1e6:.1f} um calibrated; '
                             f'wrote {path}')
        return message

    def _loop_model(self, options: dict) -> PlatformLoopModel:
        if not self._identified:
            raise CalibrationError('no platform calibration run to analyse yet: call '
                                   'platform_calibrator/calibrate first')
        data = data_of(self._identified)
        return PlatformLoopModel(dataclasses.replace(
            data, covariates={**data.covariates, **self._identified_covariates}), self.nominal)

    def on_register(self, request, response):
        if not self.calibration_service.busy.acquire(blocking=False):
            response.success, response.message = False, 'a calibration is running'
            return response
        try:
            if self.model is None:
                raise CalibrationError('no platform calibration in force: call '
                                       'platform_calibrator/calibrate first')
            method = request.method or self.get_parameter('method').value
            if self.feeds is None:               # home first: the feeds are not known yet
                self._move(inverse(self.nominal, np.zeros((1, 3)))[0])
            targets = mark_positions(np.zeros((1, 3)))[0]
            seen = []

            def measure():
                seen.append(self._marks())
                return seen[-1]
            pose, result = register(self.model, self.nominal, self.feeds, measure,
                                    self._move, targets, method)
            after = self._marks()
            before, measured = (float(composite_error(pose_of_marks(marks)[None],
                                                      pose_of_marks(targets)[None])[0])
                                for marks in (seen[0], after))
            response.pose = [float(v) for v in pose]
            response.feeds = [float(v) for v in result.feeds]
            response.predicted_error = float(result.predicted_error)
            response.measured_error = measured
            response.report_json = json.dumps({'method': method, 'message': result.message,
                                               'seconds': result.seconds,
                                               'error_before_m': before,
                                               'marks_before_m': seen[0].tolist(),
                                               'marks_after_m': after.tolist()})
            response.success, response.message = True, 'ok'
            self.get_logger().info(f'registered ({method}): marks off by {before * 1e6:.1f} um '
                                   f'before, {measured * 1e6:.1f} um after (composite, '
                                   'measured)')
        except MachineAlignmentError as exc:
            self.get_logger().error(f'registration failed: {exc}')
            response.success, response.message = False, str(exc)
        finally:
            self.calibration_service.busy.release()
        return response


def main(args=None):
    run_node(PlatformCalibratorNode, args, threads=4)


if __name__ == '__main__':
    main()
