"""The demo's hexapod steps: calibrate and the closed loop live, replay the bag, compare
the 42 parameters with the simulation's truth."""
from __future__ import annotations

import json
import time

import numpy as np

from calib_core.storage import write_atomic
from hexapod_calib.sim.hexapod import HexapodTruth
from machine_alignment.demo.common import (
    DemoRun, calibrate_offline, loop_figure, print_analysis, run_service)
from machine_alignment.launcher import Graph, hexapod_graph


def hexapod(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('starting the simulated hexapod cell and calibrating it')
    spec = run.noisy('hexapod', hexapod_graph(output_dir=str(out / 'calibration'),
                                              record_dir=str(out / 'runs')))
    start = time.monotonic()
    with Graph(spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs' / 'hexapod')) as graph:
        response, analysis = run_service(graph, 'hexapod_calibrator/calibrate',
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
    print_analysis(analysis)

    run.step('re-running the identification offline from the bag; 42 parameters against truth')
    bag = next(b for b in (out / 'runs').glob('hexapod_*') if 'analysis' not in b.name)
    calibrate_offline(['hexapod', '--bag', str(bag), '--out', str(out / 'hexapod_replay.yaml'),
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
            loop_figure(analysis, out), run.noise_text('hexapod'))
    return 0
