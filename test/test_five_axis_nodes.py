"""The five-axis dispenser on the live graph (the machine with its camera, the calibrator)
as separate processes over DDS: one call plans, checks, drives, images, calibrates with
RANSAC and evaluates on held-out poses; the recorded run solves again offline to the same
parameters; a plan outside the strokes is refused before anything moves."""
import json
import os

import pytest

DOMAIN = str(1 + os.getpid() % 9)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

from alignment_msgs.srv import MoveFiveAxis, RunCalibration  # noqa: E402

from calib_core.storage import read_calibration  # noqa: E402
from machine_alignment.launcher import five_axis_graph  # noqa: E402
from dds import call, machine_align, running  # noqa: E402


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    out = tmp_path_factory.mktemp('five_axis_graph')
    with running(five_axis_graph(str(out / 'calibration'), str(out / 'runs'), 0.1), DOMAIN, out,
                 'five_axis_test_client') as (graph, node):
        yield graph, node, out


def test_one_call_calibrates_and_evaluates_on_held_out_poses(graph):
    running_graph, node, out = graph
    client = node.create_client(RunCalibration, 'five_axis_calibrator/calibrate')
    response = call(node, client, RunCalibration.Request(plan_yaml='{evaluation: 4}'),
                    timeout=180.0)
    assert response.success, response.message
    assert all(running_graph.alive())
    report = json.loads(response.result.report_json)
    assert report['mean_reprojection_px'] < 0.2
    assert report['held_out']['rms_px_calibrated'] < 0.3 < report['held_out']['rms_px_nominal']
    assert len(response.result.names) == 31
    assert 'parameters' in read_calibration(out / 'calibration', 'five_axis')


def test_the_recorded_run_solves_again_offline(graph, tmp_path):
    _, _, out = graph
    bag = read_calibration(out / 'calibration', 'five_axis')['bag']
    done = machine_align(DOMAIN, 'calibrate', 'five-axis', '--bag', bag, '--json',
                         str(tmp_path / 'replay.json'))
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / 'replay.json').read_text())['max_difference_to_live_sigma'] < 1e-3


def test_a_pose_outside_the_strokes_is_refused(graph):
    _, node, _ = graph
    client = node.create_client(MoveFiveAxis, 'five_axis/move')
    response = call(node, client, MoveFiveAxis.Request(pose=[0.0, 0.0, 0.0, 2.0, 0.0]))
    assert not response.success and 'outside the stroke' in response.message
