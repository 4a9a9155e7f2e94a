"""`make demo`: calibrate the simulated machines end to end.

Printer vision system:
1. Start gantry_sim, camera_sim, mark_detector and vision_calibrator as separate processes
   (own ROS_DOMAIN_ID, localhost discovery) and trigger ``vision_calibrator/calibrate``,
   then the closed loop (``vision_calibrator/analyze_residuals``, applied).
2. Re-run the calibration offline from the bag the node recorded: same result.
3. Evaluate against the simulation's truth over the whole travel: camera-measured dot
   positions before (nominal model) and after calibration, as JSON and PNG.
XY-Theta stage (the dot plate removed, the vision calibration in force):
4. Start the stage graph, trigger ``stage_calibrator/calibrate`` (stepwise and
   parametric), align a substrate fixed 0.3 mm off with the nominal, stepwise and
   parametric models (stage sent home before each), then the closed loop on the run.
Hexapod:
5. Start hexapod_sim, pose_sensor_sim and hexapod_calibrator and trigger
   ``hexapod_calibrator/calibrate`` (plans poses, drives, measures, identifies, iterates,
   evaluates on separate poses), then the closed loop on its stops
   (``hexapod_calibrator/analyze_residuals``, applied).
6. Re-run the identification offline from its bag, and compare the 42 identified
   parameters with the simulation's truth.
The three machines after them:
7. Grid plate: the printer's camera gantry self-calibrated with an imperfect 5 x 5 mark
   grid plate over 2 regions (``grid_calibrator/calibrate``; the simulated operator places
   the plate as asked).
8. Platform: ``platform_calibrator/calibrate`` (20 poses by the laser tracker), then
   ``platform_calibrator/register`` (exact compensation, marks measured after the move).
9. Five-axis dispenser: ``five_axis_calibrator/calibrate`` on rendered camera frames,
   ``measure_needle`` from dispensed dots, ``locate`` a part and place its path.
Last, one summary table (machine, before, after, the paper's figure, the simulated
instruments' noise, the figure file), printed and written as ``summary.md`` and
``summary.json``.

The simulated instruments run at the noise the sources report (:data:`INSTRUMENTS`), so
the demo's numbers compare with the papers'; ``low_noise`` runs them ten times quieter,
and the table says so.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import matplotlib
import numpy as np
from alignment_msgs.srv import (
    Align, AnalyzeResiduals, LocateWorkpiece, MeasureNeedle, MoveStage, RegisterScreen,
    RunCalibration)

from calib_core.bags import decode_bag
from calib_core.errors import CalibrationError
from calib_core.figures import RUN_VARIABLE, arrow_key, save_figure
from calib_core.storage import read_calibration, write_atomic
from dispenser_calib.core.calibration import reprojection
from dispenser_calib.core.model import NAMES, DispenserModel, nominal_model
from dispenser_calib.core.records import OBSERVATIONS_TOPIC as FIVE_AXIS_OBSERVATIONS
from dispenser_calib.core.records import image_from_message
from dispenser_calib.sim.machine import IMAGE_SIZE as FIVE_AXIS_IMAGE
from hexapod_calib.sim.hexapod import HexapodTruth
from machine_alignment.cli import calibrate
from machine_alignment.launcher import (
    Graph, five_axis_graph, grid_graph, hexapod_graph, platform_graph, printer_graph, stage_graph)
from machine_alignment.live import LiveClient
from platform_calib.core.compensation import composite_error
from platform_calib.core.records import MEASUREMENTS_TOPIC as PLATFORM_MEASUREMENTS
from platform_calib.core.records import stop_from_message
from printer_alignment.core.geometry import CameraToPlate, GantryModel
from printer_alignment.sim.camera import CameraSim
from printer_alignment.sim.evaluation import measure_errors, plot_errors, summarise
from printer_alignment.sim.gantry import GantryErrors, GantrySim
from printer_alignment.sim.scenes import make_scene

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)


@dataclass(frozen=True)
class Instrument:
    """One simulated instrument's noise in the demo: the sim node and its parameter, the
    value the source reports (SI, 1 sigma per axis), and how the summary names it."""

    module: str
    parameter: str
    source: float
    label: str
    unit: str
    per_si: float       # display units per SI unit
    note: str = ''      # where the source's figure comes from


_GANTRY = Instrument('printer_alignment.nodes.gantry_sim', 'landing_sigma', 12.5e-6 / 50,
                     'gantry landing', 'um', 1e6, 'the source: 1/50 px at 12.5 um')
# The sources' figures: the printer paper's Mark-centre accuracy and stage repeatability
# (3.3 um unidirectional), the hexapod paper's CMM (0.6 um), the five-axis paper's dot-centre
# noise (0.1 px, giving its 0.17 px reprojection); the platform paper gives none, so the
# tracker has the rebuilt simulation's 10 um (SEEDS_CDE.md, platform, PROPOSED).
INSTRUMENTS = {
    'printer': (_GANTRY,),
    'stage': (_GANTRY, Instrument('printer_alignment.nodes.stage_sim', 'landing_sigma', 1.2e-6,
                                  'stage landing per chain', 'um', 1e6,
                                  'the source: 3.3 um repeatability')),
    'hexapod': (Instrument('hexapod_calib.nodes.pose_sensor_sim', 'position_noise', 0.6e-6,
                           'pose sensor', 'um', 1e6, "the source's CMM: 0.6 um"),
                Instrument('hexapod_calib.nodes.pose_sensor_sim', 'angle_noise', 6e-6,
                           'pose sensor angles', 'urad', 1e6)),
    'grid': (_GANTRY,),
    'platform': (Instrument('platform_calib.nodes.laser_tracker_sim', 'position_noise', 10e-6,
                            'laser tracker', 'um', 1e6,
                            'no figure in the source: the rebuilt simulation\'s'),
                 Instrument('platform_calib.nodes.laser_tracker_sim', 'angle_noise', 20e-6,
                            'tracker angles', 'urad', 1e6)),
    'five_axis': (Instrument('dispenser_calib.nodes.five_axis_sim', 'noise_px', 0.1,
                             'dot centres', 'px', 1.0, 'the source: 0.1 px'),),
}
LOW_NOISE_FACTOR = 0.1      # a low-noise run's instruments against the sources'


@dataclass
class DemoRun:
    """The demo's folder and ROS domain, its numbered steps and its summary rows."""

    out: Path
    domain: str
    low_noise: bool = False
    total_steps: int = 9
    steps_done: int = 0
    rows: list = field(default_factory=list)

    def step(self, text: str) -> None:
        self.steps_done += 1
        print(f'[{self.steps_done}/{self.total_steps}] {text}', flush=True)

    def noisy(self, machine: str, spec: list) -> list:
        """``spec`` (a graph) with ``machine``'s instruments at the demo's noise."""
        values = {(i.module, i.parameter): self._noise(i) for i in INSTRUMENTS[machine]}
        return [replace(node, parameters={
            **node.parameters, **{p: v for (m, p), v in values.items() if m == node.module}})
            for node in spec]

    def _noise(self, instrument: Instrument) -> float:
        return instrument.source * (LOW_NOISE_FACTOR if self.low_noise else 1.0)

    def noise_text(self, machine: str) -> str:
        """What the summary says of ``machine``'s simulated instruments."""
        text = '; '.join(f'{i.label} {self._noise(i) * i.per_si:.3g} {i.unit}'
                         + (f' ({i.note})' if i.note else '') for i in INSTRUMENTS[machine])
        return text + (f' (low-noise run: {LOW_NOISE_FACTOR:g} x the sources\')'
                       if self.low_noise else '')

    def row(self, machine: str, before: str, after: str, paper: str, figure: str,
            noise: str) -> None:
        """One line of the closing summary; ``figure`` relative to the demo folder."""
        self.rows.append({'machine': machine, 'before': before, 'after': after,
                          'paper': paper, 'noise (1 sigma, simulated)': noise,
                          'figure': figure})

    def summary(self) -> str:
        header = ['machine', 'before', 'after', 'paper', 'noise (1 sigma, simulated)',
                  'figure']
        lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
        lines += ['| ' + ' | '.join(row[k] or '-' for k in header) + ' |' for row in self.rows]
        return '\n'.join(lines) + '\n'


