"""grid_calibrator: the grid-plate self-calibration of an XY machine's measuring system on
the live graph (the printer's camera gantry here).

Service ``grid_calibrator/calibrate`` (RunCalibration) covers the travel region by region.
For each placement of each region it moves the camera to the region's centre and asks for
the plate on ``/grid_calibrator/placement`` (GridPlacement, latched): an operator (the
simulation, in the simulated graph) puts the plate's centre mark under the camera as
asked and confirms with ``grid_calibrator/confirm_placement`` (std_srvs/Trigger). It then
visits every mark (``gantry/move``, each approached from below), detects it
(``mark_detector/detect``) and records the reading: the gantry's encoder reading plus the
mark's offset from the image centre through the camera's pixel size and rotation (from
the vision calibration's result, latched on ``vision_result_topic``; the nominal
parameters otherwise, and the report says so). The regions are self-calibrated and
stitched; the stage error map is written as an atomic, versioned file, published latched on
``/grid_calibrator/result`` with progress on ``/grid_calibrator/progress``, and the run is
recorded to MCAP (``machine-align calibrate grid --bag`` solves it again offline; a run
stopped part way replays its complete regions). Each reading is stamped with its frame's
time; the machine's temperature, where a sensor publishes it on ``temperature_topic``
(sensor_msgs/Temperature, degrees Celsius), is recorded with the readings, and each
reading takes it at its stamp. Plan keys: ``half``, ``pitch``, ``columns``, ``rows``,
``first_centre``, ``approach``, ``certified_pitch``, ``stitch``. A plan that leaves the
travel is refused before anything moves.

Service ``grid_calibrator/analyze_residuals`` (AnalyzeResiduals) runs the grid's closed
loop (:func:`grid_calib.core.residual_loop.analyze_travel`) on the last run's regions:
report and figure in ``output_dir/analysis``, published latched on
``/grid_calibrator/analysis`` and recorded. The loop reads the run as the offline replay
reads its bag: every reading with its time in the run and, where logged, its temperature
(thermal expansion). Plan keys ``alpha`` and ``max_effects``; its held-out check is
leave-one-out, so ``holdout_fraction`` and ``seed`` are refused.
"""
import threading
import time

import numpy as np
from alignment_msgs.msg import (
    CalibrationResult, GantryState, GridMarkReading, GridPlacement, Progress)
from alignment_msgs.srv import AnalyzeResiduals, DetectMarks, MoveGantry, RunCalibration
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from calib_core.closed_loop import LoopConfig
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.frames import planar
from calib_core.image_plane import NOMINAL_PIXEL_SIZE, CameraToPlate
from calib_core.nodes.analysis import AnalysisService
from calib_core.nodes.calibrator import (
    READ_ONLY, CalibrationService, bounded, call_service, check_when_set, declare_paths,
    interval, positive, publish_calibration_in_force, set_described_parameters)
from calib_core.nodes.conversions import calibration_result_as_message
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.recording import RecordedRun
from calib_core.nodes.spin import run_node
from calib_core.nodes.status import CalibratorStatus
from calib_core.nodes.temperature import TemperatureLog
from calib_core.temperature import TEMPERATURE_TOPIC, TEMPERATURE_TYPE
from grid_calib.core.description import read_description as read_grid_description
from grid_calib.core.procedure import GridPlan, camera_in_stage_frame, measure_grid
from grid_calib.core.records import (
    PLACEMENT_TOPIC, READINGS_TOPIC, RESULT_TOPIC, regions_from_readings)
from grid_calib.core.residual_loop import analyze_travel
from grid_calib.core.stitching import METHODS
from grid_calib.core.travel import calibrate_travel, grid_result_content

PLAN_KEYS = ('half', 'pitch', 'columns', 'rows', 'first_centre', 'approach',
             'certified_pitch', 'stitch')
ANALYSIS_TOPIC = '/grid_calibrator/analysis'
# How long a run waits for the latched calibration of a vision calibrator it sees (s).
VISION_WAIT_S = 2.0
PLACEMENT_POLL_S = 0.5     # s: how often a wait for the operator looks for a cancel


