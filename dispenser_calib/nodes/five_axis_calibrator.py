"""five_axis_calibrator: the five-axis dispenser's vision calibration on the live graph.

Service ``five_axis_calibrator/calibrate`` (RunCalibration; plan keys ``seed``,
``evaluation``, ``frames``, ``design`` with ``stops``, ``targets``, ``target_error`` with
``max_stops`` and ``step``) plans the stepwise stops (linear, A alone, C alone), or ``stops``
chosen by the shared planner (``design`` I or D, about the calibration in force, else the
nominal model; the prediction logged before anything moves and kept in the report), or
measures ``targets`` as given; with ``target_error`` (m) it adds stops until the predicted
placement error meets it (the adaptive mode, ``report['adaptive']``); and ``evaluation``
held-out stops where A and C both turn, checks every stop against the strokes before
anything moves, drives (``five_axis/move``), images the board (``five_axis/capture_board``;
with ``frames`` true (plan key or parameter), takes the camera's frame from ``five_axis/capture_frame`` and finds and
names the dots itself with the Mark detector and the calibration in force, else the
nominal model), calibrates (Zhang, stepwise start, joint refinement with RANSAC over images) and evaluates
on the held-out images. The calibration is written as an atomic, versioned ``five_axis``
file (readable by ``machine-align locate --calibration``), published latched on
``/five_axis_calibrator/result``, and the run recorded to MCAP (``machine-align calibrate
five-axis --bag`` solves it again) with, for a viewer, each stop's machine frames on ``/tf``
(commanded axes, nominal kinematics) and each camera frame used on
``/five_axis_calibrator/frame`` (sensor_msgs/CompressedImage, ``frame_format`` jpeg or png).

Service ``five_axis_calibrator/locate`` (LocateWorkpiece; plan keys ``views`` (list of
[a, c] rad), ``path_angles`` [a, c]) images each of the part's CAD features (``part_cad``)
from several views (``five_axis/capture_features``), triangulates them through the
calibration in force, fits the part's pose and places the dispensing path (``part_path``,
needle tip ``needle_tip`` in the camera frame); every pose is checked against the strokes
first.

Service ``five_axis_calibrator/measure_needle`` (MeasureNeedle; plan keys ``spots``, ``views``)
dispenses a test dot at each spot (``five_axis/dispense``), images each from several views
(``five_axis/capture_dispensed``), locates them through the calibration in force and takes
the needle tip from where they were dispensed; the tip is used by ``locate`` from then on
and written as the versioned ``needle`` file (read again at start).

Service ``five_axis_calibrator/analyze_residuals`` (AnalyzeResiduals; plan keys ``tilts``
(rad), ``step`` (rad), ``both_ways`` besides the loop's own) images the board over a sweep
with the linear axes held (A at each tilt, C round the turn), takes the board's pose in
each through the calibration in force and runs the closed loop on the rotary axes
(:class:`dispenser_calib.core.loop_model.RotaryLoopModel`): a worm gear's error, lost
motion, error motion, drift (each image with its time and, where a sensor publishes it on
``temperature_topic``, the machine's temperature). The sweep's images are recorded
(``five_axis_sweep`` bag; ``machine-align analyze rotary --data`` on them with
``--calibration`` repeats it offline).
"""
import json

import numpy as np
from alignment_msgs.msg import CalibrationResult, FiveAxisObservation, Progress
from alignment_msgs.srv import (
    AnalyzeResiduals, CaptureDots, CaptureFrame, LocateWorkpiece, MeasureNeedle, MoveFiveAxis,
    RunCalibration)
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from calib_core.checks import MAX_SEED, whole_number
from calib_core.errors import CalibrationError, InvalidInputError, MachineAlignmentError
from calib_core.nodes.analysis import AnalysisService
from calib_core.nodes.calibrator import (
    READ_ONLY, CalibrationService, call_service, check_when_set, declare_paths, one_of, parse_plan,
    publish_calibration_in_force)
