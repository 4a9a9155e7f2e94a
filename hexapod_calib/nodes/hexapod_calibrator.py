"""hexapod_calibrator: the hexapod's kinematic calibration on the live graph.

Service ``hexapod_calibrator/calibrate`` (RunCalibration; ``plan_yaml`` overrides fields of
hexapod_calib.core.procedure.HexapodPlan) plans well-conditioned poses, drives the hexapod
with actuator lengths (``hexapod/move``), measures each pose (``pose_sensor/measure``),
identifies the 42 parameters, repeats with the legs of the new model (the paper's
iteration), and evaluates on separate poses with the nominal and the calibrated model.
The geometry is written as an atomic, versioned YAML file in the form of DESIGN.md section
6, the result published latched on ``/hexapod_calibrator/result``, every stop on
``/hexapod_calibrator/measurements`` and progress on ``/hexapod_calibrator/progress``; the
run is recorded to an MCAP bag. One calibration at a time; a failed or interrupted run
leaves the previous calibration in force.

With ``description`` (a machine description YAML, docs/machine_description.md) the node
calibrates the user's hexapod: its nominal geometry, plans in its workspace (a request's
plan keys still override), the prediction at its instrument's noise, and the gate against
what it declares.

Service ``hexapod_calibrator/analyze_residuals`` (AnalyzeResiduals) runs the closed loop on
the last run's stops, each with its time and, where a sensor publishes it on
``temperature_topic``, the machine's temperature (recorded in the run's bag).
"""
import numpy as np
from alignment_msgs.msg import CalibrationResult, HexapodMeasurement, Progress
from alignment_msgs.srv import AnalyzeResiduals, MeasurePose, MoveHexapod, RunCalibration
from rclpy.callback_groups import ReentrantCallbackGroup
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from std_msgs.msg import Header

from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.nodes.analysis import AnalysisService
from calib_core.nodes.calibrator import (
    READ_ONLY, CalibrationService, call_service, declare_paths, described_machine,
    publish_calibration_in_force)
from calib_core.nodes.conversions import calibration_result_as_message
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.recording import RecordedRun
from calib_core.nodes.scene import POSE_TYPE, frame_of
from calib_core.nodes.spin import run_node
from calib_core.nodes.status import CalibratorStatus
from calib_core.nodes.temperature import TemperatureLog
from calib_core.parameters import ParameterSet
from calib_core.storage import write_calibration
from calib_core.temperature import TEMPERATURE_TOPIC, TEMPERATURE_TYPE, stamp_seconds
from hexapod_calib.core.calibration import PoseData, check_identification
from hexapod_calib.core.description import read_description
from hexapod_calib.core.geometry import (
    HexapodGeometry, calibrated_frames, nominal_geometry, read_geometry)
from hexapod_calib.core.loop_models import HexapodLoopModel
from hexapod_calib.core.planning import predict
from hexapod_calib.core.procedure import HexapodCalibration, HexapodPlan, run_hexapod_calibration
from hexapod_calib.core.records import (
    HEXAPOD_RESULT_TOPIC as RESULT_TOPIC, MEASUREMENTS_TOPIC, leg_lengths_from_message,
    pose_from_message)
from hexapod_calib.nodes.conversions import pose_as_message
from hexapod_calib.core.statics import leg_forces

ANALYSIS_TOPIC = '/hexapod_calibrator/analysis'
MEASURED_POSE_TOPIC = '/hexapod_calibrator/measured_pose'
CALIBRATION_NAME = 'hexapod_geometry'


def hexapod_result_message(calibration: HexapodCalibration, header, file_path='', version=0):
    report = calibration.report['identification']
    return calibration_result_as_message(
        'hexapod', header, report['parameters'], report['std_devs'], report['units'],
        calibration.report, report['residual_rms_m'], report['residual_max_m'], 'm',
        report['num_poses'], file_path, version)


