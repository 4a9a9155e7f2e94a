"""What every calibrator node does the same way: declare where its files go (read-only:
set at launch, not by any peer on the domain at run time), publish the calibration in
force at start-up, call another node's service with a timeout, and serve a RunCalibration
request one at a time, answering every failure with an error instead of crashing."""
from __future__ import annotations

import math
import threading
from typing import Callable

import yaml
from rcl_interfaces.msg import ParameterDescriptor

from calib_core.errors import (
    CalibrationError, InvalidInputError, MachineAlignmentError, OutOfTravelError, RunCancelled)
from calib_core.checks import brief
from calib_core.files import load_request_yaml
from calib_core.nodes.conversions import failed_result
from calib_core.storage import read_calibration


READ_ONLY = ParameterDescriptor(read_only=True)
# rclpy's own parameters, which it reads as they change.
RCLPY_PARAMETERS = {'use_sim_time'}
# Failures that are the request's own (a malformed plan, a move outside the stroke),
# refused before the machine is trusted with it: they say nothing about the machine.
# A run the operator cancelled says nothing about the machine either.
REFUSED_REQUESTS = (InvalidInputError, OutOfTravelError, RunCancelled, TypeError,
                    yaml.YAMLError)


# The folder parameters and their defaults: calibration files, bags.
PATH_DEFAULTS = {'output_dir': 'calibration', 'record_dir': 'runs'}


def declare_paths(node, *names: str) -> None:
    """Declare the folder parameters ``names`` (``output_dir``: calibration files,
    ``record_dir``: bags) read-only, so a peer on the ROS domain cannot redirect where the
    calibration in force and the recordings are written."""
    for name in names:
        node.declare_parameter(name, PATH_DEFAULTS[name], READ_ONLY)


def described_machine(node, read_description: Callable, read_geometry: Callable,
                      built_in: Callable) -> tuple:
    """(description or None, nominal geometry) from the node's start-up parameters
    ``description`` (a machine description file: its geometry) and ``nominal_geometry`` (a
    geometry file); neither: ``built_in()``. Both given is refused."""
    path = node.get_parameter('nominal_geometry').value
    described = node.get_parameter('description').value
    if path and described:
        raise InvalidInputError('give nominal_geometry or description (it holds the '
                                'geometry), not both')
    description = read_description(described) if described else None
    return description, (description.geometry if description else
                         read_geometry(path) if path else built_in())


def set_described_parameters(node, values: dict, defaults: dict) -> None:
    """Set ``node``'s parameters to a machine description's ``values`` (name -> value),
    refusing, as two statements of one machine, any of them the launch set away from its
    declared default (``defaults``, name -> value).

    Raises
    ------
    InvalidInputError"""
    from rclpy.parameter import Parameter
    clash = [name for name in values if node.get_parameter(name).value != defaults[name]]
    if clash:
        raise InvalidInputError(f'give {", ".join(clash)} or description (it holds them), '
                                'not both')
    node.set_parameters([Parameter(name, value=value) for name, value in values.items()])


def publish_calibration_in_force(node, name: str, publisher, as_message: Callable) -> None:
    """At start-up, publish (latched) the current calibration ``name`` in the node's
    ``output_dir``, built by ``as_message(content, path)``, so a restarted calibrator
    states what is in force. A file that cannot be read is logged (calibrate again); the
    node starts anyway."""
    directory = node.get_parameter('output_dir').value
    try:
        content = read_calibration(directory, name)
        if content is None:
            return
        message = as_message(content, f'{directory}/{name}.yaml')
    except (MachineAlignmentError, OSError, KeyError, TypeError, ValueError,
            yaml.YAMLError) as exc:
        node.get_logger().error(f'the calibration {name} in {directory} is unreadable '
                                f'({exc!r}); calibrate again')
        return
    publisher.publish(message)
    node.get_logger().info(f'calibration {name} v{message.version} in force')


def call_service(client, request, what: str, timeout: float):
    """Call ``client`` and return its response.

    Raises
    ------
    CalibrationError
        The service is not there, does not answer within ``timeout`` (s), or answers
        ``success = False`` (its message is passed on)."""
    if not client.wait_for_service(timeout_sec=timeout):
        raise CalibrationError(f'{what} service {client.srv_name} is not available')
    response = client.call(request, timeout_sec=timeout)
    if response is None:
        raise CalibrationError(f'{what} service did not answer within {timeout:.0f} s')
    if not response.success:
        raise CalibrationError(f'{what} failed: {response.message}')
    return response


