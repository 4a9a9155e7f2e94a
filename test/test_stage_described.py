"""A user's XY-Theta stage of another size on the live graph (issue 50): the stage and the
camera simulators build it from its description, the stage calibrator searches for the
Marks where the described stage puts them, plans within its stroke and gates by its noise,
the aligner works within its stroke, and the recorded run replays offline to the same
calibration with the same description."""
import json
import os

import numpy as np
import pytest

DOMAIN = str(70 + os.getpid() % 20)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

from alignment_msgs.srv import Align, MoveStage, RunCalibration  # noqa: E402

from calib_core.bags import decode_bag  # noqa: E402
from dds import call, running  # noqa: E402
from machine_alignment.cli import main as cli_main  # noqa: E402
from machine_alignment.launcher import stage_graph  # noqa: E402
from printer_alignment.core.stage_description import read_description  # noqa: E402
from printer_alignment.sim.stage import described_truth  # noqa: E402
from vision_in_force import vision_in_force  # noqa: E402

# Guides 92 mm, 5.5 mm and 78.5 mm off the shipped stage's, its Marks 30 mm further out
# on the platform, an 8 mm stroke (the shipped 5 mm), a coarser camera and chains.
DESCRIPTION = """kind: stage
geometry:
  d_m: [0.36, 0.045, 0.51]
  marks_m: [[0.20, 0.16], [0.32, 0.16]]
instrument: {name: test camera, position_sigma_m: 0.5e-6}
actuators: {unit: m, sigma_m: 1.5e-6}
repeatability_m: 0.0
workspace: {stroke_m: 8.0e-3}
"""
PLAN = 'design: I\nstops: 8\nsweep_points: 3\n'
SUBSTRATE_SHIFT = (0.2e-3, 0.1e-3, np.deg2rad(0.03))


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    out = tmp_path_factory.mktemp('described_stage')
    description = out / 'stage.yaml'
    description.write_text(DESCRIPTION)
    vision_in_force(out / 'calibration')
    spec = stage_graph(output_dir=str(out / 'calibration'), record_dir=str(out / 'runs'),
                       substrate_shift=SUBSTRATE_SHIFT, description=str(description))
    with running(spec, DOMAIN, out, 'described_stage_client') as (graph, node):
        yield graph, node, out


def test_the_described_stroke_is_the_limit(graph):
    """6 mm is beyond the shipped stage's stroke and inside this one's; 8.5 mm is beyond
    both, and the refusal names the described stroke."""
    running, node, _ = graph
    move = node.create_client(MoveStage, 'stage/move')
    inside = call(node, move, MoveStage.Request(q=[6e-3, 0.0, 0.0]))
    assert inside.success, inside.message
    refused = call(node, move, MoveStage.Request(q=[0.0, 8.5e-3, 0.0]))
    assert not refused.success and '[-8.0, 8.0] mm' in refused.message, refused.message
    assert list(refused.q) == pytest.approx([6e-3, 0.0, 0.0])
    assert call(node, move, MoveStage.Request(q=[0.0, 0.0, 0.0])).success
    calibrate = node.create_client(RunCalibration, 'stage_calibrator/calibrate')
    outside = call(node, calibrate, RunCalibration.Request(
        plan_yaml='targets: [[0, 0, 0], [0, 0, 0.0085]]\n'))
    assert not outside.success and '[-8.0, 8.0] mm' in outside.message, outside.message
    assert all(running.alive())


def test_a_planned_calibration_and_an_alignment_of_the_described_stage(graph, capsys):
    running, node, out = graph
    truth = described_truth(read_description(out / 'stage.yaml'))
    response = call(node, node.create_client(RunCalibration, 'stage_calibrator/calibrate'),
                    RunCalibration.Request(plan_yaml=PLAN), timeout=300.0)
    assert response.success, response.message
    values = dict(zip(response.result.names, response.result.values))
    for i in range(3):   # a short run, as in test_stage_nodes
        assert abs(values[f'lead{i + 1}'] - truth.lead[i]) < 3e-6
    assert abs(values['alpha1'] - truth.alpha1) < 1e-3
    # d3 - d2 is what the Marks determine (the gauge); the described guides are 0.465 m
    # apart, the shipped ones 0.392 m.
    assert abs(values['stepwise_d3_minus_d2'] - (truth.d[2] - truth.d[1])) < 0.5e-3
    report = json.loads(response.result.report_json)
    gate = report['description']
    assert gate['file'].endswith('stage.yaml')
    assert gate['residual_limit_m'] == pytest.approx(5 * np.hypot(0.5e-6, 1.5e-6))
    assert report['parametric']['residual_rms_m'] < gate['residual_limit_m']
    assert report['plan_prediction']['planned_stops'] == 8

    # The run went where the described stroke allows: beyond the shipped 5 mm.
    bag = next((out / 'runs').glob('stage_2*'))
    reached = max(np.abs(m.q).max() for t, _, m in decode_bag(bag) if t.endswith('/observations'))
    assert 5e-3 < reached <= 8e-3
    # Offline, the recorded run with the same description gives the same calibration.
    assert cli_main(['calibrate', 'stage', '--bag', str(bag), '--description',
                     str(out / 'stage.yaml'), '--json', str(out / 'replay.json')]) == 0
    assert json.loads((out / 'replay.json').read_text())['max_difference_to_live_sigma'] < 1e-3
    # Without it, the replay says how the live run was made.
    assert cli_main(['calibrate', 'stage', '--bag', str(bag)]) == 0
    assert 'give --description to replay it as it ran' in capsys.readouterr().out

    aligned = call(node, node.create_client(Align, 'aligner/align'),
                   Align.Request(model='parametric'), timeout=120.0)
    assert aligned.success, aligned.message
    assert aligned.position_error < 12.3e-6
    assert aligned.orientation_error < np.deg2rad(5 / 3600)
    assert json.loads(aligned.report_json)['stroke_m'] == 8e-3
    assert all(running.alive())
