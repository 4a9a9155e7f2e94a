"""stage_calibrator: self-calibration of the XY-Theta stage with the machine's own camera.

Service ``stage_calibrator/calibrate`` (RunCalibration) moves the stage through the plan
(``stage/move``: X, Y and attitude sweeps up and down, then a workspace grid; every chain
lands afresh at each stop with a 30 um last motion in its direction of travel), measures
the two calibration Marks on the platform at every stop with the calibrated vision system
(gantry, two-way camera, detector), then runs the paper's stepwise calibration and the
parametric identification on the same measurements. The run is recorded to an MCAP bag
(``stage_calibrator/observations`` and the result), the models are written to an atomic,
versioned calibration file ``stage`` and published latched on
``/stage_calibrator/result`` (``report_json`` carries both models, so the aligner needs no
shared file system). Progress on ``/stage_calibrator/progress``. One run at a time; a
failed or interrupted run leaves the previous calibration in force.

Plan keys (``plan_yaml``): ``sweep_points``, ``grid``, ``span`` (today's run), ``design``
(``grid``; ``I`` or ``D``: the sweeps and ``stops`` stops chosen by
:mod:`printer_alignment.core.stage_planning`, planned here), ``targets`` (a planned run,
[[q1, q2, q3], ...] m, home first, as ``machine-align plan stage`` writes it); a planned
run's prediction is in the report (``plan_prediction``); ``target_error`` (m, the Marks'
RMS error predicted at the working inputs) with ``max_stops`` and ``step`` adds stops in
rounds after the run until it is met or cannot be (``adaptive`` in the report).

``description``: a stage description YAML (:mod:`printer_alignment.core.stage_description`):
the stage as drawn is the described one, mounted where ``calibration_marks`` were taught
(the Marks searched for there, the stepwise calibration started from its guides), plans
and targets stay inside its stroke and are predicted with its noise, and the gate refuses
a Mark residual above what its camera and chains give (the figure, the declared number
and the likely causes in the refusal; ``description`` in the report). A recorded run
replays with ``machine-align calibrate stage --bag B --description D``.

Service ``stage_calibrator/analyze_residuals`` (AnalyzeResiduals) runs the closed loop on
the last run's measurements with the error model without backlash as the base model, each
stop with its time and, where a sensor publishes it on ``temperature_topic``, the
machine's temperature (recorded in the run's bag), as the offline replay reads them.
"""
import numpy as np
from alignment_msgs.msg import CalibrationResult, Progress, StageObservation
from alignment_msgs.srv import AnalyzeResiduals, MoveStage, RunCalibration
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Header

from calib_core.checks import whole_number
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.frames import planar
from calib_core.nodes.analysis import AnalysisService, write_extended_calibration
from calib_core.nodes.calibrator import (
    CalibrationService, call_service, check_when_set, declare_paths, publish_calibration_in_force)
from calib_core.nodes.conversions import calibration_result_as_message
from calib_core.nodes.qos import LATCHED, SERVICES
from calib_core.nodes.recording import RecordedRun
from calib_core.nodes.spin import run_node
from calib_core.nodes.status import CalibratorStatus
from calib_core.nodes.temperature import TemperatureLog
from calib_core.planning import Adaptive
from calib_core.temperature import TEMPERATURE_TOPIC, TEMPERATURE_TYPE
from printer_alignment.core.loop_models import StageLoopModel
from printer_alignment.core.records import (
    STAGE_OBSERVATIONS_TOPIC as OBSERVATIONS_TOPIC, STAGE_RESULT_TOPIC as RESULT_TOPIC,
    stage_data_from_messages)
from printer_alignment.core.stage import NOMINAL_STAGE, STROKE
from printer_alignment.core.stage_description import likely_causes, read_description
from printer_alignment.core.stage_calibration import (
    StagePlan, check_stage_calibration, models_as_dict, models_from_dict)
from printer_alignment.core.stage_planning import (
    plan_stage, platform_marks, predict_stage_plan)
from printer_alignment.core.stage_procedure import run_stage_calibration
from printer_alignment.nodes.mark_locator import MarkLocator

ANALYSIS_TOPIC = '/stage_calibrator/analysis'
PLAN_KEYS = ('sweep_points', 'grid', 'span', 'design', 'stops', 'targets', 'target_error',
             'max_stops', 'step')
DESIGNS = ('grid', 'I', 'D')


