"""What a calibrator tells the rest of the graph about itself, the same for every machine:
its calibrated frames on ``/tf_static`` (latched, as tf2_ros's static broadcaster does:
one message with all of this node's frames, sent again when a new calibration goes into
force) and its state on ``/diagnostics`` at 1 Hz (``diagnostic_msgs/DiagnosticArray``).

The diagnostic status (name ``<node>: calibration``) says which calibration is in force
(file, version, when it was made, its fit residual), the last closed loop's verdict, what
the node is doing, and rates it:

- ERROR: the last calibration run failed or its gate refused the result (the previous
  calibration stays in force, and the status says so), or another node of this name is
  on the domain (a second graph: the node refuses to calibrate until it is gone); a
  request refused before it ran (a malformed plan, a move outside the stroke) is shown but
  changes no level;
- WARN: no calibration in force, one older than ``max_calibration_age_days``, or a last
  closed loop that left something unexplained;
- OK otherwise.

The node hands its latched result and analysis publishers to :meth:`CalibratorStatus.tap`
and its calibration services a :meth:`CalibratorStatus.finished` callback.

It also serves ``<node>/cancel`` (std_srvs/Trigger): the run in progress stops at its next
safe point, before the next move (the node calls :meth:`CalibratorStatus.check_cancelled`
there), and answers its caller with the reason; the run's bag keeps what was measured and
the calibration in force is unchanged.
"""
from __future__ import annotations

import threading
from datetime import datetime, timezone
from typing import Callable

import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from calib_core.errors import CalibrationError, MachineAlignmentError, RunCancelled
from calib_core.frames import Frame
from calib_core.nodes.qos import SERVICES
from calib_core.nodes.recording import STAMP_FORMAT
from calib_core.nodes.scene import TF_STATIC_TOPIC, transform_message
from calib_core.storage import read_calibration

DIAGNOSTICS_TOPIC = '/diagnostics'
DIAGNOSTICS_PERIOD_S = 1.0
# tf2_ros's static broadcaster: reliable, kept for listeners that join later.
TF_STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
DEFAULT_MAX_AGE_DAYS = 30.0
TWIN_CHECK_PERIOD_S = 2.0    # s between looks for another node of this name


class _Tap:
    """A publisher that also tells the status what it published. ``static_frames`` is the
    last /tf_static message the status sent (None before any), which a recorded run
    writes to its bag beside the result that put the frames in force."""

    def __init__(self, publisher, seen: Callable, status: 'CalibratorStatus'):
        self._publisher, self._seen, self._status = publisher, seen, status

    def publish(self, message) -> None:
        self._publisher.publish(message)
        self._seen(message)

    @property
    def static_frames(self):
        return self._status.frames_message


