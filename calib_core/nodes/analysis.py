"""The ``analyze_residuals`` service every calibrator offers: run the closed loop on the
calibrator's data, write the report (JSON + PNG), publish it latched, record it to an MCAP
bag and, when asked, make the extended model the calibration in force (never one with an
effect of the run rather than the machine: a drift in time or with temperature, a step
between blocks)."""
from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Callable

import yaml
from alignment_msgs.msg import ResidualAnalysis

from calib_core.closed_loop import (
    LoopConfig, MachineModel, analyze, format_report, why_not_in_force)
from calib_core.html_report import write_html
from calib_core.errors import InvalidInputError, MachineAlignmentError
from calib_core.nodes.calibrator import parse_plan
from calib_core.nodes.qos import LATCHED
from calib_core.nodes.recording import RecordedRun, run_stamp
from calib_core.storage import write_atomic, write_calibration

LOOP_OPTIONS = ('holdout_fraction', 'alpha', 'max_effects', 'seed')


def analysis_as_message(report: dict, header, applied: bool = False,
                        report_path: str = '') -> ResidualAnalysis:
    return ResidualAnalysis(
        header=header, machine=report['machine'], base_model=report['base_model'],
        unit=report['unit'], effects_added=[e['name'] for e in report['effects_added']],
        rms_before=report['rms_before'], rms_after=report['rms_after'],
        max_before=report['max_before'], max_after=report['max_after'],
        unexplained=[f'{u["kind"]} of {u["component"]} vs {u["covariate"]}'
                     for u in report['unexplained']],
        applied=applied, report_path=report_path, report_json=json.dumps(report))


def printed_report(report: dict) -> str:
    """The general loop's report as ``machine-align analyze`` prints it; '' for a machine
    with its own loop (the grid's, per region), whose page shows its JSON."""
    rows = report.get('rows')
    if isinstance(rows, dict) and 'fitting' in rows and 'config' in report:
        return format_report(report)
    return ''


def write_extended_calibration(directory, name: str, content: dict, result,
                               model_key: str = 'loop_model') -> str:
    """Write ``content`` again as a new version of calibration ``name``, with the loop's
    added effects and its refitted base model (under ``model_key``); returns the path."""
    report = result.report
    extended = dict(content, effects=report['effects_added'])
    extended[model_key] = {'base_model': report['base_model'],
                           'parameters': report['base_parameters']['after']}
    path, _ = write_calibration(directory, name, extended)
    return str(path)


def general_loop(machine: MachineModel, config: LoopConfig, progress=None):
    """The closed loop of :mod:`calib_core.closed_loop` on ``machine``: its report, a
    function drawing its figure to a path, and the result ``apply`` takes."""
    result = analyze(machine, config, progress=progress)

    def draw(png):
        # Imported here: matplotlib costs every calibrator 0.3 s at start, and only an
        # analysis draws.
        from calib_core.loop_plots import plot_loop
        plot_loop(png, machine, result)
    return result.report, draw, result