def grid_loop(data, config: LoopConfig, progress=None):
    """AnalysisService's loop for the grid: ``data`` is (grid, regions)."""
    default = LoopConfig()
    if (config.holdout_fraction, config.seed) != (default.holdout_fraction, default.seed):
        raise InvalidInputError('the grid loop holds out each reading in turn (leave-one-out): '
                                'holdout_fraction and seed do not apply')
    grid, regions = data
    details = {}
    report = analyze_travel(grid, regions, alpha=config.alpha, max_effects=config.max_effects,
                            details=details)

    def draw(png):
        from grid_calib.core.loop_plot import plot_grid_loop   # matplotlib: only when drawn
        plot_grid_loop(png, report, details)
    return report, draw, None


def grid_result_message(content: dict, header, file_path='', version=0) -> CalibrationResult:
    """The CalibrationResult of a grid calibration file's content."""
    report = content['report']
    residuals = [v for r in report['regions'].values() for v in r['residual_rms_m'].values()]
    worst = [v for r in report['regions'].values() for v in r['residual_max_m'].values()]
    parameters = {'non_orthogonality': report['non_orthogonality_rad'],
                  'scale_difference': report['scale_difference']}
    units = {'non_orthogonality': 'rad', 'scale_difference': '1'}
    if report['isotropic_scale'] is not None:
        parameters['isotropic_scale'] = report['isotropic_scale']
        units['isotropic_scale'] = '1'
    # O and R here are those of the stitched map over the whole travel; their standard
    # deviations are not propagated (the per-site uncertainty of G is in the report).
    std = {name: float('nan') for name in parameters}
    return calibration_result_as_message(
        'grid', header, parameters, std, units, report, float(np.sqrt(np.mean(np.square(
            residuals)))), float(max(worst)), 'm', len(report['sites']), file_path, version)


# The defaults (as declared below) of the parameters a machine description sets: one
# changed beside a description is refused (test_grid_description holds them to the code's).
DESCRIBED_DEFAULTS = {'half': 4, 'pitch': 7.5e-3, 'columns': 3, 'rows': 2,
                      'certified_pitch': 0.0}


