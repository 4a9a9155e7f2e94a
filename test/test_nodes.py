"""Nodes as separate processes talking over DDS (own ROS_DOMAIN_ID, localhost discovery)."""
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

DOMAIN = str(130 + os.getpid() % 30)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

import rclpy  # noqa: E402
from alignment_msgs.srv import (  # noqa: E402
    AnalyzeResiduals, DetectMarks, MoveGantry, RunCalibration)
from sensor_msgs.msg import Image  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from calib_core.nodes.status import TF_STATIC_QOS  # noqa: E402
from machine_alignment.cli import main as cli_main  # noqa: E402
from machine_alignment.launcher import printer_graph  # noqa: E402
from foxglove import assert_runs_decode  # noqa: E402
from dds import call, machine_align, running  # noqa: E402


# The vision calibrator takes the shipped gantry's description (issue 50), which states
# its defaults: the same numbers hold as without it.
SHIPPED_DESCRIPTION = (Path(__file__).resolve().parents[1] / 'printer_alignment'
                       / 'descriptions' / 'vision_shipped_simulator.yaml')


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    out = tmp_path_factory.mktemp('graph')
    spec = printer_graph(output_dir=str(out / 'calibration'), record_dir=str(out / 'runs'),
                         description=str(SHIPPED_DESCRIPTION))
    with running(spec, DOMAIN, out, 'test_client') as (graph, node):
        yield graph, node, out


def test_gantry_refuses_target_outside_travel(graph):
    running, node, _ = graph
    move = node.create_client(MoveGantry, 'gantry/move')
    refused = call(node, move, MoveGantry.Request(x=0.5, y=0.01))
    assert not refused.success and 'outside the travel' in refused.message
    nan = call(node, move, MoveGantry.Request(x=float('nan'), y=0.01))
    assert not nan.success and 'not finite' in nan.message
    ok = call(node, move, MoveGantry.Request(x=0.05, y=0.04))
    assert ok.success and ok.x == pytest.approx(0.05)
    assert all(running.alive())


def test_detector_service_and_bad_images(graph):
    running, node, _ = graph
    detect = node.create_client(DetectMarks, 'mark_detector/detect')
    found = call(node, detect, DetectMarks.Request(shape='circle'))
    assert found.success and len(found.marks.marks) > 100
    uv = np.array([[m.u, m.v] for m in found.marks.marks])
    assert np.all((uv >= 0) & (uv < [640, 480]))
    wrong = call(node, detect, DetectMarks.Request(shape='circle', expected_count=1))
    assert not wrong.success and 'expected 1' in wrong.message
    # A foreign publisher sends an image in an unsupported encoding: clear error, no crash.
    publisher = node.create_publisher(Image, 'camera/image_raw', 10)
    messages = []
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and not any('encoding' in m for m in messages):
        future = detect.call_async(DetectMarks.Request(shape='circle'))
        time.sleep(0.05)
        bad = Image(height=4, width=4, encoding='32FC3', step=48, data=bytes(192))
        bad.header.stamp = node.get_clock().now().to_msg()
        publisher.publish(bad)
        rclpy.spin_until_future_complete(node, future, timeout_sec=10)
        messages.append(future.result().message)
    assert any('unsupported image encoding' in m for m in messages), messages
    node.destroy_publisher(publisher)
    assert all(running.alive())


def test_calibration_service_and_concurrent_request(graph):
    running, node, out = graph
    client = node.create_client(RunCalibration, 'vision_calibrator/calibrate')
    assert client.wait_for_service(timeout_sec=30.0)
    first = client.call_async(RunCalibration.Request(plan_yaml='{nx: 3, ny: 2}'))
    time.sleep(0.5)
    second = client.call_async(RunCalibration.Request())
    rclpy.spin_until_future_complete(node, second, timeout_sec=30)
    assert not second.result().success and 'already running' in second.result().message
    rclpy.spin_until_future_complete(node, first, timeout_sec=120)
    result = first.result()
    assert result.success, result.message
    values = dict(zip(result.result.names, result.result.values))
    assert values['lead_x'] == pytest.approx(0.0159972, abs=0.5e-6)
    assert (out / 'calibration' / 'vision.v1.yaml').exists()
    bad = call(node, client, RunCalibration.Request(plan_yaml='{nx: 1}'))
    assert not bad.success and 'nx must be an integer from 2 to' in bad.message
    for plan, why in (('{nx: 2.7}', 'nx must be an integer'), ('{pitch: 0}', 'pitch must be a positive')):
        refused = call(node, client, RunCalibration.Request(plan_yaml=plan), timeout=5.0)
        assert not refused.success and why in refused.message   # within 5 s: nothing moved
    assert not (out / 'calibration' / 'vision.v2.yaml').exists()  # previous stays in force
    # The calibrated camera on /tf_static, as a TF listener joining now looks it up: the
    # gantry's zero and axis on the plate, the image axes on the carriage, from the file.
    frames = []
    node.create_subscription(TFMessage, '/tf_static', frames.append, TF_STATIC_QOS)
    deadline = time.time() + 10
    while not frames and time.time() < deadline:
        rclpy.spin_once(node, timeout_sec=0.2)
    assert frames
    links = {(t.header.frame_id, t.child_frame_id): t.transform for t in frames[-1].transforms}
    content = yaml.safe_load((out / 'calibration' / 'vision.yaml').read_text())
    gantry, camera = content['gantry2plate'], content['camera2plate']
    to_gantry, to_camera = links[('plate', 'gantry')], links[('carriage', 'camera')]
    assert [to_gantry.translation.x, to_gantry.translation.y] == pytest.approx(
        [gantry['offset_x'], gantry['offset_y']], abs=1e-12)
    assert 2 * np.arctan2(to_gantry.rotation.z, to_gantry.rotation.w) == pytest.approx(
        gantry['axis_angle'], abs=1e-12)
    assert 2 * np.arctan2(to_camera.rotation.z, to_camera.rotation.w) == pytest.approx(
        camera['angle'] - gantry['axis_angle'], abs=1e-12)
    assert all(running.alive())