def check_when_set(node, plan_keys, build: Callable[[dict], object],
                   checks: dict[str, Callable] | None = None) -> None:
    """Refuse a parameter set at run time (``ros2 param set``, any peer on the domain) that
    the node would refuse at start-up or in a request, or would not use: a plan
    parameter's new value is tried by ``build`` (the node's own plan from its parameters,
    ``build(overrides)``, which raises on a bad plan), each one the node reads at every
    request by its entry in ``checks`` (name -> a function raising on a bad value); every
    other parameter of the node is read at start-up only, and a new value is refused
    (accepted, it was reported and not used). The caller gets the message, a value quoted
    short. Register after every parameter is declared."""
    from rcl_interfaces.msg import SetParametersResult
    checks = checks or {}
    at_run_time = set(plan_keys) | set(checks) | RCLPY_PARAMETERS

    def on_set(parameters):
        fixed = sorted(p.name for p in parameters if p.name not in at_run_time)
        if fixed:
            return SetParametersResult(successful=False, reason=(
                f'{", ".join(fixed)}: read when the node starts; restart it with the new '
                'value (--ros-args -p or a parameter file)'))
        overrides = {p.name: p.value for p in parameters if p.name in plan_keys}
        try:
            if overrides:
                build(overrides)
            for parameter in parameters:
                if parameter.name in checks:
                    checks[parameter.name](parameter.value)
        except (MachineAlignmentError, TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)
    node.add_on_set_parameters_callback(on_set)


def one_of(name: str, allowed) -> Callable:
    """A check for :func:`check_when_set`: the value must be one of ``allowed``."""
    def check(value):
        if value not in allowed:
            raise InvalidInputError(f'{name} must be one of {list(allowed)}, not {brief(value)}')
    return check


def positive(name: str, count: int = 1) -> Callable:
    """A check for :func:`check_when_set`: ``count`` finite positive numbers (one number
    where ``count`` is 1)."""
    def check(value):
        values = [value] if count == 1 else list(value)
        if len(values) != count or not all(isinstance(v, (int, float)) and math.isfinite(v)
                                           and v > 0 for v in values):
            raise InvalidInputError(f'{name} must be {count} finite positive number(s), not '
                                    f'{brief(value)}')
    return check


def bounded(name: str, limit: float) -> Callable:
    """A check for :func:`check_when_set`: a finite number within +-``limit``."""
    def check(value):
        if not (isinstance(value, (int, float)) and math.isfinite(value)
                and abs(value) <= limit):
            raise InvalidInputError(f'{name} must be finite and within +-{limit:g}, not '
                                    f'{brief(value)}')
    return check


def interval(name: str) -> Callable:
    """A check for :func:`check_when_set`: [low, high] with low < high, finite (m)."""
    def check(value):
        values = list(value)
        if not (len(values) == 2 and all(math.isfinite(v) for v in values)
                and values[0] < values[1]):
            raise InvalidInputError(f'{name} must be [low, high] with low < high (m), not '
                                    f'{brief(value)}')
    return check


def parse_plan(text: str) -> dict:
    """A service request's ``plan_yaml``: empty means no options, otherwise a YAML mapping.

    Raises
    ------
    InvalidInputError
        The text is YAML but not a mapping, too long, uses aliases or repeats a key
        (yaml.YAMLError for text that is not YAML)."""
    options = load_request_yaml(text) if text.strip() else {}
    if not isinstance(options, dict):
        raise InvalidInputError('plan_yaml must be a YAML mapping')
    return options


class CalibrationService:
    """Serves RunCalibration for one node: refuses a second request while one runs,
    parses ``plan_yaml`` into a mapping and hands it to ``run``, which returns the
    CalibrationResult message. A failed run is logged and answered with its reason; the
    previous calibration stays in force. ``status`` (a
    :class:`calib_core.nodes.status.CalibratorStatus`) hears how each run ended."""

    def __init__(self, node, kind: str, run: Callable[[dict], object], header: Callable,
                 busy: threading.Lock | None = None, status=None):
        self.node, self.kind, self.run, self.header = node, kind, run, header
        self.status = status
        # Services that drive the same machine share one lock.
        self._busy = busy or threading.Lock()

    def __call__(self, request, response):
        if not self._busy.acquire(blocking=False):
            response.success, response.message = False, 'a calibration is already running'
            return response
        logger = self.node.get_logger()
        refused = False     # the request itself was at fault, not the machine or the fit
        try:
            if self.status is not None:
                self.status.start_run()
            response.result = self.run(parse_plan(request.plan_yaml))
            response.success, response.message = True, 'ok'
        except (MachineAlignmentError, TypeError, ValueError, yaml.YAMLError) as exc:
            logger.error(f'{self.kind} calibration failed: {exc}; previous calibration '
                         'stays in force')
            response.success, response.message = False, str(exc)
            response.result = failed_result(self.kind, self.header(), str(exc))
            refused = isinstance(exc, REFUSED_REQUESTS)
        except Exception as exc:  # log a bug, answer, keep serving
            logger.error(f'internal error in {self.kind} calibration: {exc!r}')
            response.success, response.message = False, f'internal error: {exc!r}'
            response.result = failed_result(self.kind, self.header(), response.message)
        finally:
            self._busy.release()
        if self.status is not None:
            self.status.finished(response.success, response.message, refused)
        return response

    @property
    def busy(self) -> threading.Lock:
        return self._busy
