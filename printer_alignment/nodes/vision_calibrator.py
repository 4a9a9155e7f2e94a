"""vision_calibrator: the paper's vision system calibration on the live graph.

Service ``vision_calibrator/calibrate`` (RunCalibration) drives the gantry over the dot
plate (``gantry/move``), detects dots at each stop (``mark_detector/detect``), identifies
the pixel size and image rotation, then the gantry model (leads Rx, Ry, axis angle,
non-orthogonality, offset). ``vision_calibrator/calibrate_pixel_size`` does the pixel size
alone from the current view. ``vision_calibrator/calibrate_intrinsics`` measures the lens
distortion (OpenCV) from an n x n grid of dot-plate views (plan keys ``centre``, ``step``,
``n``, ``focal_px``) and publishes it on ``vision_calibrator/intrinsics``: views square to
the plate cannot measure the focal length (parameter ``focal_px``, from the lens) nor the
principal point (the image centre), and the report says so. Each run is recorded to an
MCAP bag, written to an atomic, versioned calibration file, published latched on
``vision_calibrator/result``, with progress on ``vision_calibrator/progress``. One calibration at a time; a second request
while one runs is refused. A failed or interrupted run leaves the previous calibration
in force.

At start the node publishes the calibration in force (the current file in ``output_dir``)
on ``vision_calibrator/result``, so nodes that measure with the vision system (stage
calibrator, aligner) can work after the plate is removed and the graph restarted.

Service ``vision_calibrator/analyze_residuals`` (AnalyzeResiduals) measures ``points``
random positions over the travel in random order (so both directions of approach occur)
with the calibrated camera and gantry model, each with its frame's time and the machine's
temperature then (where a sensor publishes it on ``temperature_topic``), runs the closed
loop on the gantry (backlash, screw error, squareness, drift, thermal expansion, ...),
publishes the report latched on ``/vision_calibrator/analysis`` and, with ``apply``,
writes the calibration again with the added effects as a new version (not where they
describe the run rather than the machine: a drift in time or with temperature).
"""
import numpy as np
from alignment_msgs.msg import CalibrationResult, GantryState, Progress, VisionObservation
from alignment_msgs.srv import AnalyzeResiduals, DetectMarks, MoveGantry, RunCalibration
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Header

from calib_core.checks import MAX_POSITION_M, check_metres, positive_length, whole_number
from calib_core.datasets import directions_from_order
from calib_core.errors import CalibrationError, InvalidInputError, MachineAlignmentError
from calib_core.frames import planar
from calib_core.nodes.analysis import AnalysisService, write_extended_calibration
from calib_core.nodes.calibrator import (
    READ_ONLY, CalibrationService, call_service, check_when_set, declare_paths, positive,
    publish_calibration_in_force, set_described_parameters)
from calib_core.nodes.conversions import calibration_result_as_message, failed_result
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.recording import RecordedRun
from calib_core.nodes.spin import run_node
from calib_core.nodes.status import CalibratorStatus
from calib_core.nodes.temperature import TemperatureLog
from calib_core.temperature import TEMPERATURE_TOPIC, stamp_seconds
from printer_alignment.core.camera_calibration import distortion_from_dot_views
from printer_alignment.core.geometry import (
    NOMINAL_LEADS, NOMINAL_PIXEL_SIZE, CameraToPlate, GantryModel, calibrated_frames)
from printer_alignment.core.loop_models import GantryData, GantryLoopModel
from printer_alignment.core.records import (
    INTRINSICS_RESULT_TOPIC as INTRINSICS_TOPIC, VISION_OBSERVATIONS_TOPIC as OBSERVATIONS_TOPIC,
    VISION_RESULT_TOPIC as RESULT_TOPIC)
from printer_alignment.core.vision_calibration import (
    CAMERA_UNITS, calibrate_pixel_size, locate_camera)
from printer_alignment.core.vision_description import (
    read_description as read_vision_description)
from printer_alignment.core.vision_procedure import (
    MAX_PITCH_M, VisionCalibration, VisionPlan, observation_from_message,
    run_vision_calibration)
from printer_alignment.nodes.conversions import marks_from_message
ANALYSIS_TOPIC = '/vision_calibrator/analysis'
INTRINSICS_OPTIONS = ('centre', 'step', 'n', 'focal_px')
ANALYSIS_OPTIONS = ('points', 'measure_seed')


def vision_result_message(calibration: VisionCalibration, header, file_path='', version=0):
    return _result_message(calibration.camera2plate.pixel_size, calibration.camera2plate.angle,
                           calibration.report, header, file_path, version)