from calib_core.nodes.conversions import calibration_result_as_message
from calib_core.nodes.images import image_from_message
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.recording import RecordedRun
from calib_core.nodes.scene import IMAGE_TYPE, compressed_image
from calib_core.nodes.spin import run_node
from calib_core.nodes.status import CalibratorStatus
from calib_core.nodes.temperature import TemperatureLog
from calib_core.storage import read_calibration, write_calibration
from calib_core.temperature import TEMPERATURE_TOPIC, TEMPERATURE_TYPE, stamp_seconds
from dispenser_calib.core.board_images import observe_frame
from dispenser_calib.core.data import board_as_dict
from dispenser_calib.core.description import SHIPPED_GEOMETRY, read_description
from dispenser_calib.core.loop_model import RotaryLoopModel
from dispenser_calib.core.model import (
    NAMES, calibrated_frames, covariance_from, model_from, nominal_frames,
    nominal_model, parameter_unit)
from dispenser_calib.core.planning import NOISE_PX, stops_from_plan_keys
from dispenser_calib.core.procedure import (
    FEATURE_VIEWS, NEEDLE_TIP, PART_CAD, PART_PATH, SHIPPED_WORKSPACE, TEST_SPOTS,
    locate_workpiece, measure_needle, measure_sweep, rotary_sweep, run_five_axis_calibration)
from dispenser_calib.core.records import OBSERVATIONS_TOPIC, RESULT_TOPIC
from dispenser_calib.core.target_poses import pose_variants, poses_from_images

SHIPPED_IMAGE_SIZE = tuple(SHIPPED_GEOMETRY['image_size_px'])
PLANNED_KEYS = ('design', 'stops', 'targets', 'target_error', 'max_stops', 'step')
PLAN_KEYS = ('seed', 'evaluation', 'frames') + PLANNED_KEYS
SWEEP_KEYS = ('tilts', 'step', 'both_ways')
ANALYSIS_TOPIC = '/five_axis_calibrator/analysis'
FRAME_TOPIC = '/five_axis_calibrator/frame'


def five_axis_result_message(content: dict, header, file_path='', version=0):
    report = content['report']
    return calibration_result_as_message(
        'five-axis', header, report['parameters'], report['std_devs'],
        {n: parameter_unit(n) for n in NAMES}, report, report['rms_reprojection_px'],
        max(report['per_image_rms_px'].values()), 'px', report['images_used'], file_path,
        version)


