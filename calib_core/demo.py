"""`make demo`: calibrate the simulated printer's vision system end to end.

1. Start gantry_sim, camera_sim, mark_detector and vision_calibrator as separate processes
   (own ROS_DOMAIN_ID, localhost discovery) and trigger ``vision_calibrator/calibrate``.
2. Re-run the calibration offline from the bag the node recorded: same result.
3. Evaluate against the simulation's truth over the whole travel: camera-measured dot
   positions before (nominal model) and after calibration, as JSON and PNG.
"""
from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

from calib_core.storage import write_atomic


def run_demo(out: Path) -> int:
    out = out.resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    domain = str(100 + os.getpid() % 100)
    os.environ['ROS_DOMAIN_ID'] = domain
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import rclpy
    from alignment_msgs.msg import Progress
    from alignment_msgs.srv import RunCalibration

    from calib_core.launcher import Graph, printer_graph

    print(f'[1/3] starting the simulated printer (ROS_DOMAIN_ID={domain}); logs in {out}/logs')
    graph_spec = printer_graph(output_dir=str(out / 'calibration'), record_dir=str(out / 'runs'))
    with Graph(graph_spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs')) as graph:
        rclpy.init()
        node = rclpy.create_node('demo_client')
        try:
            node.create_subscription(Progress, '/vision_calibrator/progress',
                                     lambda m: print(f'      {m.step}/{m.total} {m.message}'), 10)
            client = node.create_client(RunCalibration, 'vision_calibrator/calibrate')
            if not client.wait_for_service(timeout_sec=30.0):
                print(f'vision_calibrator did not come up; processes alive: {graph.alive()}')
                return 1
            start = time.monotonic()
            future = client.call_async(RunCalibration.Request())
            rclpy.spin_until_future_complete(node, future, timeout_sec=300.0)
            response = future.result()
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    if response is None or not response.success:
        print(f'calibration failed: {response.message if response else "timeout"}')
        return 1
    result = response.result
    print(f'      done in {time.monotonic() - start:.1f} s; calibration file {result.file_path} '
          f'(version {result.version})')

    print('[2/3] re-running the calibration offline from the recorded bag')
    from calib_core.cli import main as cli_main
    bag = next((out / 'runs').iterdir())
    cli_main(['calibrate', 'vision', '--bag', str(bag), '--json', str(out / 'replay.json')])

    print('[3/3] evaluating against the simulation truth over the whole travel')
    from printer_alignment.core.geometry import CameraToPlate, GantryModel
    from printer_alignment.sim.camera import CameraSim
    from printer_alignment.sim.evaluation import measure_errors, plot_errors, summarise
    from printer_alignment.sim.gantry import GantrySim
    from printer_alignment.sim.scene import make_scene
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
    print(f'wrote {out}/vision_evaluation.json and .png')
    return 0
