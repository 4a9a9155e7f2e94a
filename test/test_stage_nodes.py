"""XY-Theta stage nodes as separate processes over DDS: refusals, the calibration service
with its bag and offline replay, alignment through the two-way camera, the closed loop."""
import json
import os
import time

import numpy as np
import pytest

DOMAIN = str(160 + os.getpid() % 30)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

from alignment_msgs.srv import Align, AnalyzeResiduals, MoveStage, RunCalibration  # noqa: E402

from calib_core.bags import decode_bag  # noqa: E402
from machine_alignment.cli import main as cli_main  # noqa: E402
from machine_alignment.launcher import stage_graph  # noqa: E402
from calib_core.storage import read_calibration  # noqa: E402
from foxglove import assert_runs_decode  # noqa: E402
from dds import call, machine_align, running  # noqa: E402
from vision_in_force import vision_in_force  # noqa: E402
from printer_alignment.core.stage_calibration import calibrate_stage  # noqa: E402
from printer_alignment.core.records import stage_data_from_records, stage_record  # noqa: E402
from printer_alignment.sim.camera import CameraOptics  # noqa: E402
from printer_alignment.sim.gantry import GantryErrors  # noqa: E402
from printer_alignment.core.vision_calibration import VISION_UNITS  # noqa: E402
from printer_alignment.sim.stage import TRUE_STAGE  # noqa: E402

PLAN = 'sweep_points: 3\ngrid: [2, 2, 2]\n'
SUBSTRATE_SHIFT = (0.25e-3, -0.15e-3, np.deg2rad(0.04))


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    out = tmp_path_factory.mktemp('stage')
    vision_in_force(out / 'calibration')
    spec = stage_graph(output_dir=str(out / 'calibration'), record_dir=str(out / 'runs'),
                       substrate_shift=SUBSTRATE_SHIFT)
    with running(spec, DOMAIN, out, 'stage_test_client') as (graph, node):
        yield graph, node, out


def test_stage_refuses_inputs_outside_the_stroke(graph):
    running, node, _ = graph
    move = node.create_client(MoveStage, 'stage/move')
    refused = call(node, move, MoveStage.Request(q=[0.0, 5.5e-3, 0.0]))
    assert not refused.success and 'outside the stroke' in refused.message
    assert list(refused.q) == [0.0, 0.0, 0.0]
    wrong = call(node, move, MoveStage.Request(q=[0.0, 0.0]))
    assert not wrong.success and '3 chain inputs' in wrong.message
    assert all(running.alive())


def test_align_before_calibration_is_an_error(graph):
    _, node, _ = graph
    answer = call(node, node.create_client(Align, 'aligner/align'),
                  Align.Request(model='parametric'))
    assert not answer.success and 'stage_calibrator/calibrate' in answer.message


def test_calibration_replay_alignment_and_closed_loop(graph):
    running, node, out = graph
    response = call(node, node.create_client(RunCalibration, 'stage_calibrator/calibrate'),
                    RunCalibration.Request(plan_yaml=PLAN), timeout=300.0)
    assert response.success, response.message
    values = dict(zip(response.result.names, response.result.values))
    for i in range(3):   # a short run, so looser than the core test
        assert abs(values[f'lead{i + 1}'] - TRUE_STAGE.lead[i]) < 3e-6
        assert abs(values[f'stepwise_R{i + 1}'] - TRUE_STAGE.lead[i]) < 3e-6
    assert abs(values['alpha1'] - TRUE_STAGE.alpha1) < 1e-3

    # The recorded bag replays through the same code to the same result.
    bag = next((out / 'runs').glob('stage_2*'))
    records = [stage_record(m) for t, _, m in decode_bag(bag)
               if t.endswith('/observations')]
    _, replay = calibrate_stage(stage_data_from_records(records))
    live = json.loads(response.result.report_json)['parametric']['parameters']
    assert max(abs(live[n] - v) for n, v in replay['parametric']['parameters'].items()) < 1e-12
    assert cli_main(['calibrate', 'stage', '--bag', str(bag), '--json',
                     str(out / 'replay.json')]) == 0
    assert json.loads((out / 'replay.json').read_text())['max_difference_to_live'] < 1e-12

    aligned = call(node, node.create_client(Align, 'aligner/align'),
                   Align.Request(model='parametric'), timeout=120.0)
    assert aligned.success, aligned.message
    report = json.loads(aligned.report_json)
    # The substrate was fixed 0.3 mm and 0.04 deg off; after one move it sits on the
    # stencil within the stage's repeatability and the gantry's residual error.
    before = np.linalg.norm(np.mean(report['substrate_before_m'], axis=0)
                            - np.mean(report['stencil_m'], axis=0))
    assert before > 100e-6
    assert aligned.position_error < 12.3e-6
    assert aligned.orientation_error < np.deg2rad(5 / 3600)
    # The alignment bag holds the calibration it used: planned again offline, same inputs.
    alignment_bag = next((out / 'runs').glob('alignment_*'))
    assert cli_main(['evaluate', 'alignment', '--bag', str(alignment_bag), '--json',
                     str(out / 'alignment.json')]) == 0
    replayed = json.loads((out / 'alignment.json').read_text())['alignments']
    assert len(replayed) == 1 and replayed[0]['model'] == 'parametric'
    assert replayed[0]['max_difference_m'] < 1e-12
    np.testing.assert_allclose(replayed[0]['q_replayed_m'], aligned.q, atol=1e-9)

    analysis = call(node, node.create_client(AnalyzeResiduals,
                                             'stage_calibrator/analyze_residuals'),
                    AnalyzeResiduals.Request(apply=False), timeout=300.0)
    assert analysis.success, analysis.message
    assert analysis.analysis.machine == 'stage' and analysis.analysis.rms_after > 0
    # Every stop with its time (a drift tested); no sensor publishes a temperature here.
    loop = json.loads(analysis.analysis.report_json)
    assert 'drift_time' in loop['candidates'] and 'drift_time' not in loop['skipped']
    assert 'drift_time' not in analysis.analysis.effects_added
    assert 'temperature' in loop['skipped']['drift_temperature']
    assert all(running.alive())