class HexapodCalibratorNode(Node):

    def __init__(self):
        super().__init__('hexapod_calibrator')
        declare_paths(self, 'output_dir', 'record_dir')
        self.declare_parameter('nominal_geometry', '', READ_ONLY)
        self.declare_parameter('description', '', READ_ONLY)   # the user's machine description
        self.declare_parameter('call_timeout_s', 10.0)
        self.declare_parameter('payload_mass', 0.0, READ_ONLY)
        self.declare_parameter('payload_centre', [0.0, 0.0, 0.0], READ_ONLY)
        self.declare_parameter('temperature_topic', TEMPERATURE_TOPIC)  # '': no sensor
        self.payload_mass = float(self.get_parameter('payload_mass').value)
        self.payload_centre = [float(v) for v in self.get_parameter('payload_centre').value]
        if not (self.payload_mass >= 0 and len(self.payload_centre) == 3
                and np.all(np.isfinite(self.payload_centre))):
            raise InvalidInputError('payload_mass must be >= 0 kg and payload_centre 3 numbers (m)')
        # Every stop of the last completed run, in order, and the run's covariates per stop.
        self._last_run, self._run_covariates = [], {}
        self.timeout = float(self.get_parameter('call_timeout_s').value)
        if not self.timeout > 0:
            raise InvalidInputError('call_timeout_s must be > 0')
        # A described machine: its geometry, its workspace for plans, its instrument for
        # the prediction and the gate (docs/machine_description.md).
        self.description, self.nominal = described_machine(
            self, read_description, read_geometry, nominal_geometry)
        self._settled = None
        self._last_measurement = None  # the sensor's message, recorded as it came
        group = ReentrantCallbackGroup()
        self.temperatures = TemperatureLog(self, self.get_parameter('temperature_topic').value,
                                           group)
        self.move_client = self.create_client(MoveHexapod, 'hexapod/move', callback_group=group)
        self.measure_client = self.create_client(MeasurePose, 'pose_sensor/measure',
                                                 callback_group=group)
        self.status = CalibratorStatus(self, CALIBRATION_NAME, calibrated_frames)
        self.result_pub = self.status.tap(
            self.create_publisher(CalibrationResult, RESULT_TOPIC, LATCHED))
        self.progress_pub = self.status.tap(
            self.create_publisher(Progress, '/hexapod_calibrator/progress', 10), 'progress')
        self.measurement_pub = self.create_publisher(HexapodMeasurement, MEASUREMENTS_TOPIC, 10)
        calibration = CalibrationService(
            self, 'hexapod', lambda overrides: self._run(self._plan(overrides)),
            self._header, busy=self.status.busy, status=self.status)
        self.create_service(RunCalibration, 'hexapod_calibrator/calibrate', calibration,
                            callback_group=group, qos_profile=SERVICES)
        publish_calibration_in_force(self, CALIBRATION_NAME, self.result_pub,
                                     self._message_in_force)
        self.create_service(AnalyzeResiduals, 'hexapod_calibrator/analyze_residuals',
                            AnalysisService(self, 'hexapod', calibration.busy,
                                            self._loop_model, self._apply_extended,
                                            ANALYSIS_TOPIC, self._header, status=self.status),
                            callback_group=group, qos_profile=SERVICES)

    def _header(self):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id='base')

    def _plan(self, overrides: dict) -> HexapodPlan:
        """The plan keys asked for, over the described workspace (home, box, strokes)."""
        workspace = (self.description.workspace or {}) if self.description else {}
        return HexapodPlan.from_mapping({**workspace, **overrides})

    def _message_in_force(self, content: dict, path: str) -> CalibrationResult:
        """The result message of a geometry file: an identification's (with its sigmas
        and residuals) or, after the closed loop, the extended model's geometry."""
        geometry = HexapodGeometry.from_dict(content, path)
        values = geometry.parameters().as_dict()
        identification = (content.get('report') or {}).get('identification') or {}
        sigmas = identification.get('std_devs', {})
        return calibration_result_as_message(
            'hexapod', self._header(), values, {n: sigmas.get(n, 0.0) for n in values},
            {n: 'm' for n in values}, content.get('report') or content.get('analysis') or {},
            identification.get('residual_rms_m', 0.0), identification.get('residual_max_m', 0.0),
            'm', identification.get('num_poses', 0), path, content.get('version', 0))

    def _call(self, client, request, what):
        if client is self.move_client:
            self.status.check_cancelled()       # the safe point: before the next move
        return call_service(client, request, what, self.timeout)

    def _move_legs(self, lengths):
        request = MoveHexapod.Request(mode=MoveHexapod.Request.LEG_LENGTHS,
                                      leg_lengths=np.asarray(lengths, float).tolist())
        response = self._call(self.move_client, request, 'hexapod move')
        self._settled = response.settled
        return leg_lengths_from_message(response.leg_lengths)

    def _measure(self):
        response = self._call(self.measure_client, MeasurePose.Request(not_before=self._settled),
                              'pose measurement')
        self._last_measurement = response.pose.pose
        return pose_from_message(response.pose.pose.pose)

    def _record(self, run: RecordedRun, stops, phase, target, legs, measured):
        self.temperatures.record(run)
        target_pose = pose_as_message(target)
        measurement = HexapodMeasurement(header=self._header(), phase=phase, target=target_pose,
                                         leg_lengths=np.asarray(legs, float).tolist(),
                                         measured=self._last_measurement)
        run.record(MEASUREMENTS_TOPIC, measurement, self.measurement_pub)
        stops.append((target, measured, legs, stamp_seconds(measurement)))
        # What a viewer shows: the platform as measured and where it was sent.
        run.record(MEASURED_POSE_TOPIC, PoseStamped(header=self._header(),
                                                    pose=self._last_measurement.pose))
        run.record_frames([('base', 'platform', *frame_of(self._last_measurement.pose)),
                           ('base', 'platform_target', *frame_of(target_pose))])

    def _progress(self, step, total, message):
        self.progress_pub.publish(Progress(header=self._header(), task='hexapod_calibration',
                                           step=step, total=total, message=message))
        if step % 10 == 0 or step == total:
            self.get_logger().info(f'[{step}/{total}] {message}')

    def _run(self, plan: HexapodPlan) -> CalibrationResult:
        self._settled = self.get_clock().now().to_msg()
        poses = plan.poses(self.nominal)  # a plan that cannot work fails here, before a bag exists
        noise = ()
        if self.description:
            declared = self.description.measurement
            noise = (declared.instrument.position_sigma_m, declared.instrument.angle_sigma_rad,
                     declared.actuators.sigma_m)
        prediction = predict(self.nominal, *poses, *noise)
        moved = prediction['predicted_displacement_m']
        self.get_logger().info(f'plan of {len(poses[0])} poses: displacement error predicted '
                               f'{moved["rms"] * 1e6:.2f} um RMS, {moved["max"] * 1e6:.2f} um '
                               'max (1 sigma) on the evaluation poses, before anything moves')
        stops = []
        self.temperatures.start()
        with RecordedRun(self, 'hexapod', {
                MEASUREMENTS_TOPIC: 'alignment_msgs/msg/HexapodMeasurement',
                TEMPERATURE_TOPIC: TEMPERATURE_TYPE,
                MEASURED_POSE_TOPIC: POSE_TYPE,
                RESULT_TOPIC: 'alignment_msgs/msg/CalibrationResult'}) as run:
            calibration = run_hexapod_calibration(
                plan, self.nominal, self._move_legs, self._measure, self._progress,
                lambda *stop: self._record(run, stops, *stop), poses)
            # else nothing is put in force
            check_identification(calibration.report['identification'], self.nominal,
                                 self.description)
            calibration.report['plan'] = prediction
            if self.description:
                calibration.report['description'] = self.description.gate_report()
            path, version, _ = run.save(CALIBRATION_NAME, {
                **calibration.geometry.as_dict(), 'nominal': self.nominal.as_dict(),
                'report': calibration.report})
            result = hexapod_result_message(calibration, self._header(), str(path), version)
            run.record(RESULT_TOPIC, result, self.result_pub)
            self.temperatures.record(run)
        self._last_run = [stop[:3] for stop in stops]
        self._run_covariates, sentence = self.temperatures.covariates([s[3] for s in stops])
        self.get_logger().info(f'closed loop data: {len(stops)} stops; temperature: {sentence}')
        after = calibration.report['evaluation']['after']
        self.get_logger().info(f'done: max {after["max_displacement_m"] * 1e6:.1f} um, '
                               f'{after["max_angle_rad"] * 1e6:.0f} urad on separate poses; '
                               f'wrote {path}')
        return result

    def _loop_model(self, options: dict) -> HexapodLoopModel:
        if not self._last_run:
            raise CalibrationError('no calibration run to analyse yet: call '
                                   'hexapod_calibrator/calibrate first')
        targets, measured, legs = (np.array(column) for column in zip(*self._last_run))
        data = PoseData(targets, measured, legs, self._run_covariates)
        forces = (leg_forces(self.nominal, targets, self.payload_mass, self.payload_centre)
                  if self.payload_mass > 0 else None)
        return HexapodLoopModel(data, self.nominal, forces)

    def _apply_extended(self, result) -> str:
        report = result.report
        base = report['base_parameters']
        geometry = HexapodGeometry.from_parameters(ParameterSet.from_dict(base['after'],
                                                                          base['units']))
        content = {**geometry.as_dict(), 'kind': 'hexapod', 'effects': report['effects_added'],
                   'nominal': self.nominal.as_dict(),
                   'analysis': {k: report[k] for k in ('rms_before', 'rms_after', 'max_before',
                                                       'max_after', 'unit')}}
        path, _ = write_calibration(self.get_parameter('output_dir').value, CALIBRATION_NAME,
                                    content)
        return str(path)


def main(args=None):
    run_node(HexapodCalibratorNode, args, threads=4)


if __name__ == '__main__':
    main()