def _result_message(pixel_size, camera_angle, report, header, file_path, version):
    gantry = report['gantry']
    parameters = {'pixel_size': pixel_size, 'camera_angle': camera_angle,
                  **gantry['parameters']}
    std = {'pixel_size': report['pixel_size']['pixel_size_std_m'],
           'camera_angle': report['pixel_size']['angle_std_rad'], **gantry['std_devs']}
    units = {**CAMERA_UNITS, **gantry['units']}
    return calibration_result_as_message(
        'vision', header, parameters, std, units, report, gantry['residual_rms_m'],
        gantry['residual_max_m'], 'm', gantry['num_positions'], file_path, version)


# The defaults (as declared below) of the parameters a machine description sets: one
# changed beside a description is refused (test_node_parameters holds them to the code's).
DESCRIBED_DEFAULTS = {'nominal_pixel_size': NOMINAL_PIXEL_SIZE, 'nominal_leads': [0.016, 0.04],
                      'focal_px': 2000.0, 'image_size': [640, 480], 'pitch': 0.5e-3,
                      'x_range': [0.0, 0.2], 'y_range': [0.0, 0.15]}


class VisionCalibratorNode(Node):

    def __init__(self):
        super().__init__('vision_calibrator')
        declare_paths(self, 'output_dir', 'record_dir')
        self.declare_parameter('pitch', 0.5e-3)
        self.declare_parameter('nx', 5)
        self.declare_parameter('ny', 4)
        self.declare_parameter('x_range', [0.0, 0.200])
        self.declare_parameter('y_range', [0.0, 0.150])
        self.declare_parameter('nominal_pixel_size', NOMINAL_PIXEL_SIZE)
        # The screws' leads the drive converts motor angles with (m/rev, X and Y): the
        # gate holds the identified leads within 10 % of them.
        self.declare_parameter('nominal_leads', NOMINAL_LEADS.tolist())
        self.declare_parameter('call_timeout_s', 10.0)
        # The lens's focal length in px (datasheet focal length / pixel pitch): views square
        # to the plate cannot measure it, and the distortion coefficients scale with it.
        self.declare_parameter('focal_px', 2000.0)
        self.declare_parameter('image_size', [640, 480])
        self.declare_parameter('temperature_topic', TEMPERATURE_TOPIC)  # '': no sensor
        self.declare_parameter('description', '', READ_ONLY)   # the user's lens and screws
        self._take_description()
        focal = self.get_parameter('focal_px').value
        size = list(self.get_parameter('image_size').value)
        if not (focal > 0 and len(size) == 2 and all(int(v) > 0 for v in size)):
            raise ValueError('focal_px must be > 0 px and image_size two positive px counts')
        self.plan = self._plan_from_parameters({})
        self.timeout = float(self.get_parameter('call_timeout_s').value)
        self.nominal_camera = CameraToPlate(float(self.get_parameter('nominal_pixel_size').value))
        leads = np.asarray(self.get_parameter('nominal_leads').value, dtype=float)
        if leads.shape != (2,) or not np.all(np.isfinite(leads)) or not np.all(leads > 0):
            raise ValueError('nominal_leads must be the X and Y screws\' leads, two positive '
                             'values in m/rev')
        self.nominal_leads = leads
        self.nominal_gantry = GantryModel(lead_x=float(leads[0]), lead_y=float(leads[1]))
        self._gantry_state = GantryState()
        group = ReentrantCallbackGroup()
        self.temperatures = TemperatureLog(self, self.get_parameter('temperature_topic').value,
                                           group)
        self.move_client = self.create_client(MoveGantry, 'gantry/move', callback_group=group)
        self.detect_client = self.create_client(DetectMarks, 'mark_detector/detect',
                                                callback_group=group)
        self.status = CalibratorStatus(self, 'vision', calibrated_frames)
        self.result_pub = self.status.tap(
            self.create_publisher(CalibrationResult, RESULT_TOPIC, LATCHED))
        self.progress_pub = self.status.tap(
            self.create_publisher(Progress, '/vision_calibrator/progress', 10), 'progress')
        self.observation_pub = self.create_publisher(VisionObservation, OBSERVATIONS_TOPIC, 10)
        self.calibration_service = CalibrationService(
            self, 'vision', lambda overrides: self._run(self._plan_from_parameters(overrides)),
            self._header, busy=self.status.busy, status=self.status)
        self.create_service(RunCalibration, 'vision_calibrator/calibrate',
                            self.calibration_service, callback_group=group, qos_profile=SERVICES)
        self.create_service(RunCalibration, 'vision_calibrator/calibrate_pixel_size',
                            self.on_pixel_size, callback_group=group, qos_profile=SERVICES)
        self.intrinsics_pub = self.create_publisher(CalibrationResult, INTRINSICS_TOPIC, LATCHED)
        self.create_service(RunCalibration, 'vision_calibrator/calibrate_intrinsics',
                            CalibrationService(self, 'intrinsics', self._run_intrinsics,
                                               self._header, self.calibration_service.busy,
                                               status=self.status),
                            callback_group=group, qos_profile=SERVICES)
        self._calibration = None   # (VisionCalibration, file content) of the last run
        self._publish_calibration_in_force()
        self.create_service(AnalyzeResiduals, 'vision_calibrator/analyze_residuals',
                            AnalysisService(self, 'vision', self.calibration_service.busy,
                                            self._measure_for_analysis, self._apply_extended,
                                            ANALYSIS_TOPIC, self._header,
                                            options=ANALYSIS_OPTIONS, status=self.status),
                            callback_group=group, qos_profile=SERVICES)
        # A peer's `ros2 param set` meets the same checks as a request's plan.
        check_when_set(self, ('pitch', 'nx', 'ny', 'x_range', 'y_range'),
                       self._plan_from_parameters,
                       {'focal_px': positive('focal_px'), 'image_size': positive('image_size', 2)})

    def _publish_calibration_in_force(self):
        def as_message(content, path):
            camera = content['camera2plate']
            return _result_message(camera['pixel_size'], camera['angle'], content['report'],
                                   self._header(), path, content.get('version', 0))
        publish_calibration_in_force(self, 'vision', self.result_pub, as_message)

    def _take_description(self) -> None:
        """A machine description (parameter ``description``) sets the lens, screws, camera,
        dot plate and travel parameters (docs/machine_description.md); one of those set
        beside it as well is refused, as two statements of one machine."""
        described = self.get_parameter('description').value
        if not described:
            return
        set_described_parameters(self, read_vision_description(described).node_parameters(),
                                 DESCRIBED_DEFAULTS)

    def _plan_from_parameters(self, overrides: dict) -> VisionPlan:
        g = lambda n: overrides.get(n, self.get_parameter(n).value)  # noqa: E731
        unknown = set(overrides) - {'pitch', 'nx', 'ny', 'x_range', 'y_range'}
        if unknown:
            raise InvalidInputError(f'unknown plan keys {sorted(unknown)}')
        # VisionPlan checks every value (integers, positive lengths) before anything moves.
        return VisionPlan(x_range=tuple(g('x_range')), y_range=tuple(g('y_range')),
                          nx=g('nx'), ny=g('ny'), pitch=g('pitch'))

    def _header(self):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id='plate')

    def _call(self, client, request, what):
        if client is self.move_client:
            self.status.check_cancelled()       # the safe point: before the next move
        return call_service(client, request, what, self.timeout)

    def _detect_dots(self):
        """The detector's answer for the next image and its dot centres (px, (n, 2))."""
        detected = self._call(self.detect_client, DetectMarks.Request(shape='circle'),
                              'detection')
        return detected, np.array([[m.u, m.v] for m in marks_from_message(detected.marks)])

    def _observe_and_record(self, run: RecordedRun) -> np.ndarray:
        """Detect dots at the current stop, publish and record the observation; return the
        dot centres (px, (n, 2)) for the core calibration loop."""
        detected, _ = self._detect_dots()
        msg = VisionObservation(header=self._header(), gantry=self._gantry_state,
                                marks=detected.marks)
        run.record(OBSERVATIONS_TOPIC, msg, self.observation_pub)
        # What a viewer shows: the camera where the gantry's encoders put it.
        run.record_frames([('gantry', 'carriage', *planar(msg.gantry.x, msg.gantry.y, 0.0))])
        return observation_from_message(msg).uv

    def _move(self, x, y):
        reached = self._call(self.move_client, MoveGantry.Request(x=float(x), y=float(y)),
                             'gantry move')
        # The drive reports axis positions as motor angle times the nominal lead.
        revs = np.array([reached.x, reached.y]) / self.nominal_leads
        self._gantry_state = GantryState(header=self._header(), x=reached.x, y=reached.y,
                                         x_rev=float(revs[0]), y_rev=float(revs[1]))
        return revs

    def _progress(self, step, total, message):
        self.progress_pub.publish(Progress(header=self._header(), task='vision_calibration',
                                           step=step, total=total, message=message))
        self.get_logger().info(f'[{step}/{total}] {message}')

    def _run(self, plan: VisionPlan) -> CalibrationResult:
        total = len(plan.targets()) + 1  # the stops, then the fit
        with RecordedRun(self, 'vision', {
                OBSERVATIONS_TOPIC: 'alignment_msgs/msg/VisionObservation',
                RESULT_TOPIC: 'alignment_msgs/msg/CalibrationResult'}) as run:
            _, calibration = run_vision_calibration(
                plan, self._move, lambda: self._observe_and_record(run),
                lambda step, _, message: self._progress(step, total, message),
                nominal_camera=self.nominal_camera, nominal_gantry=self.nominal_gantry)
            path, version, content = run.save('vision', {
                'camera2plate': {'pixel_size': calibration.camera2plate.pixel_size,
                                 'angle': calibration.camera2plate.angle,
                                 'principal': list(calibration.camera2plate.principal)},
                'gantry2plate': calibration.gantry.as_dict(),
                'report': calibration.report})
            result = vision_result_message(calibration, self._header(), str(path), version)
            run.record(RESULT_TOPIC, result, self.result_pub)
        self._calibration = (calibration, content)
        self._progress(total, total,
                       f'done: pixel size {calibration.camera2plate.pixel_size * 1e6:.4f} um, '
                       f'Rx {calibration.gantry.lead_x * 1e3:.4f} mm/rev, '
                       f'Ry {calibration.gantry.lead_y * 1e3:.4f} mm/rev; wrote {path}')
        return result

    def _run_intrinsics(self, options: dict) -> CalibrationResult:
        """Lens distortion (OpenCV) from an n x n grid of dot-plate views ``step`` (m)
        apart around ``centre`` (gantry command, m); the focal length is given
        (``focal_px``) and the principal point is the image centre, because views square to
        the plate determine neither."""
        unknown = set(options) - set(INTRINSICS_OPTIONS)
        if unknown:
            raise InvalidInputError(f'unknown plan keys {sorted(unknown)}; known: '
                                    f'{list(INTRINSICS_OPTIONS)}')
        # Every option is checked before the first move.
        centre = np.asarray(options.get('centre', [0.1, 0.075]), dtype=float)
        if centre.shape != (2,) or not np.all(np.isfinite(centre)):
            raise InvalidInputError(f'centre must be (x, y) in m, not {options.get("centre")!r}')
        check_metres(centre, 'centre', 'the plan', MAX_POSITION_M)
        step = positive_length(options.get('step', 1.3e-3), 'step', 0.05)
        n = whole_number(options.get('n', 3), 'n', 2)
        focal = options.get('focal_px', self.get_parameter('focal_px').value)
        if isinstance(focal, bool) or not isinstance(focal, (int, float)) \
                or not np.isfinite(focal) or focal <= 0:
            raise InvalidInputError(f'focal_px must be a positive number of px, not {focal!r}')
        focal = float(focal)
        pitch = positive_length(self.get_parameter('pitch').value, 'pitch', MAX_PITCH_M)
        setup = {'pitch_m': pitch, 'pitch_px': pitch / self.nominal_camera.pixel_size,
                 'focal_px': focal,
                 'image_size': [int(v) for v in self.get_parameter('image_size').value]}
        offsets = (np.arange(n) - (n - 1) / 2) * step
        targets = [centre + [dx, dy] for dy in offsets for dx in offsets]
        dots = []
        with RecordedRun(self, 'intrinsics', {
                OBSERVATIONS_TOPIC: 'alignment_msgs/msg/VisionObservation',
                INTRINSICS_TOPIC: 'alignment_msgs/msg/CalibrationResult'}) as run:
            for k, (x, y) in enumerate(targets):
                self._move(x, y)
                dots.append(self._observe_and_record(run))
                self._progress(k + 1, len(targets) + 1, f'view {k + 1}/{len(targets)}: '
                               f'{len(dots[-1])} dots')
            report = distortion_from_dot_views(dots, setup).report()
            report['setup'] = setup
            path, version, _ = run.save('intrinsics', {'report': report})
            result = calibration_result_as_message(
                'intrinsics', self._header(), report['parameters'], report['std_devs'],
                report['units'], report, report['rms_reprojection_px'],
                max(report['per_view_rms_px']), 'px', len(dots), str(path), version)
            run.record(INTRINSICS_TOPIC, result, self.intrinsics_pub)
        p = report['parameters']
        self._progress(len(targets) + 1, len(targets) + 1,
                       f'done: k1 {p["k1"]:.4g}, k2 {p["k2"]:.4g}, p1 {p["p1"]:.3g}, '
                       f'p2 {p["p2"]:.3g} (focal {focal:g} px), reprojection RMS '
                       f'{report["rms_reprojection_px"]:.4f} px; wrote {path}')
        return result

    def _measure_for_analysis(self, options: dict) -> GantryLoopModel:
        """Visit random positions over the travel with the calibrated vision system and
        return the gantry data for the closed loop."""
        if self._calibration is None:
            raise CalibrationError('no vision calibration to analyse yet: call '
                                   'vision_calibrator/calibrate first')
        points = options.get('points', 60)
        if isinstance(points, bool) or not isinstance(points, int) or points < 10:
            raise InvalidInputError(f'points must be an integer >= 10, not {points!r}')
        calibration = self._calibration[0]
        plan = self.plan
        rng = np.random.default_rng(int(options.get('measure_seed', 0)))
        low = np.array([plan.x_range[0], plan.y_range[0]]) + plan.margin
        high = np.array([plan.x_range[1], plan.y_range[1]]) - plan.margin
        targets = rng.uniform(low, high, (points, 2))
        start = np.array([self._gantry_state.x, self._gantry_state.y])
        command, measured, stamps = [], [], []
        self.temperatures.start()
        for k, (x, y) in enumerate(targets):
            revs = self._move(x, y)
            predicted = calibration.gantry.camera_position(revs)[0]
            position, stamp = self._locate(calibration, predicted)
            measured.append(position)
            stamps.append(stamp)
            command.append([self._gantry_state.x, self._gantry_state.y])
            self.temperatures.record()
            self._progress(k + 1, points, f'analysis: position {k + 1}/{points}')
        command = np.array(command)
        directions = directions_from_order(np.vstack([start, command]))[1:]
        covariates, sentence = self.temperatures.covariates(stamps)
        self.get_logger().info(f'analysis: temperature: {sentence}')
        return GantryLoopModel(GantryData(command, np.array(measured), directions,
                                          covariates))

    def _locate(self, calibration, predicted, attempts: int = 3) -> tuple[np.ndarray, float]:
        """Camera position (m) measured at the current stop, and its frame's stamp (s). An
        image far from where the calibrated model puts the camera (a quarter pitch) is
        taken again: it was exposed before the gantry arrived."""
        pitch = self.plan.pitch
        for _ in range(attempts):
            detected, uv = self._detect_dots()
            position = locate_camera(uv, calibration.camera2plate, pitch, predicted)
            miss = float(np.linalg.norm(position - predicted))
            if miss < 0.25 * pitch:
                return position, stamp_seconds(detected.marks)
            self.get_logger().warning(f'camera position {miss * 1e6:.0f} um from the '
                                      'calibrated model\'s; taking another image')
        raise CalibrationError(f'{attempts} images in a row disagree with the calibrated model '
                               f'by more than {0.25 * pitch * 1e6:.0f} um: is the calibration '
                               'stale or the plate moved?')

    def _apply_extended(self, result) -> str:
        return write_extended_calibration(self.get_parameter('output_dir').value, 'vision',
                                          self._calibration[1], result, 'gantry_loop_model')

    def on_pixel_size(self, request, response):
        if not self.calibration_service.busy.acquire(blocking=False):
            response.success, response.message = False, 'a calibration is already running'
            return response
        try:
            _, uv = self._detect_dots()
            result = calibrate_pixel_size([uv], self.plan.pitch, self.nominal_camera)
            report = result.report()
            response.result = calibration_result_as_message(
                'pixel_size', self._header(),
                {'pixel_size': report['pixel_size_m'], 'camera_angle': report['angle_rad']},
                {'pixel_size': report['pixel_size_std_m'], 'camera_angle': report['angle_std_rad']},
                {'pixel_size': 'm/px', 'camera_angle': 'rad'}, report,
                report['residual_rms_px'], report['residual_max_px'], 'px', report['num_marks'])
            response.success, response.message = True, 'ok'
        except MachineAlignmentError as exc:
            self.get_logger().error(f'pixel size calibration failed: {exc}')
            response.success, response.message = False, str(exc)
            response.result = failed_result('pixel_size', self._header(), str(exc))
        finally:
            self.calibration_service.busy.release()
        return response


def main(args=None):
    run_node(VisionCalibratorNode, args, threads=4)


if __name__ == '__main__':
    main()