def test_analyze_residuals_finds_the_gantry_backlash(graph):
    running, node, out = graph
    client = node.create_client(AnalyzeResiduals, 'vision_calibrator/analyze_residuals')
    bad = call(node, client, AnalyzeResiduals.Request(plan_yaml='{points: 3}'))
    assert not bad.success and 'points must be' in bad.message
    response = call(node, client, AnalyzeResiduals.Request(plan_yaml='{points: 40}', apply=True),
                    timeout=180)
    assert response.success, response.message
    analysis = response.analysis
    report = json.loads(analysis.report_json)
    assert analysis.machine == 'gantry' and report['rows']['total'] == 40
    # The simulated gantry has 4 / 6 um backlash, which the paper's model lacks.
    assert 'reversal' in analysis.effects_added
    backlash = next(e for e in report['effects_added'] if e['name'] == 'reversal')['parameters']
    assert backlash['backlash_x'] == pytest.approx(4e-6, abs=1.5e-6)
    assert backlash['backlash_y'] == pytest.approx(6e-6, abs=1.5e-6)
    assert analysis.rms_after < 0.6 * analysis.rms_before
    # Each position with its frame's time and the machine's temperature (20 C throughout):
    # a drift in time tested and not added on a machine that does not drift.
    assert 'drift_time' in report['candidates'] and 'drift_time' not in report['skipped']
    assert report['skipped']['drift_temperature'] == 'temperature is constant in the data'
    assert not {'drift_time', 'drift_temperature'} & set(analysis.effects_added)
    assert analysis.applied and (out / 'calibration' / 'vision.v2.yaml').exists()
    assert all(running.alive())


def test_intrinsics_service_on_the_dot_plate(graph):
    running, node, out = graph
    client = node.create_client(RunCalibration, 'vision_calibrator/calibrate_intrinsics')
    bad = call(node, client, RunCalibration.Request(plan_yaml='{views: 4}'))
    assert not bad.success and 'unknown plan keys' in bad.message
    for plan, why in (('{focal_px: 0}', 'focal_px must be a positive'),
                      ('{n: 2.5}', 'n must be an integer'), ('{step: 1.3}', 'look like mm')):
        refused = call(node, client, RunCalibration.Request(plan_yaml=plan), timeout=5.0)
        assert not refused.success and why in refused.message, refused.message
    assert not list((out / 'runs').glob('intrinsics_*'))   # refused before the first move
    response = call(node, client, RunCalibration.Request(plan_yaml='{n: 2, step: 0.0013}'),
                    timeout=120.0)
    assert response.success, response.message
    values = dict(zip(response.result.names, response.result.values))
    # The simulated lens has no distortion (k1 0.5 is recovered in the core test).
    assert abs(values['k1']) < 0.02 and abs(values['p1']) < 2e-3
    assert values['fx'] == 2000.0 and values['cx'] == 319.5
    assert response.result.rms_residual < 0.05 and response.result.num_observations == 4
    report = json.loads(response.result.report_json)
    assert 'focal length' in report['fixed']['fx']
    assert (out / 'calibration' / 'intrinsics.v1.yaml').exists()
    # The recorded run reruns offline through the same code to the same numbers.
    bag = next((out / 'runs').glob('intrinsics_*'))
    assert cli_main(['calibrate', 'camera', '--bag', str(bag), '--json',
                     str(out / 'intrinsics.json')]) == 0
    assert json.loads((out / 'intrinsics.json').read_text())['max_difference_to_live'] < 1e-9
    assert all(running.alive())


def test_calibration_triggered_from_the_command_line(graph):
    running, node, out = graph
    done = machine_align(DOMAIN, 'call', 'vision_calibrator/calibrate', '{nx: 3, ny: 2}')
    assert done.returncode == 0, done.stderr
    assert 'vision calibration, version' in done.stdout and '7/7' in done.stdout
    assert 'pixel_size' in done.stdout
    assert all(running.alive())


def test_every_bag_of_these_runs_decodes_in_foxglove(graph):
    """What the runs above recorded (vision, vision_analysis) opens in Foxglove: its own
    decoders read every channel and message as this suite's reader does."""
    assert_runs_decode(graph[2] / 'runs', {'vision_analysis', 'vision'})