class StageCalibratorNode(Node):

    def __init__(self):
        super().__init__('stage_calibrator')
        declare_paths(self, 'output_dir', 'record_dir')
        self.declare_parameter('sweep_points', StagePlan.sweep_points)
        self.declare_parameter('grid', list(StagePlan.grid))
        self.declare_parameter('span', StagePlan.span)
        self.declare_parameter('design', 'grid')   # grid; I or D: the sweeps and `stops` planned
        self.declare_parameter('stops', 40)        # chosen stops of a planned run
        # Where the two calibration Marks are (plate frame, m) with the stage at home, as
        # taught by jogging the camera over them once.
        self.declare_parameter('calibration_marks', [0.0351, 0.0791, 0.1551, 0.0797])
        self.declare_parameter('call_timeout_s', 10.0)
        self.declare_parameter('temperature_topic', TEMPERATURE_TOPIC)  # '': no sensor
        self.declare_parameter('description', '')   # '': the shipped stage
        marks = [float(v) for v in self.get_parameter('calibration_marks').value]
        if len(marks) != 4 or not np.all(np.isfinite(marks)):
            raise ValueError('calibration_marks must be x1, y1, x2, y2 (m)')
        self.home_marks = np.reshape(marks, (2, 2))
        path = self.get_parameter('description').value
        self.described = read_description(path) if path else None
        # The stage as drawn (mounted where the Marks were taught), its stroke and noise.
        self.nominal = (self.described.nominal(self.home_marks) if self.described
                        else NOMINAL_STAGE)
        self.stroke = self.described.stroke if self.described else STROKE
        self.noise = self.described.noise() if self.described else {}
        self._plan(dict())    # validates the parameters at start
        self.timeout = float(self.get_parameter('call_timeout_s').value)
        group = ReentrantCallbackGroup()
        self.temperatures = TemperatureLog(self, self.get_parameter('temperature_topic').value,
                                           group)
        self._observations = []              # the run's StageObservation messages
        self.locator = MarkLocator(self, group, self.timeout)
        self.move_client = self.create_client(MoveStage, 'stage/move', callback_group=group)
        self.status = CalibratorStatus(self, 'stage', None)
        self.result_pub = self.status.tap(
            self.create_publisher(CalibrationResult, RESULT_TOPIC, LATCHED))
        self.progress_pub = self.status.tap(
            self.create_publisher(Progress, '/stage_calibrator/progress', 10), 'progress')
        self.observation_pub = self.create_publisher(StageObservation, OBSERVATIONS_TOPIC, 10)
        self.calibration_service = CalibrationService(
            self, 'stage', lambda overrides: self._run(*self._plan(overrides)), self._header,
            busy=self.status.busy, status=self.status)
        self.create_service(RunCalibration, 'stage_calibrator/calibrate',
                            self.calibration_service, callback_group=group, qos_profile=SERVICES)
        self._data = self._content = None    # StageData and file content of the last run
        publish_calibration_in_force(
            self, 'stage', self.result_pub,
            lambda content, path: stage_result_message(
                content['report'], models_from_dict(content['models']), self._header(), path,
                content.get('version', 0)))
        self.create_service(AnalyzeResiduals, 'stage_calibrator/analyze_residuals',
                            AnalysisService(self, 'stage', self.calibration_service.busy,
                                            self._loop_model, self._apply_extended,
                                            ANALYSIS_TOPIC, self._header, status=self.status),
                            callback_group=group, qos_profile=SERVICES)
        # A peer's `ros2 param set` meets the same checks as a request's plan.
        check_when_set(self, PLAN_KEYS, self._plan)

    def _plan(self, overrides: dict) -> tuple[StagePlan, dict | None, Adaptive | None]:
        """The run to measure, for a planned one what it is predicted to give, and the
        adaptive rounds that follow it if a ``target_error`` is given."""
        unknown = set(overrides) - set(PLAN_KEYS)
        if unknown:
            raise InvalidInputError(f'unknown plan keys {sorted(unknown)}; known: {list(PLAN_KEYS)}')
        adaptive = None
        if 'target_error' in overrides:
            adaptive = Adaptive(overrides['target_error'],
                                whole_number(overrides.get('max_stops', 100), 'max_stops', 1),
                                whole_number(overrides.get('step', 8), 'step', 1), 'stops',
                                ' (the landing and camera noise decide it)')
        elif {'max_stops', 'step'} & set(overrides):
            raise InvalidInputError('max_stops and step belong to the adaptive mode: give a '
                                    'target_error (m) too')
        return (*self._run_plan(overrides), adaptive)

    def _run_plan(self, overrides: dict) -> tuple[StagePlan, dict | None]:
        """Today's sweeps and grid, a run planned here, or the planned ``targets``."""
        g = lambda n: overrides.get(n, self.get_parameter(n).value)  # noqa: E731
        design = g('design')
        if design not in DESIGNS:
            raise InvalidInputError(f'design must be one of {", ".join(DESIGNS)}, not {design!r}')
        marks = (self.described.marks if self.described
                 else platform_marks(self.home_marks, self.nominal))
        if 'targets' in overrides:
            # Checks shape, home first, stroke.
            plan = StagePlan(stops=overrides['targets'], stroke=self.stroke)
            return plan, predict_stage_plan(self.nominal, marks, plan.targets(),
                                            stroke=self.stroke, **self.noise).report()
        if design != 'grid':
            planned = plan_stage(self.nominal, marks, whole_number(g('stops'), 'stops', 1),
                                 int(g('sweep_points')), criterion=design, stroke=self.stroke,
                                 **self.noise)
            return StagePlan(stops=planned.targets, stroke=self.stroke), planned.report()
        return StagePlan(sweep_points=int(g('sweep_points')),
                         grid=tuple(int(v) for v in g('grid')), span=float(g('span')),
                         stroke=self.stroke), None

    def _header(self):
        return Header(stamp=self.get_clock().now().to_msg(), frame_id='plate')

    def _progress(self, step, total, message):
        self.progress_pub.publish(Progress(header=self._header(), task='stage_calibration',
                                           step=step, total=total, message=message))
        self.get_logger().info(f'[{step}/{total}] {message}')

    def _move(self, q):
        """Command the chain inputs (m); the inputs reached and the chains' last directions."""
        self.status.check_cancelled()       # the safe point: before the next move
        reached = call_service(self.move_client, MoveStage.Request(q=[float(v) for v in q]),
                               'stage move', self.timeout)
        return np.array(reached.q), np.array(reached.direction)

    def _record_stop(self, run: RecordedRun, q, direction, marks) -> None:
        self.temperatures.record(run)
        observation = StageObservation(header=self._header(), q=list(q),
                                       direction=[int(v) for v in direction],
                                       marks_x=marks[:, 0].tolist(), marks_y=marks[:, 1].tolist())
        run.record(OBSERVATIONS_TOPIC, observation, self.observation_pub)
        self._observations.append(observation)
        # What a viewer shows: each calibration Mark where the camera measured it.
        run.record_frames([('plate', f'mark{k + 1}', *planar(x, y, 0.0))
                           for k, (x, y) in enumerate(marks)])

    def _run(self, plan: StagePlan, prediction: dict | None,
             adaptive: Adaptive | None) -> CalibrationResult:
        self.locator.vision   # fails early without a vision calibration
        self.temperatures.start()
        self._observations = []
        with RecordedRun(self, 'stage', {
                OBSERVATIONS_TOPIC: 'alignment_msgs/msg/StageObservation',
                TEMPERATURE_TOPIC: TEMPERATURE_TYPE,
                RESULT_TOPIC: 'alignment_msgs/msg/CalibrationResult'}) as run:
            self.locator.select_view('substrate')
            data, models, report = run_stage_calibration(
                plan, self.home_marks, self._move,
                lambda expected: self.locator.measure(expected, 'circle'), self._progress,
                lambda *stop: self._record_stop(run, *stop), adaptive, self.nominal,
                **self.noise)
            if self.described is None:
                check_stage_calibration(report)   # else nothing is put in force
            else:
                report['description'] = self.described.gate_report()
                check_stage_calibration(report, self.described,
                                        likely_causes(data, self.described))
            if prediction is not None:
                report['plan_prediction'] = prediction
            # Which vision calibration measured the Marks, for whoever reads this one.
            path, version, content = run.save('stage', {
                'models': models_as_dict(models), 'report': report,
                'vision_calibration': dict(self.locator.source)})
            result = stage_result_message(report, models, self._header(), str(path), version)
            run.record(RESULT_TOPIC, result, self.result_pub)
            self.temperatures.record(run)
        self._data, self._content = self._loop_data(), content
        r = report['stepwise']
        total = len(data) + 1
        self._progress(total, total, f'done: R1..R3 {r["R1"] * 1e3:.4f}, {r["R2"] * 1e3:.4f}, '
                       f'{r["R3"] * 1e3:.4f} mm/rev, alpha1 {np.rad2deg(r["alpha1"]):.4f} deg; '
                       f'wrote {path}')
        return result

    def _loop_data(self):
        """The run for the closed loop as the offline replay reads its bag: every stop
        with its time and, where the log covers it, the machine's temperature."""
        log, sentence = self.temperatures.log()
        data, why = stage_data_from_messages(self._observations, log)
        self.get_logger().info(f'closed loop data: {len(data)} stops; temperature: '
                               f'{why or sentence}')
        return data

    def _loop_model(self, options: dict):
        if self._data is None:
            raise CalibrationError('no stage calibration run to analyse yet: call '
                                   'stage_calibrator/calibrate first')
        return StageLoopModel(self._data, self.nominal.d)

    def _apply_extended(self, result) -> str:
        return write_extended_calibration(self.get_parameter('output_dir').value, 'stage',
                                          self._content, result)


def stage_result_message(report: dict, models: dict, header, file_path='', version=0):
    """CalibrationResult of a stage calibration: the parametric model's free parameters
    with their sigmas, the stepwise values as ``stepwise_*``; both models in the JSON."""
    parametric = report['parametric']
    names = [n for n in parametric['parameters'] if n not in parametric['fixed']]
    values = {n: parametric['parameters'][n] for n in names}
    units = {n: parametric['units'][n] for n in names}
    stepwise = report['stepwise']
    for key in ('R1', 'R2', 'R3', 'alpha1', 'd3_minus_d2'):
        values[f'stepwise_{key}'] = stepwise[key]
        units[f'stepwise_{key}'] = stepwise['units'][key]
    full = dict(report, models=models_as_dict(models))
    return calibration_result_as_message(
        'stage', header, values, parametric['std_devs'], units, full,
        parametric['residual_rms_m'], parametric['residual_max_m'], 'm', report['num_poses'],
        file_path, version)


def main(args=None):
    run_node(StageCalibratorNode, args, threads=4)


if __name__ == '__main__':
    main()