def test_calibration_and_alignment_triggered_from_the_command_line(graph):
    """A run the calibrator plans itself (the sweeps of 3 and 8 chosen stops, as short as
    the test's grid run), its prediction stated in the calibration it puts in force; the
    adaptive mode, asked for 0.1 um within 40 stops, says the limits cannot give it
    before measuring more (the rounds themselves: test/test_stage_planning.py)."""
    running, node, out = graph
    done = machine_align(DOMAIN, 'call', 'stage_calibrator/calibrate',
                         'design: I\nstops: 8\nsweep_points: 3\ntarget_error: 1.0e-7\n'
                         'max_stops: 40\n')
    assert done.returncode == 0, done.stderr
    assert 'stage calibration, version' in done.stdout and 'lead1' in done.stdout
    report = read_calibration(out / 'calibration', 'stage')['report']
    prediction, adaptive = report['plan_prediction'], report['adaptive']
    assert prediction['stops'] == 27 and prediction['planned_stops'] == 8
    assert 0.3e-6 < prediction['predicted_rms_m'] < 2e-6
    assert adaptive['stopped'].startswith('target cannot be met within max_stops = 40')
    assert [r['stops'] for r in adaptive['rounds']] == [27]
    aligned = machine_align(DOMAIN, 'call', 'aligner/align', 'parametric')
    assert aligned.returncode == 0, aligned.stderr
    assert 'aligned:' in aligned.stdout
    assert all(running.alive())


def test_a_forged_vision_result_is_not_used(graph):
    """Another process publishing a vision result (latched, success, the pixel size 3.7 %
    too large): the stage calibrator refuses to measure with it and names the publisher.
    The stage file written above names the vision calibration it was computed with."""
    from alignment_msgs.msg import CalibrationResult
    import yaml
    from calib_core.nodes.qos import LATCHED
    running, node, out = graph
    stage = yaml.safe_load((out / 'calibration' / 'stage.yaml').read_text())
    vision = yaml.safe_load((out / 'calibration' / 'vision.yaml').read_text())
    assert stage['vision_calibration']['version'] == vision['version']
    assert stage['vision_calibration']['file'].endswith('vision.yaml')
    forger = node.create_publisher(CalibrationResult, '/vision_calibrator/result', LATCHED)
    camera = CameraOptics().camera2plate
    gantry = GantryErrors().model.as_dict()
    names = ['pixel_size', 'camera_angle', *gantry]
    forger.publish(CalibrationResult(
        kind='vision', success=True, names=names,
        values=[camera.pixel_size * 1.037, camera.angle, *gantry.values()],
        units=[VISION_UNITS[n] for n in names], residual_unit='m', version=99))
    try:
        time.sleep(1.0)
        refused = call(node, node.create_client(RunCalibration, 'stage_calibrator/calibrate'),
                       RunCalibration.Request(plan_yaml=PLAN), timeout=60.0)
        assert not refused.success
        assert 'stage_test_client also publish(es) on /vision_calibrator/result' in \
            refused.message, refused.message
        assert yaml.safe_load((out / 'calibration' / 'stage.yaml').read_text()) == stage
    finally:
        node.destroy_publisher(forger)
    assert all(running.alive())


def test_every_bag_of_these_runs_decodes_in_foxglove(graph):
    """What the runs above recorded (stage, stage_analysis, alignment) opens in Foxglove: its own
    decoders read every channel and message as this suite's reader does."""
    assert_runs_decode(graph[2] / 'runs', {'stage_analysis', 'stage', 'alignment'})
