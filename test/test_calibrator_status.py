"""A calibrator's /diagnostics status and /tf_static frames (calib_core.nodes.status), on
an rclpy node in this process with discovery off (every ROS domain is some DDS test
module's band, and nothing here needs a peer): each level from what the node was handed."""
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

import rclpy
from alignment_msgs.msg import CalibrationResult, Progress, ResidualAnalysis
from alignment_msgs.srv import RunCalibration
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node

from calib_core.errors import CalibrationError
from calib_core.frames import planar
from calib_core.nodes.calibrator import CalibrationService
from calib_core.nodes.status import CalibratorStatus
from calib_core.storage import write_calibration

CREATED = datetime(2026, 11, 1, 8, 0, tzinfo=timezone.utc)


class _Sink:
    def __init__(self):
        self.sent = []

    def publish(self, message):
        self.sent.append(message)


@pytest.fixture
def node(tmp_path, monkeypatch):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF')    # read by rclpy.init
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node('status_test', context=context)
    node.declare_parameter('output_dir', str(tmp_path))
    yield node
    node.destroy_node()
    rclpy.shutdown(context=context)


def _frames(content):
    return [('plate', 'gantry', *planar(content['x'], 0.0, content['angle']))]


def _values(status):
    return {kv.key: kv.value for kv in status.values}


def _in_force(node, tmp_path, status, x=0.001):
    _, version = write_calibration(tmp_path, 'demo', {'created': CREATED.strftime(
        '%Y%m%dT%H%M%S%f'), 'x': x, 'angle': 0.002})
    tapped = status.tap(_Sink())
    tapped.publish(CalibrationResult(success=True, version=version, rms_residual=1.5e-6,
                                     residual_unit='m', file_path=f'demo.v{version}.yaml'))
    return version


def test_levels_follow_what_the_node_did(node, tmp_path):
    status = CalibratorStatus(node, 'demo', _frames)
    day_after = CREATED + timedelta(days=1)
    first = status.status(day_after)
    assert first.level == DiagnosticStatus.WARN and 'no calibration in force' in first.message
    version = _in_force(node, tmp_path, status)
    ok = status.status(day_after)
    assert ok.level == DiagnosticStatus.OK, ok.message
    values = _values(ok)
    assert values['version'] == str(version) and values['age_days'] == '1.00'
    assert values['frames'] == 'plate->gantry' and values['state'] == 'idle'
    # Older than the 30 days allowed by default.
    stale = status.status(CREATED + timedelta(days=31))
    assert stale.level == DiagnosticStatus.WARN and '31 days old' in stale.message
    # A closed loop that left something unexplained.
    analysis = status.tap(_Sink(), 'analysis')
    analysis.publish(ResidualAnalysis(effects_added=['reversal'], rms_after=2e-6, unit='m',
                                      unexplained=['periodic of x vs position_x']))
    warned = status.status(day_after)
    assert warned.level == DiagnosticStatus.WARN and 'unexplained' in warned.message
    assert _values(warned)['loop_unexplained'] == 'periodic of x vs position_x'
    analysis.publish(ResidualAnalysis(effects_added=[], rms_after=2e-6, unit='m'))
    assert status.status(day_after).level == DiagnosticStatus.OK
    # A run that failed (the gate refused its result) is an ERROR until one succeeds; a
    # malformed request changes no level.
    status.finished(False, 'residual above the gate', refused=False)
    failed = status.status(day_after)
    assert failed.level == DiagnosticStatus.ERROR and 'gate' in failed.message
    status.finished(False, 'unknown plan keys', refused=True)
    still = status.status(day_after)
    assert still.level == DiagnosticStatus.ERROR
    assert _values(still)['last_request_refused'] == 'unknown plan keys'
    status.finished(True)
    cleared = status.status(day_after)
    assert cleared.level == DiagnosticStatus.OK and 'last_request_refused' not in _values(cleared)


def test_a_running_calibration_shows_its_progress(node, tmp_path):
    status = CalibratorStatus(node, 'demo', None)
    status.busy.acquire()
    status.tap(_Sink(), 'progress').publish(Progress(task='calibration', step=3, total=20,
                                                      message='pose 3'))
    assert _values(status.status())['state'] == 'calibration 3/20: pose 3'
    status.busy.release()
    assert _values(status.status())['state'] == 'idle'


def test_frames_are_sent_again_when_a_new_calibration_goes_into_force(node, tmp_path):
    status = CalibratorStatus(node, 'demo', _frames)
    status._tf_pub = _Sink()        # what would go on /tf_static
    _in_force(node, tmp_path, status, x=0.001)
    _in_force(node, tmp_path, status, x=0.003)
    messages = status._tf_pub.sent
    assert len(messages) == 2
    shifts = [m.transforms[0].transform.translation.x for m in messages]
    assert shifts == [0.001, 0.003]
    assert messages[-1].transforms[0].header.frame_id == 'plate'
    assert messages[-1].transforms[0].child_frame_id == 'gantry'
    rotation = messages[-1].transforms[0].transform.rotation
    assert np.arctan2(rotation.z, rotation.w) * 2 == pytest.approx(0.002)


def test_a_calibration_service_reports_how_its_runs_ended(node, tmp_path):
    status = CalibratorStatus(node, 'demo', None)
    _in_force(node, tmp_path, status)

    def run(plan):
        if plan.get('fail'):
            raise CalibrationError('the fit failed its sanity checks')
        return CalibrationResult(success=True)
    service = CalibrationService(node, 'demo', run, lambda: None, busy=status.busy,
                                 status=status)
    service(RunCalibration.Request(plan_yaml='fail: true'), RunCalibration.Response())
    assert status.status().level == DiagnosticStatus.ERROR
    service(RunCalibration.Request(plan_yaml='[not, a, mapping]'), RunCalibration.Response())
    assert status.status().level == DiagnosticStatus.ERROR      # refused: no change
    service(RunCalibration.Request(plan_yaml=''), RunCalibration.Response())
    assert status.status().level == DiagnosticStatus.OK