def _calibrate_offline(argv: list[str]) -> int:
    """``machine-align calibrate ...`` in this process (the demo replays its own bags)."""
    parser = argparse.ArgumentParser(prog='machine-align')
    calibrate.add_parser(parser.add_subparsers(dest='command', required=True))
    args = parser.parse_args(['calibrate', *argv])
    return args.func(args)


def _run_service(graph, service: str, progress_topic: str, timeout: float = 600.0,
                 analysis: str = '', plan: str = ''):
    """Call a RunCalibration service on a running graph, printing its progress; then, if
    the calibration succeeded and ``analysis`` names an AnalyzeResiduals service, run the
    closed loop with ``apply``. Returns (calibration response, analysis response), None
    for a call that got no answer."""
    shown = {'step': -1}

    def show(step, total, message):
        if step == total or step - shown['step'] >= max(total // 10, 1):
            shown['step'] = step
            print(f'      {step}/{total} {message}')
    with LiveClient('demo_client') as client:
        try:
            calibration = client.call(RunCalibration, service,
                                      RunCalibration.Request(plan_yaml=plan), progress_topic,
                                      show, timeout)
        except CalibrationError as exc:
            print(f'      {exc}; processes alive: {graph.alive()}')
            return None, None
        if not (analysis and calibration.success):
            return calibration, None
        print(f'      closed loop: {analysis} (apply)')
        try:
            return calibration, client.call(AnalyzeResiduals, analysis,
                                            AnalyzeResiduals.Request(apply=True), timeout=timeout)
        except CalibrationError as exc:
            print(f'      {exc}')
            return calibration, None


def _loop_figure(response, out: Path) -> str:
    """The closed loop's figure (beside its report), relative to the demo folder; '' if
    the loop did not run."""
    if response is None or not response.success:
        return ''
    figure = Path(response.analysis.report_path).with_suffix('.png')
    return str(figure.relative_to(out)) if figure.is_file() else ''


def _print_analysis(response) -> None:
    if response is None or not response.success:
        print(f'      closed loop failed: {response.message if response else "timeout"}')
        return
    a = response.analysis
    print(f'      closed loop added {", ".join(a.effects_added) or "nothing"}; held-out RMS '
          f'{a.rms_before * 1e6:.2f} -> {a.rms_after * 1e6:.2f} um, max {a.max_before * 1e6:.2f} '
          f'-> {a.max_after * 1e6:.2f} um; report {a.report_path}')


def _printer(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step(f'starting the simulated printer (ROS_DOMAIN_ID={domain}); logs in {out}/logs/<phase>')
    graph_spec = run.noisy('printer', printer_graph(output_dir=str(out / 'calibration'),
                                                   record_dir=str(out / 'runs')))
    start = time.monotonic()
    with Graph(graph_spec, env={'ROS_DOMAIN_ID': domain},
               log_dir=str(out / 'logs' / 'printer')) as graph:
        response, analysis = _run_service(graph, 'vision_calibrator/calibrate',
                                          '/vision_calibrator/progress', timeout=300.0,
                                          analysis='vision_calibrator/analyze_residuals')
    if response is None or not response.success:
        print(f'calibration failed: {response.message if response else "timeout"}')
        return 1
    result = response.result
    print(f'      done in {time.monotonic() - start:.1f} s; calibration file {result.file_path} '
          f'(version {result.version})')
    _print_analysis(analysis)

    run.step('re-running the calibration offline from the recorded bag')
    bag = next(b for b in (out / 'runs').glob('vision_*') if 'analysis' not in b.name)
    _calibrate_offline(['vision', '--bag', str(bag), '--json', str(out / 'replay.json')])

    run.step('evaluating against the simulation truth over the whole travel')
    values = dict(zip(result.names, result.values))
    camera2plate = CameraToPlate(values['pixel_size'], values['camera_angle'])
    gantry_model = GantryModel(**{k: values[k] for k in GantryModel().as_dict()})
    rng = np.random.default_rng(1)
    targets = np.column_stack([rng.uniform(0.001, 0.199, 60), rng.uniform(0.001, 0.149, 60)])
    gantry, camera = GantrySim(), CameraSim(make_scene('dot_plate'), seed=2)
    after = measure_errors(camera2plate, gantry_model, gantry, camera, targets, 0.5e-3)
    nominal = GantryModel()
    before = measure_errors(CameraToPlate(), nominal, gantry, camera, targets, 0.5e-3)
    before -= before[0]  # homing: the nominal system is zeroed on its first point
    report = {'parameters': values, 'std_devs': dict(zip(result.names, result.std_devs)),
              'units': dict(zip(result.names, result.units)),
              'before': summarise(before), 'after': summarise(after),
              'note': 'camera-measured dot positions against truth at 60 random gantry '
                      'targets approached from random directions; after calibration the '
                      'remaining error is the unmodelled backlash and screw periodic error'}
    write_atomic(out / 'vision_evaluation.json', json.dumps(report, indent=2) + '\n')
    plot_errors(out / 'vision_evaluation.png', targets, before, after,
                'Vision system: camera-measured position error over the gantry travel')
    print(f'      before: max {report["before"]["max_um"]:.1f} um, RMS {report["before"]["rms_um"]:.1f} um')
    print(f'      after:  max {report["after"]["max_um"]:.2f} um, RMS {report["after"]["rms_um"]:.2f} um')
    print(f'      wrote {out}/vision_evaluation.json and .png')
    loop = (f'; closed loop, held-out RMS {analysis.analysis.rms_after * 1e6:.2f} um'
            if analysis is not None and analysis.success else '')
    run.row('printer vision system (60 held-out positions, camera against truth)',
            f'max {report["before"]["max_um"]:.1f} um, RMS {report["before"]["rms_um"]:.1f} um',
            f'max {report["after"]["max_um"]:.2f} um, RMS {report["after"]["rms_um"]:.2f} um'
            + loop, '', ', '.join(filter(None, ['vision_evaluation.png',
                                                  _loop_figure(analysis, out)])),
            run.noise_text('printer'))
    return 0


def _hexapod(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('starting the simulated hexapod cell and calibrating it')
    spec = run.noisy('hexapod', hexapod_graph(output_dir=str(out / 'calibration'),
                                              record_dir=str(out / 'runs')))
    start = time.monotonic()
    with Graph(spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs' / 'hexapod')) as graph:
        response, analysis = _run_service(graph, 'hexapod_calibrator/calibrate',
                                          '/hexapod_calibrator/progress',
                                          analysis='hexapod_calibrator/analyze_residuals')
    if response is None or not response.success:
        print(f'hexapod calibration failed: {response.message if response else "timeout"}')
        return 1
    result = response.result
    report = json.loads(result.report_json)
    before, after = report['evaluation']['before'], report['evaluation']['after']
    print(f'      done in {time.monotonic() - start:.1f} s; geometry file {result.file_path} '
          f'(version {result.version})')
    print(f'      {before["num_poses"]} separate poses, before: max {before["max_displacement_m"] * 1e6:.1f} um '
          f'/ {before["max_angle_rad"] * 1e6:.0f} urad; after: max {after["max_displacement_m"] * 1e6:.2f} um '
          f'/ {after["max_angle_rad"] * 1e6:.1f} urad (paper: 12.1 um / 1100 urad)')
    _print_analysis(analysis)

    run.step('re-running the identification offline from the bag; 42 parameters against truth')
    bag = next(b for b in (out / 'runs').glob('hexapod_*') if 'analysis' not in b.name)
    _calibrate_offline(['hexapod', '--bag', str(bag), '--out', str(out / 'hexapod_replay.yaml'),
                        '--json', str(out / 'hexapod_replay.json')])
    truth = HexapodTruth.default().geometry.parameters().as_dict()
    identified = report['identification']
    z = {n: (identified['parameters'][n] - v) / identified['std_devs'][n] for n, v in truth.items()}
    inside = float(np.mean([abs(v) < 3 for v in z.values()]))
    evaluation = {'evaluation': report['evaluation'], 'iterations': report['iterations'],
                  'parameters': [{'name': n, 'true_m': truth[n],
                                  'estimate_m': identified['parameters'][n],
                                  'std_dev_m': identified['std_devs'][n], 'z': z[n]} for n in truth],
                  'inside_3_sigma': inside}
    write_atomic(out / 'hexapod_evaluation.json', json.dumps(evaluation, indent=2) + '\n')
    print(f'      {inside * 100:.0f} % of the 42 true parameters inside 3 sigma; '
          f'wrote {out}/hexapod_evaluation.json')
    run.row(f'hexapod ({before["num_poses"]} held-out poses, sensor-measured)',
            f'max {before["max_displacement_m"] * 1e6:.0f} um / '
            f'{before["max_angle_rad"] * 1e6:.0f} urad',
            f'max {after["max_displacement_m"] * 1e6:.1f} um / '
            f'{after["max_angle_rad"] * 1e6:.0f} urad; {inside * 100:.0f} % of the 42 '
            'parameters within 3 sigma of truth', '12.1 um / 1100 urad',
            _loop_figure(analysis, out), run.noise_text('hexapod'))
    return 0


def run_demo(out: Path, low_noise: bool = False) -> int:
    out = out.resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    run = DemoRun(out, str(100 + os.getpid() % 100), low_noise)
    # The run every figure it draws names (nodes inherit it); `make figures` names its own.
    os.environ.setdefault(RUN_VARIABLE, time.strftime('make demo %Y-%m-%dT%H:%M:%SZ',
                                                      time.gmtime()))
    print(f'run: {os.environ[RUN_VARIABLE]}', flush=True)
    os.environ['ROS_DOMAIN_ID'] = run.domain
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    started = time.monotonic()
    for machine in (_printer, _stage, _hexapod, _grid, _platform, _five_axis):
        if machine(run):
            return 1
    table = run.summary()
    write_atomic(out / 'summary.md', table)
    write_atomic(out / 'summary.json', json.dumps(run.rows, indent=2) + '\n')
    print(f'\nSummary ({time.monotonic() - started:.0f} s; figures and files in {out}):\n')
    print(table)
    return 0


def _calibrated(graph, name: str, service: str, plan: str = ''):
    """Call RunCalibration ``service`` on the running ``graph``: its report, or None after
    printing why it failed."""
    start = time.monotonic()
    response, _ = _run_service(graph, service, f'/{service.split("/")[0]}/progress', plan=plan)
    if response is None or not response.success:
        print(f'      {name} calibration failed: {response.message if response else "timeout"}')
        return None
    print(f'      done in {time.monotonic() - start:.1f} s; file {response.result.file_path}')
    return json.loads(response.result.report_json)


def _graph(name: str, spec, out: Path, domain: str) -> Graph:
    return Graph(spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs' / name))


def _grid(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('grid-plate self-calibration of the camera gantry (a 5 x 5 mark plate over 2 '
          'regions, the simulated operator places it)')
    spec = run.noisy('grid', grid_graph(str(out / 'calibration'), str(out / 'runs'), half=2,
                                        columns=2, rows=1))
    with _graph('grid', spec, out, domain) as graph:
        report = _calibrated(graph, 'grid', 'grid_calibrator/calibrate')
    if report is None:
        return 1
    errors = np.array([[s['error_x'], s['error_y']] for s in report['sites']])
    # G's symmetric shear O is half the Y axis's turn from square (the turn of the whole
    # is each placement's): the gantry model's non-orthogonality is twice it.
    square = 2 * report['non_orthogonality_rad']
    print(f'      {len(errors)} sites in {report["stitching"]["regions"]} regions stitched '
          f'({report["stitching"]["method"]}); stage error up to '
          f'{np.abs(errors).max() * 1e6:.2f} um; non-orthogonality (twice the map\'s shear) = '
          f'{square * 1e6:.1f} urad (the simulated gantry: '
          f'{GantryErrors().model.non_orthogonality * 1e6:.1f} urad)')
    sites = np.array([[s['x'], s['y']] for s in report['sites']])
    _plot_grid_map(out / 'grid_map.png', sites, errors)
    print(f'      wrote {out}/grid_map.png')
    run.row(f'grid plate ({len(errors)} sites, {report["stitching"]["regions"]} regions)',
            f'stage error up to {np.abs(errors).max() * 1e6:.2f} um at the sites',
            f'mapped; non-orthogonality {square * 1e6:.1f} urad (simulated '
            f'{GantryErrors().model.non_orthogonality * 1e6:.1f} urad)', '', 'grid_map.png',
            run.noise_text('grid'))
    return 0


def _platform(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('the screen-registration platform: identification by the laser tracker, then '
          'registration of a screen')
    spec = run.noisy('platform', platform_graph(str(out / 'calibration'), str(out / 'runs')))
    with _graph('platform', spec, out, domain) as graph:
        report = _calibrated(graph, 'platform', 'platform_calibrator/calibrate', '{poses: 20}')
        if report is None:
            return 1
        evaluation = report['evaluation']
        print(f'      held-out poses, median error: nominal '
              f'{evaluation["evaluate_nominal"]["median_m"] * 1e6:.1f} um, calibrated '
              f'{evaluation["evaluate_calibrated"]["median_m"] * 1e6:.1f} um')
        with LiveClient('demo_platform_client') as client:
            answer = client.call(RegisterScreen, 'platform_calibrator/register',
                                 RegisterScreen.Request(method='exact'), timeout=120.0)
    if not answer.success:
        print(f'      registration failed: {answer.message}')
        return 1
    before = json.loads(answer.report_json)['error_before_m']
    print(f'      registered (exact compensation): marks off by {before * 1e3:.3f} mm before, '
          f'{answer.measured_error * 1e6:.2f} um after the move')
    _plot_platform_evaluation(out / 'platform_evaluation.png', out / 'runs')
    print(f'      wrote {out}/platform_evaluation.png')
    run.row(f'screen-registration platform ({evaluation["evaluate_calibrated"]["poses"]} '
            'held-out poses, tracker-measured; one registration)',
            f'median {evaluation["evaluate_nominal"]["median_m"] * 1e6:.1f} um (nominal model); '
            f'screen placed {before * 1e3:.2f} mm off',
            f'median {evaluation["evaluate_calibrated"]["median_m"] * 1e6:.1f} um; marks '
            f'{answer.measured_error * 1e6:.1f} um off after the move',
            '0.21-1.96 mm -> about 0.10 mm', 'platform_evaluation.png',
            run.noise_text('platform'))
    return 0


def _plot_grid_map(path: Path, sites: np.ndarray, errors: np.ndarray) -> None:
    """The stage error map the grid calibration found: an arrow per site, scale bar in um."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    arrows = ax.quiver(sites[:, 0] * 1e3, sites[:, 1] * 1e3, errors[:, 0] * 1e6,
                       errors[:, 1] * 1e6, angles='xy', color='tab:blue')
    arrow_key(ax, arrows, float(np.abs(errors).max() * 1e6 / 2), 'um')
    ax.set_xlabel('x (mm)')
    ax.set_ylabel('y (mm)')
    ax.set_aspect('equal')
    ax.margins(0.1, 0.3)                   # room for the arrows at the edges
    ax.set_title('stage error map from the grid plate (self-calibrated, 2 regions)', fontsize=10)
    fig.subplots_adjust(bottom=0.24)       # the arrow key sits below the axes
    save_figure(fig, path, [__file__])
    plt.close(fig)


def _plot_platform_evaluation(path: Path, runs: Path) -> None:
    """Each held-out pose's composite mark error, measured by the tracker, with the nominal
    and the calibrated commands (from the run's bag), on one scale."""
    bag = next(b for b in sorted(runs.glob('platform_*')) if 'analysis' not in b.name)
    stops = [stop_from_message(msg) for topic, _, msg in decode_bag(bag)
             if topic == PLATFORM_MEASUREMENTS]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for phase, colour, label in (('evaluate_nominal', 'tab:red', 'nominal geometry'),
                                 ('evaluate_calibrated', 'tab:blue', 'identified geometry')):
        rows = [s for s in stops if s.phase == phase]
        errors = composite_error(np.array([s.measured for s in rows]),
                                 np.array([s.target for s in rows])) * 1e6
        ax.semilogy(np.arange(1, len(errors) + 1), errors, 'o', color=colour,
                    label=f'{label}: median {np.median(errors):.1f} um')
    ax.set_xlabel('held-out pose')
    ax.set_ylabel("composite mark error |AA'| + |BB'| (um, log)")
    ax.set_title('platform: held-out poses measured by the laser tracker', fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which='both')
    fig.tight_layout()
    save_figure(fig, path, [__file__])
    plt.close(fig)


def _five_axis(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('the five-axis dispenser: calibration from rendered camera frames, the needle '
          'measured from dispensed dots, a part located and its path placed')
    spec = run.noisy('five_axis', five_axis_graph(str(out / 'calibration'), str(out / 'runs')))
    with _graph('five_axis', spec, out, domain) as graph:
        report = _calibrated(graph, 'five-axis', 'five_axis_calibrator/calibrate',
                             '{frames: true}')
        if report is None:
            return 1
        held = report['held_out']
        print(f'      reprojection {report["mean_reprojection_px"]:.4f} px mean; held out '
              f'{held["rms_px_calibrated"]:.4f} px RMS calibrated, {held["rms_px_nominal"]:.1f} px '
              f'nominal; set aside {sorted(report["bad_images"]) or "none"}')
        with LiveClient('demo_five_axis_client') as client:
            needle = client.call(MeasureNeedle, 'five_axis_calibrator/measure_needle',
                                 MeasureNeedle.Request(), timeout=120.0)
            if not needle.success:
                print(f'      needle measurement failed: {needle.message}')
                return 1
            part = client.call(LocateWorkpiece, 'five_axis_calibrator/locate',
                               LocateWorkpiece.Request(), timeout=120.0)
    if not part.success:
        print(f'      localisation failed: {part.message}')
        return 1
    print(f'      needle tip {", ".join(f"{v * 1e3:.4f}" for v in needle.tip)} mm (camera frame; '
          f'one dot alone within {needle.spread * 1e6:.1f} um)')
    print(f'      part found at {", ".join(f"{v * 1e3:.4f}" for v in part.pose[:3])} mm, '
          f'{part.pose[5] * 1e3:.3f} mrad (placed at 1.5, -1, 0 mm, 30 mrad); '
          f'{len(part.path_poses) // 5} path poses')
    figure = out / 'five_axis_evaluation.png'
    _plot_five_axis_evaluation(figure, read_calibration(out / 'calibration', 'five_axis'))
    print(f'      wrote {figure}')
    run.row(f'five-axis dispenser ({report["held_out"]["images"]} held-out images)',
            f'{report["held_out"]["rms_px_nominal"]:.1f} px RMS (nominal model)',
            f'{report["held_out"]["rms_px_calibrated"]:.4f} px RMS', '0.17 px',
            figure.name, run.noise_text('five_axis'))
    return 0


def _plot_five_axis_evaluation(path: Path, calibration: dict) -> None:
    """The held-out images of the run (A and C both turned, not calibrated on): each
    image's RMS reprojection with the nominal and the calibrated model on one log scale,
    and the calibrated model's residual vectors over the image with a key."""
    stops = [stop for _, _, msg in decode_bag(calibration['bag'], [FIVE_AXIS_OBSERVATIONS])
             for stop in [image_from_message(msg)] if stop[1] == 'evaluate']
    images = [image for image, _ in stops]
    calibrated = DispenserModel(np.array([calibration['parameters'][n] for n in NAMES]))
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.6))
    for model, colour, label in ((nominal_model(), 'tab:red', 'nominal model'),
                                 (calibrated, 'tab:blue', 'calibrated')):
        per_image = [float(np.sqrt(np.mean(e ** 2))) for e in reprojection(model, images)]
        left.semilogy(np.arange(1, len(images) + 1), per_image, 'o', color=colour,
                      label=f'{label}: median {np.median(per_image):.3g} px')
    left.set_xlabel('held-out image (A and C both turned)')
    left.set_ylabel('RMS reprojection (px, log)')
    left.legend(fontsize=8)
    left.grid(alpha=0.3, which='both')
    uv = np.concatenate([im.pixels for im in images])
    r = np.concatenate(reprojection(calibrated, images))
    longest = max(float(np.linalg.norm(r, axis=1).max()), 1e-9)
    arrows = right.quiver(uv[:, 0], uv[:, 1], r[:, 0], r[:, 1], angles='xy',
                          scale_units='xy', scale=longest / 60.0, width=0.002)
    arrow_key(right, arrows, longest / 2, 'px')
    right.set_xlim(0, FIVE_AXIS_IMAGE[0])
    right.set_ylim(FIVE_AXIS_IMAGE[1], 0)
    right.set_aspect('equal')
    right.set_xlabel('u (px)')
    right.set_ylabel('v (px)')
    right.set_title(f'calibrated residuals, held-out dots (longest {longest:.3g} px)',
                    fontsize=10)
    fig.suptitle('five-axis dispenser: held-out images, nominal against calibrated', fontsize=11)
    fig.tight_layout(rect=(0, 0.08, 1, 1))      # room for the arrow key below the axes
    save_figure(fig, path, [__file__])
    plt.close(fig)


def _stage(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('the XY-Theta stage: self-calibration with the camera, then alignment')
    spec = run.noisy('stage', stage_graph(
        output_dir=str(out / 'calibration'), record_dir=str(out / 'runs'),
        substrate_shift=(0.25e-3, -0.15e-3, float(np.deg2rad(0.04)))))
    start = time.monotonic()
    with Graph(spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs' / 'stage')) as graph:
        response, analysis = _run_service(graph, 'stage_calibrator/calibrate',
                                          '/stage_calibrator/progress', timeout=900.0,
                                          analysis='stage_calibrator/analyze_residuals')
        if response is None or not response.success:
            print(f'stage calibration failed: {response.message if response else "timeout"}')
            return 1
        report = json.loads(response.result.report_json)
        s = report['stepwise']
        print(f'      done in {time.monotonic() - start:.1f} s; file {response.result.file_path}; '
              f'R1..R3 {s["R1"] * 1e3:.4f}, {s["R2"] * 1e3:.4f}, {s["R3"] * 1e3:.4f} mm/rev, '
              f'alpha1 {np.rad2deg(s["alpha1"]):.4f} deg (true 2.0064, 2.0027, 2.0021, 89.8670)')
        _print_analysis(analysis)
        results = {}
        with LiveClient('demo_aligner_client') as client:
            for model in ('nominal', 'stepwise', 'parametric'):
                try:
                    client.call(MoveStage, 'stage/move', MoveStage.Request(q=[0.0, 0.0, 0.0]),
                                timeout=30.0)
                    answer = client.call(Align, 'aligner/align', Align.Request(model=model),
                                         timeout=120.0)
                except CalibrationError as exc:
                    print(f'      alignment ({model}) failed: {exc}')
                    return 1
                if not answer.success:
                    print(f'      alignment ({model}) failed: {answer.message}')
                    return 1
                results[model] = json.loads(answer.report_json)
                print(f'      aligned with the {model:>10} model: {answer.position_error * 1e6:6.2f} um, '
                      f'{np.rad2deg(answer.orientation_error) * 3600:5.2f} arcsec left (camera)')
    write_atomic(out / 'stage_alignment.json', json.dumps(results, indent=2) + '\n')
    print(f'      wrote {out}/stage_alignment.json')
    left = {model: results[model]['verification']['position_error_m'] * 1e6
            for model in results}
    run.row('XY-Theta stage (one alignment of a substrate 0.3 mm off, camera-measured)',
            f'{left["nominal"]:.2f} um left (nominal model)',
            f'{left["parametric"]:.2f} um (parametric), {left["stepwise"]:.2f} um (stepwise)',
            'max 12.3 um', _loop_figure(analysis, out), run.noise_text('stage'))
    return 0