class AnalysisService:
    """Serves AnalyzeResiduals for one calibrator.

    Parameters
    ----------
    node : rclpy Node
        Its ``output_dir`` and ``record_dir`` parameters say where reports and bags go.
    kind : str
        Name used in file names and logs (``vision``, ``hexapod``).
    lock : threading.Lock
        Shared with the calibration service: one calibration or analysis at a time.
    collect : callable (options: dict) -> data
        The data to analyse (a MachineModel for the general loop); ``options`` are the
        plan's keys other than the loop's own.
    apply : callable (result) -> str, or str
        Writes the extended model as the calibration in force and returns the file path;
        or why this machine cannot put one in force (a request to apply is refused before
        anything runs).
    topic : str
        Latched topic of the reports.
    header : callable () -> std_msgs/Header
    progress : callable (step, total, message), optional
    options : tuple of str
        The plan keys ``collect`` takes besides the loop's; any other key is refused before
        anything runs.
    loop : callable (data, LoopConfig, progress) -> (report, draw, result)
        The loop a machine runs (:func:`general_loop` unless it has its own); ``report``
        has the keys :func:`analysis_as_message` reads, ``draw(png_path)`` writes the
        figure, ``result`` is what ``apply`` takes.
    status : calib_core.nodes.status.CalibratorStatus, optional
        Hears each report published (the loop's verdict on the node's diagnostics); its
        cancel is reset as each analysis starts.
    """

    def __init__(self, node, kind: str, lock: threading.Lock,
                 collect: Callable[[dict], MachineModel],
                 apply: Callable[[object], str] | str,
                 topic: str, header: Callable, progress: Callable | None = None,
                 options: tuple = (), loop: Callable = general_loop, status=None):
        self.node, self.kind, self.lock, self.header = node, kind, lock, header
        self.collect, self.apply, self.topic, self.progress = collect, apply, topic, progress
        self.options, self.loop = tuple(options), loop
        self.publisher = node.create_publisher(ResidualAnalysis, topic, LATCHED)
        self.status = status
        if status is not None:
            self.publisher = status.tap(self.publisher, 'analysis')

    def __call__(self, request, response):
        if not self.lock.acquire(blocking=False):
            response.success, response.message = False, 'a calibration or analysis is running'
            return response
        logger = self.node.get_logger()
        try:
            if self.status is not None:
                self.status.start_run()
            if request.apply and isinstance(self.apply, str):
                raise InvalidInputError(f'apply refused: {self.apply}; call again without '
                                        'apply for the report')
            options = parse_plan(request.plan_yaml)
            config = LoopConfig(**{k: options.pop(k) for k in LOOP_OPTIONS if k in options})
            unknown = set(options) - set(self.options)
            if unknown:
                raise InvalidInputError(f'unknown analysis options {sorted(unknown)}; known: '
                                        f'{list(self.options) + list(LOOP_OPTIONS)}')
            report, draw, result = self.loop(self.collect(options), config, self.progress)
            refused = why_not_in_force(report['effects_added']) if request.apply else ''
            if refused:
                report = dict(report, not_applied=refused)
            response.analysis = self._publish(report, draw, result,
                                              request.apply and not refused)
            response.success = True
            response.message = (f'added {", ".join(response.analysis.effects_added) or "nothing"}; '
                                f'held-out RMS {report["rms_before"]:.4g} -> '
                                f'{report["rms_after"]:.4g} {report["unit"]}'
                                + (f'; {report["not_applied"]}' if 'not_applied' in report
                                   else ''))
            logger.info(f'{self.kind} analysis: {response.message}')
        except (MachineAlignmentError, TypeError, ValueError, yaml.YAMLError) as exc:
            logger.error(f'{self.kind} analysis failed: {exc}')
            response.success, response.message = False, str(exc)
        except Exception as exc:  # log a bug, answer, keep serving
            logger.error(f'internal error in {self.kind} analysis: {exc!r}')
            response.success, response.message = False, f'internal error: {exc!r}'
        finally:
            self.lock.release()
        return response

    def _publish(self, report: dict, draw: Callable, result, apply: bool) -> ResidualAnalysis:
        stamp = run_stamp()
        report = dict(report, created=stamp)
        applied_to = ''
        if apply and report['effects_added']:
            applied_to = self.apply(result)
            report['applied_to'] = applied_to
        path = Path(self.node.get_parameter('output_dir').value) / 'analysis' / \
            f'{self.kind}_{stamp}.json'
        write_atomic(path, json.dumps(report, indent=2) + '\n')
        draw(path.with_suffix('.png'))
        write_html(path.with_suffix('.html'), report, f'{self.kind} closed-loop analysis',
                   [path.with_suffix('.png')], printed_report(report))
        message = analysis_as_message(report, self.header(), bool(applied_to), str(path))
        with RecordedRun(self.node, f'{self.kind}_analysis',
                         {self.topic: 'alignment_msgs/msg/ResidualAnalysis'}) as run:
            run.record(self.topic, message, self.publisher)
        return message
