"""Two graphs started on one ROS domain both answer every request: both calibrators would
run, both machines move. A calibrator that sees another of its name refuses to calibrate,
says why on the request and on /diagnostics, and calibrates again once it is alone."""
import os
import time

DOMAIN = str(125 + os.getpid() % 5)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

import rclpy  # noqa: E402
from alignment_msgs.srv import RunCalibration  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402

from dds import call, running  # noqa: E402
from machine_alignment.launcher import Graph, NodeSpec  # noqa: E402


def test_a_second_calibrator_of_the_same_name_is_refused(tmp_path):
    # No hexapod here: a calibration that gets past the refusal fails at its first move,
    # after call_timeout_s.
    first = [NodeSpec('hexapod_calib.nodes.hexapod_calibrator',
                      {'output_dir': str(tmp_path / 'a'), 'record_dir': str(tmp_path / 'a'),
                       'call_timeout_s': 1.0})]
    second = [NodeSpec('hexapod_calib.nodes.hexapod_calibrator',
                       {'output_dir': str(tmp_path / 'b'), 'record_dir': str(tmp_path / 'b')})]
    with running(first, DOMAIN, tmp_path, 'two_graphs_probe') as (_, node):
        statuses = []
        node.create_subscription(DiagnosticArray, '/diagnostics', lambda array: statuses.extend(
            array.status), 10)
        client = node.create_client(RunCalibration, 'hexapod_calibrator/calibrate')
        with Graph(second, env={'ROS_DOMAIN_ID': DOMAIN}, log_dir=str(tmp_path / 'logs2')):
            deadline = time.time() + 20
            while time.time() < deadline and not any(
                    s.level == DiagnosticStatus.ERROR and 'another hexapod_calibrator' in s.message
                    for s in statuses):
                rclpy.spin_once(node, timeout_sec=0.2)
            assert any('another hexapod_calibrator is on this ROS domain' in s.message
                       for s in statuses)
            # Whichever of the two answers, it refuses (no hexapod here: nothing could move).
            refused = call(node, client, RunCalibration.Request(plan_yaml='num_poses: 20'))
            assert not refused.success
            assert 'another hexapod_calibrator is on this ROS domain' in refused.message
        # Alone again: the refusal is lifted (this one now fails on the missing hexapod).
        deadline, answer = time.time() + 20, None
        while time.time() < deadline:
            answer = call(node, client, RunCalibration.Request(plan_yaml='num_poses: 20'))
            if 'another hexapod_calibrator' not in answer.message:
                break
            time.sleep(1.0)
        assert 'another hexapod_calibrator' not in answer.message, answer.message
        assert not answer.success and 'hexapod/move' in answer.message, answer.message


def test_a_burst_of_50_calls_from_one_client_is_all_answered(tmp_path):
    """50 calls at once from one client: every one answered, the refused ones at once (27
    to 40 of them were never answered, and their callers waited out their timeout). The
    client keeps every response too (calib_core.nodes.qos.SERVICES, as the suite's own
    clients do): one with the default depth of 10 can drop a burst's responses itself
    when it is slow to take them (37 of 50 under a full test run's load)."""
    from calib_core.nodes.qos import SERVICES
    from std_srvs.srv import Trigger
    spec = [NodeSpec('hexapod_calib.nodes.hexapod_calibrator',
                     {'output_dir': str(tmp_path / 'a'), 'record_dir': str(tmp_path / 'a')})]
    with running(spec, DOMAIN, tmp_path, 'burst_probe') as (_, node):
        for service, kind, request in (
                ('hexapod_calibrator/cancel', Trigger, Trigger.Request()),
                ('hexapod_calibrator/calibrate', RunCalibration,
                 RunCalibration.Request(plan_yaml='speed: 3'))):
            client = node.create_client(kind, service, qos_profile=SERVICES)
            assert client.wait_for_service(timeout_sec=30.0)
            futures = [client.call_async(request) for _ in range(50)]
            deadline = time.time() + 30
            while not all(f.done() for f in futures) and time.time() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            answered = [f.result() for f in futures if f.done()]
            assert len(answered) == 50, f'{service}: {len(answered)} of 50 answered'
            assert not any(a.success for a in answered)