class CalibratorStatus:
    """``/tf_static`` and ``/diagnostics`` of one calibrator node.

    Parameters
    ----------
    node : rclpy.node.Node
        Declares ``output_dir`` (where the calibration files are).
    name : str
        The calibration file's name (``<output_dir>/<name>.yaml``).
    frames : callable, optional
        The calibrated frames of a calibration file's content: (parent, child, translation
        (3,) m, quaternion (x, y, z, w)) each; None where the calibration fixes no frame.

    Attributes
    ----------
    busy : threading.Lock
        Held while the node runs a calibration or an analysis: hand it to the node's
        CalibrationService."""

    def __init__(self, node, name: str, frames: Callable[[dict], list[Frame]] | None = None):
        self.node, self.name, self.frames = node, name, frames
        self.busy = threading.Lock()
        node.declare_parameter('max_calibration_age_days', DEFAULT_MAX_AGE_DAYS)
        self.max_age_days = float(node.get_parameter('max_calibration_age_days').value)
        if not self.max_age_days > 0:
            raise ValueError('max_calibration_age_days must be > 0 days')
        self._lock = threading.Lock()
        self._in_force: dict | None = None
        self._failure: str | None = None
        self._refused: str | None = None
        self._loop: dict | None = None
        self._doing = ''
        self.frames_message: TFMessage | None = None
        self._tf_pub = node.create_publisher(TFMessage, TF_STATIC_TOPIC, TF_STATIC_QOS)
        self._diagnostics_pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._cancel = threading.Event()
        # Its own group: answered while the run's callback holds the node's.
        node.create_service(Trigger, f'{node.get_name()}/cancel', self._on_cancel,
                            qos_profile=SERVICES, callback_group=ReentrantCallbackGroup())
        node.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)
        self.twin: str | None = None
        node.create_timer(TWIN_CHECK_PERIOD_S, self._look_for_a_twin)

    # -- another node of this name on the domain ------------------------------------------

    def _look_for_a_twin(self) -> None:
        """Two graphs on one domain both answer every request: both calibrators run, both
        simulators or machines move. Once a second node of this name is seen, the node
        refuses to calibrate (:meth:`check_alone`) until it is gone."""
        name = self.node.get_name()
        count = sum(1 for other in self.node.get_node_names() if other == name)
        twin = (f'another {name} is on this ROS domain (ROS_DOMAIN_ID '
                f'{self.node.context.get_domain_id()}): two graphs would both drive the '
                'machine; stop one, or give each cell its own domain') if count > 1 else None
        if twin and not self.twin:
            self.node.get_logger().error(twin)
        self.twin = twin

    def check_alone(self) -> None:
        """Raise CalibrationError while another node of this name is on the domain."""
        if self.twin:
            raise CalibrationError(self.twin)

    # -- cancelling a run -----------------------------------------------------------------

    def start_run(self) -> None:
        """A run (calibration or analysis) starts: an earlier cancel does not apply to it,
        and it may not run beside a twin (:meth:`check_alone` raises)."""
        self._cancel.clear()
        self.check_alone()

    def check_cancelled(self) -> None:
        """Called before each move of a run: the safe point where a cancel stops it.

        Raises
        ------
        RunCancelled
            The operator called ``<node>/cancel`` since the run started."""
        if self._cancel.is_set():
            raise RunCancelled('cancelled by the operator before the next move; what was '
                               'measured is in the run\'s bag, the calibration in force is '
                               'unchanged')

    def _on_cancel(self, request, response):
        if not self.busy.locked():
            response.success, response.message = False, 'nothing is running'
            return response
        self._cancel.set()
        self.node.get_logger().warning('cancel requested: the run stops before its next move')
        response.success, response.message = True, 'the run stops before its next move'
        return response

    # -- what the node hands over ---------------------------------------------------------

    def tap(self, publisher, kind: str = 'result'):
        """``publisher`` wrapped: what it publishes also updates the status. ``kind`` is
        'result' (CalibrationResult), 'analysis' (ResidualAnalysis) or 'progress'."""
        seen = {'result': self._result, 'analysis': self._analysis,
                'progress': self._progress}[kind]
        return _Tap(publisher, seen, self)

    def finished(self, success: bool, message: str = '', refused: bool = False) -> None:
        """A calibration run ended. A failure stays the node's ERROR until a run succeeds;
        a ``refused`` request (malformed, outside the stroke: nothing about the machine) is
        only shown."""
        with self._lock:
            self._doing = ''
            if refused:
                self._refused = message
                return
            self._failure = None if success else message
            self._refused = None

    # -- what the taps see ----------------------------------------------------------------

    def _result(self, message) -> None:
        if not message.success:
            return
        content = self._read()
        with self._lock:
            self._in_force = {'file': message.file_path, 'version': int(message.version),
                              'created': str(content.get('created', '')),
                              'rms_residual': float(message.rms_residual),
                              'max_residual': float(message.max_residual),
                              'residual_unit': message.residual_unit}
        self._send_frames(content)

    def _analysis(self, message) -> None:
        with self._lock:
            self._loop = {'effects_added': list(message.effects_added),
                          'unexplained': list(message.unexplained),
                          'rms_after': float(message.rms_after), 'unit': message.unit}
        if message.applied:
            # The extended model is a new version of the file in force.
            content = self._read()
            with self._lock:
                if self._in_force is not None and 'version' in content:
                    self._in_force.update(version=int(content['version']),
                                          created=str(content.get('created', '')))
            self._send_frames(content)

    def _read(self) -> dict:
        """The calibration file in force ({} where there is none or it cannot be read)."""
        directory = self.node.get_parameter('output_dir').value
        try:
            content = read_calibration(directory, self.name)
        except (OSError, ValueError, yaml.YAMLError) as exc:
            self.node.get_logger().error(f'cannot read {self.name} for its status: {exc!r}')
            return {}
        return content if isinstance(content, dict) else {}

    def _progress(self, message) -> None:
        with self._lock:
            self._doing = (f'{message.task} {message.step}/{message.total}: {message.message}'
                           if message.total else f'{message.task}: {message.message}')

    def _send_frames(self, content: dict) -> None:
        if self.frames is None or not content:
            return
        try:
            frames = self.frames(content)
        except (MachineAlignmentError, KeyError, TypeError, ValueError) as exc:
            self.node.get_logger().error(f'the calibration {self.name} in force has no '
                                         f'frames to publish ({exc!r})')
            return
        now = self.node.get_clock().now().nanoseconds
        self.frames_message = transform_message(now, frames)
        self._tf_pub.publish(self.frames_message)

    # -- what it says ---------------------------------------------------------------------

    def status(self, now: datetime | None = None) -> DiagnosticStatus:
        """The node's DiagnosticStatus now (UTC)."""
        now = now or datetime.now(timezone.utc)
        with self._lock:
            in_force, failure, loop, doing = self._in_force, self._failure, self._loop, self._doing
            refused = self._refused
        running = self.busy.locked()
        values = {'state': (doing or 'calibrating') if running else 'idle'}
        problems, level = [], DiagnosticStatus.OK
        if in_force is None:
            problems.append('no calibration in force')
            level = DiagnosticStatus.WARN
        else:
            values.update({k: str(v) for k, v in in_force.items()})
            age = _age_days(in_force['created'], now)
            if age is not None:
                values['age_days'] = f'{age:.2f}'
                if age > self.max_age_days:
                    problems.append(f'calibration {age:.0f} days old (more than '
                                    f'{self.max_age_days:g})')
                    level = DiagnosticStatus.WARN
        if loop is not None:
            values['loop_effects_added'] = ', '.join(loop['effects_added']) or 'none'
            values['loop_unexplained'] = '; '.join(loop['unexplained']) or 'none'
            values['loop_rms_after'] = f'{loop["rms_after"]:.4g} {loop["unit"]}'
            if loop['unexplained']:
                problems.append(f'the last closed loop left {len(loop["unexplained"])} '
                                'structure(s) unexplained')
                level = DiagnosticStatus.WARN
        if self.frames_message is not None:
            values['frames'] = ', '.join(f'{t.header.frame_id}->{t.child_frame_id}'
                                         for t in self.frames_message.transforms)
        if refused is not None:
            values['last_request_refused'] = refused
        if self.twin:
            problems.insert(0, self.twin)
            level = DiagnosticStatus.ERROR
        if failure is not None:
            values['last_failure'] = failure
            problems.insert(0, f'the last calibration failed ({failure}); the previous one '
                               'stays in force')
            level = DiagnosticStatus.ERROR
        summary = '; '.join(problems) or (
            f'{self.name} v{in_force["version"]} in force')
        return DiagnosticStatus(
            level=level, name=f'{self.node.get_name()}: calibration',
            hardware_id=self.node.get_name(), message=summary,
            values=[KeyValue(key=k, value=v) for k, v in values.items()])

    def publish_diagnostics(self) -> None:
        array = DiagnosticArray(status=[self.status()])
        array.header.stamp = self.node.get_clock().now().to_msg()
        self._diagnostics_pub.publish(array)


def _age_days(created: str, now: datetime) -> float | None:
    """Days since a calibration's ``created`` stamp (UTC), or None where it has none."""
    try:
        made = datetime.strptime(created, STAMP_FORMAT).replace(tzinfo=timezone.utc)
    except ValueError:
        return None
    return (now - made).total_seconds() / 86400.0
