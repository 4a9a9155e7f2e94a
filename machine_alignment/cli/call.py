"""``machine-align call SERVICE [YAML]``: trigger a calibration, the closed loop or an
alignment on a running graph from the venv, with progress while it runs, and print the
result as the offline subcommands do. The same as ``ros2 service call`` on a ROS install."""
from __future__ import annotations

import json

import numpy as np

from alignment_msgs.srv import (
    Align, AnalyzeResiduals, LocateWorkpiece, MeasureNeedle, RegisterScreen, RunCalibration)
from std_srvs.srv import Trigger

from calib_core.controller_formats import write_gcode_path
from calib_core.errors import CalibrationError, InvalidInputError
from dispenser_calib.core.part_files import write_path_poses
from calib_core.nodes.services import OPERATOR_SERVICES
from machine_alignment.cli import command_help
from machine_alignment.cli.common import progress, quantity, ranged, write_json
from machine_alignment.live import LiveClient

_TYPES = {kind.__name__: kind for kind in (Align, AnalyzeResiduals, LocateWorkpiece,
                                           MeasureNeedle, RegisterScreen, RunCalibration,
                                           Trigger)}
# service -> (type, progress topic, what the YAML argument is)
SERVICES = {name: (_TYPES[kind], topic, argument)
            for name, (kind, topic, argument) in OPERATOR_SERVICES.items()}


def alignment_line(position_error: float, orientation_error: float) -> str:
    """What is left after an alignment, for people: ``position_error`` (m) in um and
    ``orientation_error`` (rad) in arcsec."""
    return (f'aligned: {position_error * 1e6:.2f} um, '
            f'{np.degrees(orientation_error) * 3600:.2f} arcsec left (measured by the camera)')


def _request(service_type, text: str, apply: bool):
    if service_type is RunCalibration:
        return RunCalibration.Request(plan_yaml=text)
    if service_type is AnalyzeResiduals:
        return AnalyzeResiduals.Request(plan_yaml=text, apply=apply)
    if service_type is Trigger:
        return Trigger.Request()
    if service_type is RegisterScreen:
        return RegisterScreen.Request(method=text.strip())
    if service_type in (MeasureNeedle, LocateWorkpiece):
        return service_type.Request(plan_yaml=text)
    return Align.Request(model=text.strip())


def _print_calibration(result) -> dict:
    print(f'{result.kind} calibration, version {result.version}: {result.file_path}')
    print(f'  {result.num_observations} observations, residual RMS {result.rms_residual:.4g} '
          f'{result.residual_unit}, max {result.max_residual:.4g} {result.residual_unit}')
    for name, value, sigma, unit in zip(result.names, result.values, result.std_devs,
                                        result.units):
        print(f'  {name:>18} = {quantity(value, sigma, unit)}')
    return json.loads(result.report_json) if result.report_json else {}


def _print_analysis(analysis) -> dict:
    print(f'closed loop on the {analysis.machine}: added '
          f'{", ".join(analysis.effects_added) or "nothing"}; held-out RMS '
          f'{analysis.rms_before:.4g} -> {analysis.rms_after:.4g} {analysis.unit}, max '
          f'{analysis.max_before:.4g} -> {analysis.max_after:.4g} {analysis.unit}'
          + ('; applied' if analysis.applied else ''))
    for item in analysis.unexplained:
        print(f'  unexplained: {item}')
    print(f'  report: {analysis.report_path}')
    return json.loads(analysis.report_json) if analysis.report_json else {}


def _write_path(args, poses) -> None:
    """The located part's path poses (k, 5) as the labelled CSV and the G-code asked for."""
    names = [f'p{k}' for k in range(len(poses))]
    if args.csv:
        write_path_poses(args.csv, names, poses)
        print(f'wrote {args.csv} (point, x_m, y_m, z_m, a_rad, c_rad)')
    if args.gcode:
        write_gcode_path(args.gcode, poses, 'XYZAC', 'mm', args.feed,
                         f'dispensing path, {len(poses)} points')
        print(f'wrote {args.gcode} (RS274/NGC, mm, A and C in degrees)')