class FiveAxisCalibratorNode(Node):

    def __init__(self):
        super().__init__('five_axis_calibrator')
        declare_paths(self, 'output_dir', 'record_dir')
        self.declare_parameter('seed', 0)
        self.declare_parameter('evaluation', 6)
        self.declare_parameter('image_size', [2448, 2048])   # the shipped camera's
        self.declare_parameter('description', '', READ_ONLY)   # the user's machine description
        self.declare_parameter('call_timeout_s', 10.0)
        self.declare_parameter('temperature_topic', TEMPERATURE_TOPIC)  # '': no sensor
        self.declare_parameter('part_cad', PART_CAD.ravel().tolist())
        self.declare_parameter('part_path', PART_PATH.ravel().tolist())
        self.declare_parameter('needle_tip', NEEDLE_TIP.tolist())
        self.declare_parameter('frames', False)
        self.declare_parameter('frame_format', 'jpeg')  # frames in the bag: jpeg or png (lossless)
        if self.get_parameter('frame_format').value not in ('jpeg', 'png'):
            raise ValueError('frame_format must be jpeg (about 0.5 MB a frame in the bag) or '
                             'png (lossless, about 2.3 MB)')
        self._frame = None       # the last camera frame taken, until it is recorded
        self._plan_from_parameters({})
        self.cad = self._triples('part_cad')
        self.path = self._triples('part_path')
        self.tip = np.asarray(self.get_parameter('needle_tip').value, dtype=float)
        if self.tip.shape != (3,) or not np.all(np.isfinite(self.tip)):
            raise ValueError('needle_tip must be x, y, z (m) in the camera frame')
        measured = read_calibration(self.get_parameter('output_dir').value, 'needle')
        if measured is not None:     # the last measured tip overrides the configured one
            self.tip = np.asarray(measured['tip_m'], dtype=float).reshape(3)
        self.model = None
        self.covariance = None        # the calibration's parameters' (31, 31), SI
        size = [int(v) for v in self.get_parameter('image_size').value]
        if len(size) != 2 or min(size) <= 0:
            raise ValueError('image_size must be two positive px counts')
        # A description holds the camera, strokes and working distance, the dot noise
        # plans are predicted at and the gate (docs/machine_description.md).
        described = self.get_parameter('description').value
        if described and tuple(size) != SHIPPED_IMAGE_SIZE:
            raise InvalidInputError('give image_size or description (it holds the camera), '
                                    'not both')
        self.description = read_description(described) if described else None
        self.workspace = self.description.workspace() if described else SHIPPED_WORKSPACE
        self.image_size = self.description.image_size if described else tuple(size)
        self.timeout = float(self.get_parameter('call_timeout_s').value)
        self.pose = np.zeros(5)
        self.nominal = (self.description.nominal() if described
                        else nominal_model(size=self.image_size))
        group = ReentrantCallbackGroup()
        self.temperatures = TemperatureLog(self, self.get_parameter('temperature_topic').value,
                                           group)
        self.move_client = self.create_client(MoveFiveAxis, 'five_axis/move', callback_group=group)
        self.capture_client = self.create_client(CaptureDots, 'five_axis/capture_board',
                                                 callback_group=group)
        self.features_client = self.create_client(CaptureDots, 'five_axis/capture_features',
                                                  callback_group=group)
        self.frame_client = self.create_client(CaptureFrame, 'five_axis/capture_frame',
                                               callback_group=group)
        self.dispense_client = self.create_client(Trigger, 'five_axis/dispense',
                                                  callback_group=group)
        self.dispensed_client = self.create_client(CaptureDots, 'five_axis/capture_dispensed',
                                                   callback_group=group)
        self.status = CalibratorStatus(self, 'five_axis', calibrated_frames)
        self.result_pub = self.status.tap(
            self.create_publisher(CalibrationResult, RESULT_TOPIC, LATCHED))
        self.observation_pub = self.create_publisher(FiveAxisObservation, OBSERVATIONS_TOPIC, 10)
        self.progress_pub = self.status.tap(
            self.create_publisher(Progress, '/five_axis_calibrator/progress', 10), 'progress')
        self.calibration_service = CalibrationService(
            self, 'five-axis', self._run, self._header, busy=self.status.busy, status=self.status)
        self.create_service(RunCalibration, 'five_axis_calibrator/calibrate',
                            self.calibration_service, callback_group=group, qos_profile=SERVICES)
        self.create_service(AnalyzeResiduals, 'five_axis_calibrator/analyze_residuals',
                            AnalysisService(
                                self, 'five_axis', self.calibration_service.busy, self._sweep,
                                'the five-axis calibration file has no place for rotary-axis '
                                'effects yet', ANALYSIS_TOPIC, self._header, self._progress,
                                options=SWEEP_KEYS, status=self.status),
                            callback_group=group, qos_profile=SERVICES)
        self.create_service(LocateWorkpiece, 'five_axis_calibrator/locate', self.on_locate,
                            callback_group=group, qos_profile=SERVICES)
        self.create_service(MeasureNeedle, 'five_axis_calibrator/measure_needle',
                            self.on_measure_needle, callback_group=group, qos_profile=SERVICES)
        publish_calibration_in_force(self, 'five_axis', self.result_pub, self._in_force)
        # A peer's `ros2 param set` meets the same checks as a request's plan.
        check_when_set(self, PLAN_KEYS, self._plan_from_parameters,
                       {'frame_format': one_of('frame_format', ('jpeg', 'png'))})

    def _triples(self, name: str) -> np.ndarray:
        values = np.asarray(self.get_parameter(name).value, dtype=float)
        if values.size == 0 or values.size % 3 or not np.all(np.isfinite(values)):
            raise ValueError(f'{name} must be x y z triples (m)')
        return values.reshape(-1, 3)

    def _in_force(self, content, path):
        # Both read before either is kept: a file refused here leaves nothing in force.
        model, covariance = model_from(content, path), covariance_from(content, path)
        message = five_axis_result_message(content, self._header(), path,
                                           content.get('version', 0))
        self.model, self.covariance = model, covariance
        return message

    def _header(self):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id='camera')

    def _plan_from_parameters(self, overrides: dict) -> tuple[int, int, bool, dict]:
        """seed, evaluation, frames, and the keys that choose the stops (checked when the
        stops are planned)."""
        unknown = set(overrides) - set(PLAN_KEYS)
        if unknown:
            raise InvalidInputError(f'unknown plan keys {sorted(unknown)}; known: {list(PLAN_KEYS)}')
        g = lambda n: overrides.get(n, self.get_parameter(n).value)  # noqa: E731
        if not isinstance(g('frames'), bool):
            raise InvalidInputError(f'frames must be true or false, not {g("frames")!r}')
        return (whole_number(g('seed'), 'seed', 0, MAX_SEED), whole_number(g('evaluation'), 'evaluation', 0),
                g('frames'), {k: overrides[k] for k in PLANNED_KEYS if k in overrides})

    def _move(self, pose):
        self.status.check_cancelled()       # the safe point: before the next move
        reached = call_service(self.move_client, MoveFiveAxis.Request(
            pose=[float(v) for v in pose]), 'five-axis move', self.timeout)
        self.pose = np.array(reached.pose)
        return self.pose

    def _capture(self, client=None, what='board image'):
        found = call_service(client or self.capture_client, CaptureDots.Request(), what,
                             self.timeout)
        return (np.column_stack([found.i, found.j]).reshape(-1, 2),
                np.column_stack([found.u, found.v]).reshape(-1, 2))

    def _capture_frame(self):
        """The board's dots (indices (k, 2), pixels (k, 2)) found in a camera frame and
        named with the calibration in force (the nominal model before the first)."""
        taken = call_service(self.frame_client, CaptureFrame.Request(), 'camera frame',
                             self.timeout)
        self._frame = image_from_message(taken.image)
        image = observe_frame(self._frame, self.pose,
                              self.model or self.nominal, f'frame at {self.pose.round(6).tolist()}',
                              board=self.workspace.board)
        return image.indices, image.pixels

    def _dispense(self):
        call_service(self.dispense_client, Trigger.Request(), 'dispense', self.timeout)

    def _capture_dispensed(self):
        """(dot numbers (n,), pixels (n, 2)) of the dispensed dots in the current image."""
        numbers, pixels = self._capture(self.dispensed_client, 'dispensed-dot image')
        return numbers[:, 0], pixels

    def _capture_features(self):
        """(feature numbers (n,), pixels (n, 2)) in the current image."""
        numbers, pixels = self._capture(self.features_client, 'feature image')
        return numbers[:, 0], pixels

    def _record(self, run, image, phase) -> float:
        """Records an image's observation (and, when frames are used, its frame); returns
        the observation's stamp (s)."""
        observation = FiveAxisObservation(
            header=self._header(), image=image.name, phase=phase,
            pose=[float(v) for v in image.pose], i=[int(v) for v in image.indices[:, 0]],
            j=[int(v) for v in image.indices[:, 1]], u=[float(v) for v in image.pixels[:, 0]],
            v=[float(v) for v in image.pixels[:, 1]])
        run.record(OBSERVATIONS_TOPIC, observation, self.observation_pub)
        # What a viewer shows: the machine at the commanded pose (nominal kinematics) and,
        # when frames are used, the camera's frame the dots were found in.
        run.record_frames((self.description.frames if self.description
                           else nominal_frames)(image.pose))
        frame, self._frame = self._frame, None
        if frame is not None:
            run.record(FRAME_TOPIC, compressed_image(frame, self._header(),
                                                     self.get_parameter('frame_format').value))
        return stamp_seconds(observation)

    def _progress(self, step, total, message):
        self.progress_pub.publish(Progress(header=self._header(), task='five_axis_calibration',
                                           step=step, total=total, message=message))
        self.get_logger().info(f'[{step}/{total}] {message}')

    def _run(self, overrides: dict) -> CalibrationResult:
        seed, evaluation, frames, choice = self._plan_from_parameters(overrides)
        stops, plan, adapt = stops_from_plan_keys(
            choice, self.model or self.nominal, self.image_size, seed,
            self.description.centroid_sigma_px if self.description else NOISE_PX, self.workspace)
        if plan is not None:
            self._progress(0, 1, f'{len(stops)} stops planned ({plan["criterion"]}): predicted '
                                 f'before anything moves: part placement '
                                 f'{plan["predicted_working_error_m"]["rms"] * 1e6:.2f} um RMS, '
                                 f'E_B0A +- {plan["predicted_iso230_7_sigmas"]["E_B0A"] * 1e6:.0f}'
                                 f' urad, E_B0C +- '
                                 f'{plan["predicted_iso230_7_sigmas"]["E_B0C"] * 1e6:.0f} urad')
        self._frame = None      # a frame left by a failed run belongs to no stop of this one
        with RecordedRun(self, 'five_axis', {
                OBSERVATIONS_TOPIC: 'alignment_msgs/msg/FiveAxisObservation',
                FRAME_TOPIC: IMAGE_TYPE,
                RESULT_TOPIC: 'alignment_msgs/msg/CalibrationResult'}) as run:
            result, report, _ = run_five_axis_calibration(
                self.nominal, self.image_size, seed, evaluation, self._move,
                self._capture_frame if frames else self._capture,
                lambda image, phase: self._record(run, image, phase), self._progress, stops,
                adapt, self.description)
            if plan is not None:
                report['plan'] = plan
            report['image_size_px'] = list(self.image_size)
            report['board'] = board_as_dict(self.workspace.board)
            if self.description:
                report['description'] = self.description.gate_report()
            if adapt is not None:
                report['adaptive'] = adapt.report()
            # The covariance: what the rotary loop weighs a sweep's effects against.
            path, version, content = run.save('five_axis', {
                'parameters': report['parameters'], 'std_devs': report['std_devs'],
                'covariance': result.covariance.tolist(), 'board': report['board'],
                'report': report})
            message = five_axis_result_message(content, self._header(), str(path), version)
            run.record(RESULT_TOPIC, message, self.result_pub)
        self.model, self.covariance = result.model, result.covariance
        held = report.get('held_out', {})
        self._progress(1, 1, f'done: mean reprojection {report["mean_reprojection_px"]:.3f} px; '
                             f'held out {held.get("rms_px_calibrated", float("nan")):.3f} px RMS '
                             f'(nominal {held.get("rms_px_nominal", float("nan")):.1f}); '
                             f'set aside {sorted(result.outliers) or "none"}; wrote {path}')
        return message

    def _sweep(self, options: dict) -> RotaryLoopModel:
        """Image the board over a sweep with the linear axes held (plan keys ``tilts``,
        ``step``, ``both_ways``), recorded, and its board poses through the calibration in
        force, as the rotary axes' loop model."""
        if self.model is None:
            raise CalibrationError('no five-axis calibration in force: call '
                                   'five_axis_calibrator/calibrate first')
        tilts = np.asarray(options.get('tilts', np.linspace(-0.3, 0.3, 5)), dtype=float)
        step = options.get('step', float(np.deg2rad(22.5)))
        both_ways = options.get('both_ways', False)
        if tilts.ndim != 1 or not len(tilts) or not np.all(np.isfinite(tilts)):
            raise InvalidInputError('tilts must be a list of A angles (rad)')
        if not isinstance(step, (int, float)) or not 0.01 <= step <= np.pi / 2:
            raise InvalidInputError(f'step must be a C step in rad, 0.01 to pi/2, not {step!r}')
        if not isinstance(both_ways, bool):
            raise InvalidInputError(f'both_ways must be true or false, not {both_ways!r}')
        capture = self._capture_frame if self.get_parameter('frames').value else self._capture
        self._frame = None
        stamps = []
        self.temperatures.start()

        def record(run, image, phase):
            self.temperatures.record(run)
            stamps.append(self._record(run, image, phase))
        with RecordedRun(self, 'five_axis_sweep', {
                OBSERVATIONS_TOPIC: 'alignment_msgs/msg/FiveAxisObservation',
                TEMPERATURE_TOPIC: TEMPERATURE_TYPE, FRAME_TOPIC: IMAGE_TYPE}) as run:
            images = measure_sweep(
                rotary_sweep(tilts, float(step), both_ways), self._move, capture,
                lambda image, phase: record(run, image, phase), self._progress, self.workspace)
            self.temperatures.record(run)
        covariates, sentence = self.temperatures.covariates(stamps)
        self.get_logger().info(f'sweep: {len(images)} images; temperature: {sentence}')
        # Weighed against the calibration the poses come through, where its covariance is
        # known (a calibration file from before it was kept has none).
        variants = (None if self.covariance is None else
                    pose_variants(self.model, self.covariance, images, covariates))
        return RotaryLoopModel(poses_from_images(self.model, images, covariates),
                               variants=variants)

    def _with_calibration(self, request, response, what: str, known: tuple, work):
        """Run ``work(options)`` on the request's plan with the calibration in force, one
        job at a time; errors are logged and answered, the node keeps running."""
        if not self.calibration_service.busy.acquire(blocking=False):
            response.success, response.message = False, 'a calibration is running'
            return response
        try:
            if self.model is None:
                raise CalibrationError('no five-axis calibration in force: call '
                                       'five_axis_calibrator/calibrate first')
            options = parse_plan(request.plan_yaml)
            unknown = set(options) - set(known)
            if unknown:
                raise InvalidInputError(f'unknown plan keys {sorted(unknown)}; known: '
                                        f'{", ".join(known)}')
            work(options)
            response.success, response.message = True, 'ok'
        except (MachineAlignmentError, TypeError, ValueError) as exc:
            self.get_logger().error(f'{what} failed: {exc}')
            response.success, response.message = False, str(exc)
        finally:
            self.calibration_service.busy.release()
        return response

    @staticmethod
    def _views(options) -> list:
        views = np.asarray(options.get('views', FEATURE_VIEWS), dtype=float)
        if views.ndim != 2 or views.shape[1] != 2 or len(views) < 2:
            raise InvalidInputError('views must be at least two [a, c] pairs (rad)')
        return [tuple(v) for v in views]

    def on_locate(self, request, response):
        def work(options):
            angles = np.asarray(options.get('path_angles', [0.17, 0.8]), dtype=float)
            if angles.shape != (2,):
                raise InvalidInputError('path_angles must be one [a, c] pair (rad)')
            result = locate_workpiece(self.model, self.cad, self.path, self.tip,
                                      self._views(options), tuple(angles), self._move,
                                      self._capture_features, self.workspace)
            response.features = [float(v) for v in np.ravel(result['features_m'])]
            response.pose = [float(v) for v in result['pose']['translation_m']
                             + result['pose']['rotation_vector_rad']]
            response.path_poses = [float(v) for v in np.ravel(result['path_poses'])]
            response.report_json = json.dumps(result)
            self.get_logger().info(f'part located: CAD misfit {result["cad_misfit_rms_m"] * 1e6:.2f} '
                                   f'um RMS; {len(result["path_poses"])} path poses')
        return self._with_calibration(request, response, 'localisation',
                                      ('views', 'path_angles'), work)

    def on_measure_needle(self, request, response):
        def work(options):
            spots = np.asarray(options.get('spots', TEST_SPOTS), dtype=float)
            if spots.ndim != 2 or spots.shape[1] != 3 or not np.all(np.isfinite(spots)):
                raise InvalidInputError('spots must be [x, y, z] triples (m, board frame)')
            result = measure_needle(self.model, self.tip, spots, self._views(options),
                                    self._move, self._dispense, self._capture_dispensed,
                                    self.workspace)
            self.tip = np.array(result['tip_m'])
            path, version = write_calibration(self.get_parameter('output_dir').value, 'needle',
                                              {'tip_m': result['tip_m'], 'report': result})
            response.tip = [float(v) for v in self.tip]
            response.spread = result['spread_m']
            response.report_json = json.dumps(dict(result, file=str(path), version=version))
            self.get_logger().info(f'needle tip {np.round(self.tip * 1e3, 4).tolist()} mm '
                                   f'(spread {result["spread_m"] * 1e6:.1f} um); wrote {path}')
        return self._with_calibration(request, response, 'needle measurement',
                                      ('spots', 'views'), work)

def main(args=None):
    run_node(FiveAxisCalibratorNode, args, threads=4)


if __name__ == '__main__':
    main()