class GridCalibratorNode(Node):

    def __init__(self):
        super().__init__('grid_calibrator')
        declare_paths(self, 'output_dir', 'record_dir')
        self.declare_parameter('half', 4)
        self.declare_parameter('pitch', 7.5e-3)
        self.declare_parameter('columns', 3)
        self.declare_parameter('rows', 2)
        self.declare_parameter('first_centre', [5, 5])
        self.declare_parameter('approach', 1e-3)
        self.declare_parameter('certified_pitch', 0.0)     # 0: none, scale undetermined
        self.declare_parameter('stitch', 'joint')
        self.declare_parameter('x_range', [0.0, 0.200])
        self.declare_parameter('y_range', [0.0, 0.150])
        self.declare_parameter('pixel_size', NOMINAL_PIXEL_SIZE)
        self.declare_parameter('camera_angle', 0.0)
        self.declare_parameter('image_size', [640, 480])
        self.declare_parameter('vision_result_topic', '/vision_calibrator/result')
        self.declare_parameter('call_timeout_s', 10.0)
        self.declare_parameter('placement_timeout_s', 600.0)
        self.declare_parameter('temperature_topic', TEMPERATURE_TOPIC)  # '': no sensor
        self.declare_parameter('description', '', READ_ONLY)   # the user's plate and noise
        self.description = self._take_description()
        self._plan_from_parameters({})            # refuse a bad plan at start-up
        size = [int(v) for v in self.get_parameter('image_size').value]
        if len(size) != 2 or min(size) <= 0:
            raise ValueError('image_size must be two positive px counts')
        self.principal = ((size[0] - 1) / 2, (size[1] - 1) / 2)
        self.timeout = float(self.get_parameter('call_timeout_s').value)
        self.placement_timeout = float(self.get_parameter('placement_timeout_s').value)
        if not (self.timeout > 0 and self.placement_timeout > 0):
            raise ValueError('call_timeout_s and placement_timeout_s must be positive')
        self._vision = None                       # (pixel_size, angle) from the vision result
        self._vision_heard = threading.Event()    # a vision result arrived, in force or not
        self._placed = threading.Event()
        self._gantry_state, self._last_marks = GantryState(), None
        self._run_readings = []
        group = ReentrantCallbackGroup()
        self.move_client = self.create_client(MoveGantry, 'gantry/move', callback_group=group)
        self.detect_client = self.create_client(DetectMarks, 'mark_detector/detect',
                                                callback_group=group)
        self.status = CalibratorStatus(self, 'grid', None)
        self.result_pub = self.status.tap(
            self.create_publisher(CalibrationResult, RESULT_TOPIC, LATCHED))
        self.placement_pub = self.create_publisher(GridPlacement, PLACEMENT_TOPIC, LATCHED)
        self.reading_pub = self.create_publisher(GridMarkReading, READINGS_TOPIC, 10)
        self.progress_pub = self.status.tap(
            self.create_publisher(Progress, '/grid_calibrator/progress', 10), 'progress')
        self.create_subscription(CalibrationResult,
                                 self.get_parameter('vision_result_topic').value,
                                 self.on_vision_result, LATCHED, callback_group=group)
        self.temperatures = TemperatureLog(self, self.get_parameter('temperature_topic').value,
                                           group)
        self.calibration_service = CalibrationService(
            self, 'grid', self._run, self._header, busy=self.status.busy, status=self.status)
        self.create_service(RunCalibration, 'grid_calibrator/calibrate',
                            self.calibration_service, callback_group=group, qos_profile=SERVICES)
        self.create_service(Trigger, 'grid_calibrator/confirm_placement',
                            self.on_confirm_placement, callback_group=group, qos_profile=SERVICES)
        self._measured = None         # (grid, regions) of the last completed run
        self.create_service(AnalyzeResiduals, 'grid_calibrator/analyze_residuals',
                            AnalysisService(
                                self, 'grid', self.calibration_service.busy, self._last_run,
                                'the grid map has no place for the run\'s effects (a drift '
                                'during the run is not a property of the stage)',
                                ANALYSIS_TOPIC, self._header, loop=grid_loop,
                                status=self.status),
                            callback_group=group, qos_profile=SERVICES)
        publish_calibration_in_force(
            self, 'grid', self.result_pub,
            lambda content, path: grid_result_message(content, self._header(), path,
                                                      content.get('version', 0)))
        # A peer's `ros2 param set` meets the same checks as a request's plan.
        check_when_set(self, PLAN_KEYS, self._plan_from_parameters, {
            'x_range': interval('x_range'), 'y_range': interval('y_range'),
            'pixel_size': positive('pixel_size'), 'camera_angle': bounded('camera_angle', np.pi),
            # Any topic name: where the run looks for the vision calibration.
            'vision_result_topic': lambda topic: None})

    def _header(self):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id='machine')

    def _last_run(self, options: dict):
        if self._measured is None:
            raise CalibrationError('no grid calibration run to analyse yet: call '
                                   'grid_calibrator/calibrate first')
        return self._measured

    def _plan_from_parameters(self, overrides: dict) -> tuple[GridPlan, float | None, str]:
        unknown = set(overrides) - set(PLAN_KEYS)
        if unknown:
            raise InvalidInputError(f'unknown plan keys {sorted(unknown)}; known: '
                                    f'{list(PLAN_KEYS)}')
        g = lambda n: overrides.get(n, self.get_parameter(n).value)  # noqa: E731
        plan = GridPlan(half=g('half'), pitch=g('pitch'), columns=g('columns'),
                        rows=g('rows'), first_centre=tuple(g('first_centre')),
                        approach=g('approach'))
        plan.check(tuple(self.get_parameter('x_range').value),
                   tuple(self.get_parameter('y_range').value))
        certified = g('certified_pitch')
        if isinstance(certified, bool) or not isinstance(certified, (int, float)):
            raise InvalidInputError(f'certified_pitch must be a length in m (0: none), not '
                                    f'{certified!r}')
        stitch = g('stitch')
        if stitch not in METHODS:
            raise InvalidInputError(f'stitch must be one of {METHODS}, not {stitch!r}')
        return plan, (float(certified) or None), stitch

    def on_vision_result(self, msg):
        camera = camera_in_stage_frame(dict(zip(msg.names, msg.values))) if msg.success else None
        if camera is not None:
            self._vision = camera
        self._vision_heard.set()

    def on_confirm_placement(self, request, response):
        self._placed.set()
        response.success, response.message = True, 'placement confirmed'
        return response

    def _camera(self) -> tuple[CameraToPlate, str]:
        topic = self.get_parameter('vision_result_topic').value
        if self._vision is None and self.count_publishers(topic):
            # A vision calibrator is up, and the calibration it keeps in force may still be
            # on its way to a graph just started: run on the nominal camera only once it
            # has had time to arrive (the demo's grid run had measured every mark through
            # the nominal pixel size, 0.3 um off in its readings).
            self._vision_heard.wait(VISION_WAIT_S)
        if self._vision is not None:
            return (CameraToPlate(*self._vision, self.principal),
                    'pixel size and rotation from the vision calibration')
        self.get_logger().warning('no vision calibration received: the mark offsets use the '
                                  'nominal pixel size and camera angle parameters')
        return (CameraToPlate(float(self.get_parameter('pixel_size').value),
                              float(self.get_parameter('camera_angle').value), self.principal),
                'nominal pixel size and camera angle (no vision calibration received)')

    def _move(self, x, y) -> np.ndarray:
        self.status.check_cancelled()       # the safe point: before the next move
        reached = call_service(self.move_client, MoveGantry.Request(x=float(x), y=float(y)),
                               'gantry move', self.timeout)
        self._gantry_state = GantryState(header=self._header(), x=reached.x, y=reached.y)
        return np.array([reached.x, reached.y])

    def _locate(self, camera: CameraToPlate) -> np.ndarray:
        """The offset (m) of the detected mark nearest the image centre."""
        detected = call_service(self.detect_client, DetectMarks.Request(shape='circle'),
                                'detection', self.timeout)
        self._last_marks = detected.marks
        uv = np.array([[m.u, m.v] for m in detected.marks.marks], dtype=float).reshape(-1, 2)
        if not len(uv) or not np.all(np.isfinite(uv)):
            raise CalibrationError('no grid mark in view: is the plate placed as asked?')
        nearest = uv[np.argmin(np.linalg.norm(uv - np.asarray(self.principal), axis=1))]
        return camera.offset(nearest[None])[0]

    def _place(self, run: RecordedRun, plan: GridPlan, region, placement, centre) -> None:
        self._move(centre[0] - plan.approach, centre[1] - plan.approach)
        self._move(*centre)
        self._placed.clear()
        message = (f'put the plate {placement} over region {region}: centre mark under the '
                   f'camera at ({centre[0] * 1e3:.3f}, {centre[1] * 1e3:.3f}) mm, then call '
                   'grid_calibrator/confirm_placement')
        self.get_logger().info(message)
        run.record(PLACEMENT_TOPIC, GridPlacement(
            header=self._header(), region=int(region), placement=placement,
            centre_x=float(centre[0]), centre_y=float(centre[1]),
            marks_per_side=2 * plan.half + 1, pitch=plan.pitch), self.placement_pub)
        deadline = time.monotonic() + self.placement_timeout
        while not self._placed.wait(PLACEMENT_POLL_S):     # a cancel ends the wait too
            self.status.check_cancelled()
            if time.monotonic() > deadline:
                raise CalibrationError(f'no confirmation of the {placement} placement of '
                                       f'region {region} within {self.placement_timeout:.0f} s')

    def _record_reading(self, run, region, placement, mark, reading) -> None:
        self.temperatures.record(run)
        # Stamped when the frame showed the mark (the camera's stamp): the reading's time
        # and temperature are that moment's, not the end of its detection's.
        header = self._header()
        if self._last_marks.header.stamp.sec or self._last_marks.header.stamp.nanosec:
            header.stamp = self._last_marks.header.stamp
        msg = GridMarkReading(
            header=header, region=int(region), placement=placement, i=int(mark[0]),
            j=int(mark[1]), x=float(reading[0]), y=float(reading[1]),
            gantry=self._gantry_state, marks=self._last_marks)
        run.record(READINGS_TOPIC, msg, self.reading_pub)
        self._run_readings.append(msg)
        # What a viewer shows: the camera over the mark, at the stage's reading.
        run.record_frames([('stage', 'camera', *planar(reading[0], reading[1], 0.0))])

    def _keep_for_the_loop(self, grid) -> str:
        """Keeps the run for the closed loop as the offline replay reads its bag (each
        reading's time, and its temperature where the log covers the run); says where the
        temperature came from, or why there is none. A bad temperature log costs the loop
        its temperature, never the calibration."""
        log, sentence = self.temperatures.log()
        regions, notes = regions_from_readings(grid, self._run_readings, log)
        self._measured = (grid, regions)
        return '; '.join([sentence] + notes)

    def _progress(self, step, total, message):
        self.progress_pub.publish(Progress(header=self._header(), task='grid_calibration',
                                           step=step, total=total, message=message))
        self.get_logger().info(f'[{step}/{total}] {message}')

    def _take_description(self):
        """A machine description (parameter ``description``) sets the plate (``half``,
        ``pitch``, ``certified_pitch``) and the regions (``columns``, ``rows``), and its
        declared reading noise gates each run (docs/machine_description.md); one of those
        set beside it as well is refused, as two statements of one machine. The graph's
        readings are in m, so its unit is not used here."""
        described = self.get_parameter('description').value
        if not described:
            return None
        description = read_grid_description(described)
        values = {'half': description.grid.half, 'pitch': description.grid.pitch,
                  'columns': description.regions[0], 'rows': description.regions[1],
                  'certified_pitch': description.certified_pitch or 0.0}
        set_described_parameters(self, values, DESCRIBED_DEFAULTS)
        return description

    def _run(self, overrides: dict) -> CalibrationResult:
        plan, certified, stitch = self._plan_from_parameters(overrides)
        camera, camera_source = self._camera()
        self.temperatures.start()
        self._run_readings = []
        with RecordedRun(self, 'grid', {
                PLACEMENT_TOPIC: 'alignment_msgs/msg/GridPlacement',
                READINGS_TOPIC: 'alignment_msgs/msg/GridMarkReading',
                TEMPERATURE_TOPIC: TEMPERATURE_TYPE,
                RESULT_TOPIC: 'alignment_msgs/msg/CalibrationResult'}) as run:
            regions = measure_grid(
                plan, lambda r, p, centre: self._place(run, plan, r, p, centre), self._move,
                lambda: self._locate(camera), self._progress,
                lambda r, p, mark, reading: self._record_reading(run, r, p, mark, reading))
            self.temperatures.record(run)
            calibration = calibrate_travel(plan.grid, regions, stitch, certified,
                                           self.description)
            temperature = self._keep_for_the_loop(plan.grid)
            content = grid_result_content(calibration)
            if self.description:
                content['report']['description'] = self.description.gate_report()
            content['report']['camera'] = camera_source
            content['report']['temperature'] = temperature
            path, version, content = run.save('grid', content)
            result = grid_result_message(content, self._header(), str(path), version)
            run.record(RESULT_TOPIC, result, self.result_pub)
        stitched = calibration.stitched
        self._progress(1, 1, f'done: {len(stitched.sites)} sites, G RMS '
                             f'{np.sqrt(np.mean(stitched.stage_error ** 2)) * 1e6:.3f} um; '
                             f'wrote {path}')
        return result


def main(args=None):
    run_node(GridCalibratorNode, args, threads=4)


if __name__ == '__main__':
    main()