def cmd_call(args) -> int:
    service_type, progress_topic, _ = SERVICES[args.service]
    if (args.csv or args.gcode) and service_type is not LocateWorkpiece:
        raise InvalidInputError('--csv and --gcode write a located part\'s path poses: '
                                'five_axis_calibrator/locate only')
    request = _request(service_type, args.yaml, args.apply)
    shown = {'step': -1}

    def show(step, total, message):
        progress(step, total, args.service)
        if not args.quiet and (step == total or step - shown['step'] >= max(total // 10, 1)):
            shown['step'] = step
            print(f'  {step}/{total} {message}', flush=True)
    # Ctrl-C cancels a run that moves the machine: the node's cancel stops it safely.
    node = args.service.split('/')[0]
    cancel = (f'{node}/cancel' if f'{node}/cancel' in SERVICES and service_type is not Trigger
              else None)
    with LiveClient('machine_align_call', args.domain) as client:
        response = client.call(service_type, args.service, request, progress_topic, show,
                               timeout=args.timeout, cancel=cancel)
    if not response.success:
        raise CalibrationError(f'{args.service}: {response.message}')
    if service_type is RunCalibration:
        report = _print_calibration(response.result)
    elif service_type is AnalyzeResiduals:
        report = _print_analysis(response.analysis)
    elif service_type is Trigger:
        print(response.message)
        return 0
    elif service_type is MeasureNeedle:
        print(f'needle tip {", ".join(f"{v * 1e3:.4f}" for v in response.tip)} mm (calibrated '
              f'camera frame); one dot alone within {response.spread * 1e6:.1f} um')
        report = json.loads(response.report_json)
    elif service_type is LocateWorkpiece:
        print(f'part at {", ".join(f"{v * 1e3:.4f}" for v in response.pose[:3])} mm, rotation '
              f'vector {", ".join(f"{v:.5f}" for v in response.pose[3:])} rad; '
              f'{len(response.path_poses) // 5} path poses')
        report = json.loads(response.report_json)
        _write_path(args, np.reshape(response.path_poses, (-1, 5)))
    elif service_type is RegisterScreen:
        report = json.loads(response.report_json)
        print(f'registered: marks off by {report["error_before_m"] * 1e3:.3f} mm before, '
              f'{response.measured_error * 1e6:.2f} um after the move (composite, measured; '
              f'the model predicted {response.predicted_error * 1e6:.3f} um: its own view)')
    else:
        print(alignment_line(response.position_error, response.orientation_error))
        report = json.loads(response.report_json)
    write_json(args.json, report)
    return 0


def add_parser(sub) -> None:
    call = sub.add_parser('call', help=command_help('call'))
    call.add_argument('service', choices=sorted(SERVICES), metavar='SERVICE',
                      help='one of: ' + ', '.join(sorted(SERVICES)))
    call.add_argument('yaml', nargs='?', default='',
                      help='calibrate: plan overrides (YAML mapping, e.g. "{nx: 3, ny: 2}"); '
                           'analyze_residuals: options; align: the model name; register: '
                           'the method (exact, lm, pso)')
    call.add_argument('--apply', action='store_true',
                      help='analyze_residuals: make the extended model the calibration in force')
    call.add_argument('--domain', type=ranged(int, 0, 232), default=None,
                      help='ROS domain of the graph (default: ROS_DOMAIN_ID, else 0)')
    call.add_argument('--timeout', type=ranged(float, 0.1, 86400.0, 's'), default=900.0, help='s')
    call.add_argument('--quiet', action='store_true', help='no progress lines')
    call.add_argument('--json', help='the full report to write')
    call.add_argument('--csv', help='locate: the path poses as a labelled CSV (point, x_m, '
                                    'y_m, z_m, a_rad, c_rad)')
    call.add_argument('--gcode', help='locate: the path poses as G-code (RS274/NGC, mm, '
                                      'degrees)')
    call.add_argument('--feed', type=ranged(float, 1e-6, 1e6, 'mm/min'), default=300.0,
                      help='locate: the G-code\'s feed (mm/min, default 300)')
    call.set_defaults(func=cmd_call)
