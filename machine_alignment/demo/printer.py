"""The demo's printer steps: the vision system (calibrate, replay, evaluate against truth)
and the XY-Theta stage (calibrate, the closed loop, three alignments)."""
from __future__ import annotations

import json
import time

import numpy as np
from alignment_msgs.srv import Align, MoveStage

from calib_core.errors import CalibrationError
from calib_core.storage import write_atomic
from machine_alignment.demo.common import (
    DemoRun, calibrate_offline, loop_figure, print_analysis, run_service)
from machine_alignment.launcher import Graph, printer_graph, stage_graph
from machine_alignment.live import LiveClient
from printer_alignment.core.geometry import CameraToPlate, GantryModel
from printer_alignment.sim.camera import CameraSim
from printer_alignment.sim.evaluation import measure_errors, plot_errors, summarise
from printer_alignment.sim.gantry import GantrySim
from printer_alignment.sim.scenes import make_scene


def printer(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step(f'starting the simulated printer (ROS_DOMAIN_ID={domain}); logs in {out}/logs/<phase>')
    graph_spec = run.noisy('printer', printer_graph(output_dir=str(out / 'calibration'),
                                                   record_dir=str(out / 'runs')))
    start = time.monotonic()
    with Graph(graph_spec, env={'ROS_DOMAIN_ID': domain},
               log_dir=str(out / 'logs' / 'printer')) as graph:
        response, analysis = run_service(graph, 'vision_calibrator/calibrate',
                                         '/vision_calibrator/progress', timeout=300.0,
                                         analysis='vision_calibrator/analyze_residuals')
    if response is None or not response.success:
        print(f'calibration failed: {response.message if response else "timeout"}')
        return 1
    result = response.result
    print(f'      done in {time.monotonic() - start:.1f} s; calibration file {result.file_path} '
          f'(version {result.version})')
    print_analysis(analysis)

    run.step('re-running the calibration offline from the recorded bag')
    bag = next(b for b in (out / 'runs').glob('vision_*') if 'analysis' not in b.name)
    calibrate_offline(['vision', '--bag', str(bag), '--json', str(out / 'replay.json')])

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
                                                  loop_figure(analysis, out)])),
            run.noise_text('printer'))
    return 0


def stage(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('the XY-Theta stage: self-calibration with the camera, then alignment')
    spec = run.noisy('stage', stage_graph(
        output_dir=str(out / 'calibration'), record_dir=str(out / 'runs'),
        substrate_shift=(0.25e-3, -0.15e-3, float(np.deg2rad(0.04)))))
    start = time.monotonic()
    with Graph(spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs' / 'stage')) as graph:
        response, analysis = run_service(graph, 'stage_calibrator/calibrate',
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
        print_analysis(analysis)
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
            'max 12.3 um', loop_figure(analysis, out), run.noise_text('stage'))
    return 0
