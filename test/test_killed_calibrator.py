"""A calibrator SIGKILLed in the middle of a run (issue 19): the run's bag still replays
every stop it measured before the kill, the calibration in force is unchanged, the
``machine-align call`` waiting on it ends with a clear error within 30 s (issue 31), and
the restarted calibrator publishes it; its folder parameters are read-only."""
import os
import signal
import subprocess
import sys
import time

DOMAIN = str(190 + os.getpid() % 20)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

import pytest  # noqa: E402
import rclpy  # noqa: E402
from alignment_msgs.msg import CalibrationResult, HexapodMeasurement  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402

from calib_core.bags import cut_run_count, decode_bag  # noqa: E402
from calib_core.nodes.qos import LATCHED  # noqa: E402
from calib_core.storage import read_calibration, write_calibration  # noqa: E402
from dds import running  # noqa: E402
from foxglove import assert_foxglove_reads  # noqa: E402
from hexapod_calib.core.geometry import nominal_geometry  # noqa: E402
from hexapod_calib.core.procedure import HexapodPlan  # noqa: E402
from hexapod_calib.core.records import (  # noqa: E402
    HEXAPOD_RESULT_TOPIC, MEASUREMENTS_TOPIC, measurement_record)
from machine_alignment.cli import main as cli_main  # noqa: E402
from machine_alignment.launcher import hexapod_graph  # noqa: E402

CALIBRATOR = 2   # position of hexapod_calibrator in hexapod_graph()


def test_sigkill_mid_run_keeps_the_measured_stops_and_the_calibration_in_force(tmp_path, capsys):
    calibration = tmp_path / 'calibration'
    in_force, _ = write_calibration(calibration, 'hexapod_geometry',
                                    {**nominal_geometry().as_dict(), 'kind': 'hexapod'})
    before = in_force.read_bytes()
    spec = hexapod_graph(output_dir=str(calibration), record_dir=str(tmp_path / 'runs'))
    with running(spec, DOMAIN, tmp_path, 'kill_test_client') as (graph, node):
        seen = []
        node.create_subscription(HexapodMeasurement, MEASUREMENTS_TOPIC, seen.append, 100)
        # The run must not start before this subscription is matched to the calibrator's
        # publisher: one .ci/run under load saw 4 of a whole run's 60 stops, the rest
        # published before discovery had matched the two (the run completed).
        deadline = time.monotonic() + 60
        while node.count_publishers(MEASUREMENTS_TOPIC) < 1 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        assert node.count_publishers(MEASUREMENTS_TOPIC) >= 1, 'no measurements publisher'
        settled = time.monotonic() + 1.0     # the publisher's side of the match
        while time.monotonic() < settled:
            rclpy.spin_once(node, timeout_sec=0.1)
        caller = subprocess.Popen(
            [sys.executable, '-m', 'machine_alignment.cli', 'call', '--quiet',
             'hexapod_calibrator/calibrate'], env={**os.environ, 'ROS_DOMAIN_ID': DOMAIN},
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 120
        while len(seen) < 10 and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        if len(seen) < 10:
            # Say what the caller saw.
            caller.kill()
            output = caller.communicate()
            pytest.fail(f'the run did not start measuring ({len(seen)} measurements in '
                        f'120 s); the caller printed: {output}')
        graph.processes[CALIBRATOR].send_signal(signal.SIGKILL)
        graph.processes[CALIBRATOR].wait(10)
        killed_at = time.monotonic()
        while time.monotonic() < killed_at + 1.0:     # what was on its way before the kill
            rclpy.spin_once(node, timeout_sec=0.1)
        seen_at_kill = len(seen)
        try:
            _, stderr = caller.communicate(timeout=45)
        finally:
            caller.kill()
        waited = time.monotonic() - killed_at
        assert caller.returncode == 2, stderr
        assert 'hexapod_calibrator/calibrate went away' in stderr and 'died' in stderr, stderr
        assert waited < 30, f'call noticed the dead calibrator after {waited:.0f} s'

    bag = next((tmp_path / 'runs').iterdir())
    recovered = [measurement_record(m) for t, _, m in decode_bag(bag) if t == MEASUREMENTS_TOPIC]
    # Each stop is published, then written: the kill may fall between the two. Every stop
    # seen is in the bag; stops published just before the kill may not have reached the
    # test's subscription under load (measured: 19 in the bag with 10 seen, and 65 with
    # 10), so more can be, but fewer than the whole default plan: the run was cut.
    plan = HexapodPlan()
    whole_plan = plan.num_poses * plan.iterations + 2 * plan.num_evaluation
    assert seen_at_kill - 1 <= len(recovered) == cut_run_count(bag, MEASUREMENTS_TOPIC) \
        < whole_plan
    assert in_force.read_bytes() == before
    assert read_calibration(calibration, 'hexapod_geometry')['kind'] == 'hexapod'
    assert sorted(p.name for p in calibration.glob('hexapod_geometry*.yaml')) \
        == ['hexapod_geometry.v1.yaml', 'hexapod_geometry.yaml']
    # The replay solves from the stops recovered and says the bag was cut.
    capsys.readouterr()
    assert cli_main(['calibrate', 'hexapod', '--bag', str(bag), '--geometry',
                     str(in_force)]) == 0
    replay = capsys.readouterr().out
    assert 'is a cut run' in replay and f'{len(recovered)} stops recovered' in replay, replay
    # A kill after the identification rounds leaves evaluation stops in the bag too
    # (measured under load: 68 recovered, 60 of them identification stops); only the
    # identification stops are used.
    identification_stops = sum(phase.startswith('identify_') for phase, *_ in recovered)
    assert 0 < identification_stops <= plan.num_poses * plan.iterations
    assert f'{len(recovered)} recorded stops, {identification_stops} used' in replay, replay
    # Written as a complete bag, the cut run opens in Foxglove with every message it held.
    assert cli_main(['recover', str(bag)]) == 0
    complete = bag.with_name(f'{bag.name}_recovered')
    assert f'written to {complete}' in capsys.readouterr().out
    seen_by_foxglove = assert_foxglove_reads([complete])[complete.name]
    assert seen_by_foxglove[MEASUREMENTS_TOPIC] == len(recovered)
    assert sum(seen_by_foxglove.values()) == cut_run_count(bag)
    assert cli_main(['recover', str(complete)]) == 2      # complete already: refused

    # Restarted, the calibrator publishes the calibration in force (latched), and its
    # folders cannot be redirected by a peer on the domain.
    with running(spec[CALIBRATOR:], DOMAIN, tmp_path, 'restart_test_client') as (graph, node):
        got = []
        node.create_subscription(CalibrationResult, HEXAPOD_RESULT_TOPIC, got.append, LATCHED)
        deadline = time.monotonic() + 30
        while not got and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        assert got and got[0].version == 1 and got[0].file_path.endswith('hexapod_geometry.yaml')
        assert dict(zip(got[0].names, got[0].values)) \
            == nominal_geometry().parameters().as_dict()
        setter = node.create_client(SetParameters, '/hexapod_calibrator/set_parameters')
        assert setter.wait_for_service(timeout_sec=10.0)
        future = setter.call_async(SetParameters.Request(parameters=[Parameter(
            name='output_dir', value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                    string_value=str(tmp_path / 'elsewhere')))]))
        rclpy.spin_until_future_complete(node, future, timeout_sec=10.0)
        assert not future.result().results[0].successful
