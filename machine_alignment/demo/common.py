"""What every step of the demo shares: the simulated instruments at the sources' noise
(:data:`INSTRUMENTS`), the run's folder, domain, steps and summary (:class:`DemoRun`), and
calling a calibrator's services on a running graph."""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from alignment_msgs.srv import AnalyzeResiduals, RunCalibration

from calib_core.errors import CalibrationError
from machine_alignment.cli import calibrate
from machine_alignment.launcher import Graph
from machine_alignment.live import LiveClient


@dataclass(frozen=True)
class Instrument:
    """One simulated instrument's noise in the demo: the sim node and its parameter, the
    value the source reports (SI, 1 sigma per axis), and how the summary names it."""

    module: str
    parameter: str
    source: float
    label: str
    unit: str
    per_si: float       # display units per SI unit
    note: str = ''      # where the source's figure comes from


_GANTRY = Instrument('printer_alignment.nodes.gantry_sim', 'landing_sigma', 12.5e-6 / 50,
                     'gantry landing', 'um', 1e6, 'the source: 1/50 px at 12.5 um')
# The sources' figures: the printer paper's Mark-centre accuracy and stage repeatability
# (3.3 um unidirectional), the hexapod paper's CMM (0.6 um), the five-axis paper's dot-centre
# noise (0.1 px, giving its 0.17 px reprojection); the platform paper gives none, so the
# tracker has the rebuilt simulation's 10 um (SEEDS_CDE.md, platform, PROPOSED).
INSTRUMENTS = {
    'printer': (_GANTRY,),
    'stage': (_GANTRY, Instrument('printer_alignment.nodes.stage_sim', 'landing_sigma', 1.2e-6,
                                  'stage landing per chain', 'um', 1e6,
                                  'the source: 3.3 um repeatability')),
    'hexapod': (Instrument('hexapod_calib.nodes.pose_sensor_sim', 'position_noise', 0.6e-6,
                           'pose sensor', 'um', 1e6, "the source's CMM: 0.6 um"),
                Instrument('hexapod_calib.nodes.pose_sensor_sim', 'angle_noise', 6e-6,
                           'pose sensor angles', 'urad', 1e6)),
    'grid': (_GANTRY,),
    'platform': (Instrument('platform_calib.nodes.laser_tracker_sim', 'position_noise', 10e-6,
                            'laser tracker', 'um', 1e6,
                            'no figure in the source: the rebuilt simulation\'s'),
                 Instrument('platform_calib.nodes.laser_tracker_sim', 'angle_noise', 20e-6,
                            'tracker angles', 'urad', 1e6)),
    'five_axis': (Instrument('dispenser_calib.nodes.five_axis_sim', 'noise_px', 0.1,
                             'dot centres', 'px', 1.0, 'the source: 0.1 px'),),
}
LOW_NOISE_FACTOR = 0.1      # a low-noise run's instruments against the sources'


@dataclass
class DemoRun:
    """The demo's folder and ROS domain, its numbered steps and its summary rows."""

    out: Path
    domain: str
    low_noise: bool = False
    total_steps: int = 9
    steps_done: int = 0
    rows: list = field(default_factory=list)

    def step(self, text: str) -> None:
        self.steps_done += 1
        print(f'[{self.steps_done}/{self.total_steps}] {text}', flush=True)

    def noisy(self, machine: str, spec: list) -> list:
        """``spec`` (a graph) with ``machine``'s instruments at the demo's noise."""
        values = {(i.module, i.parameter): self._noise(i) for i in INSTRUMENTS[machine]}
        return [replace(node, parameters={
            **node.parameters, **{p: v for (m, p), v in values.items() if m == node.module}})
            for node in spec]

    def _noise(self, instrument: Instrument) -> float:
        return instrument.source * (LOW_NOISE_FACTOR if self.low_noise else 1.0)

    def noise_text(self, machine: str) -> str:
        """What the summary says of ``machine``'s simulated instruments."""
        text = '; '.join(f'{i.label} {self._noise(i) * i.per_si:.3g} {i.unit}'
                         + (f' ({i.note})' if i.note else '') for i in INSTRUMENTS[machine])
        return text + (f' (low-noise run: {LOW_NOISE_FACTOR:g} x the sources\')'
                       if self.low_noise else '')

    def row(self, machine: str, before: str, after: str, paper: str, figure: str,
            noise: str) -> None:
        """One line of the closing summary; ``figure`` relative to the demo folder."""
        self.rows.append({'machine': machine, 'before': before, 'after': after,
                          'paper': paper, 'noise (1 sigma, simulated)': noise,
                          'figure': figure})

    def summary(self) -> str:
        header = ['machine', 'before', 'after', 'paper', 'noise (1 sigma, simulated)',
                  'figure']
        lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
        lines += ['| ' + ' | '.join(row[k] or '-' for k in header) + ' |' for row in self.rows]
        return '\n'.join(lines) + '\n'


def calibrate_offline(argv: list[str]) -> int:
    """``machine-align calibrate ...`` in this process (the demo replays its own bags)."""
    parser = argparse.ArgumentParser(prog='machine-align')
    calibrate.add_parser(parser.add_subparsers(dest='command', required=True))
    args = parser.parse_args(['calibrate', *argv])
    return args.func(args)


def run_service(graph, service: str, progress_topic: str, timeout: float = 600.0,
                analysis: str = '', plan: str = ''):
    """Call a RunCalibration service on a running graph, printing its progress; then, if
    the calibration succeeded and ``analysis`` names an AnalyzeResiduals service, run the
    closed loop with ``apply``. Returns (calibration response, analysis response), None
    for a call that got no answer."""
    shown = {'step': -1}

    def show(step, total, message):
        if step == total or step - shown['step'] >= max(total // 10, 1):
            shown['step'] = step
            print(f'      {step}/{total} {message}')
    with LiveClient('demo_client') as client:
        try:
            calibration = client.call(RunCalibration, service,
                                      RunCalibration.Request(plan_yaml=plan), progress_topic,
                                      show, timeout)
        except CalibrationError as exc:
            print(f'      {exc}; processes alive: {graph.alive()}')
            return None, None
        if not (analysis and calibration.success):
            return calibration, None
        print(f'      closed loop: {analysis} (apply)')
        try:
            return calibration, client.call(AnalyzeResiduals, analysis,
                                            AnalyzeResiduals.Request(apply=True), timeout=timeout)
        except CalibrationError as exc:
            print(f'      {exc}')
            return calibration, None


def loop_figure(response, out: Path) -> str:
    """The closed loop's figure (beside its report), relative to the demo folder; '' if
    the loop did not run."""
    if response is None or not response.success:
        return ''
    figure = Path(response.analysis.report_path).with_suffix('.png')
    return str(figure.relative_to(out)) if figure.is_file() else ''


def print_analysis(response) -> None:
    if response is None or not response.success:
        print(f'      closed loop failed: {response.message if response else "timeout"}')
        return
    a = response.analysis
    print(f'      closed loop added {", ".join(a.effects_added) or "nothing"}; held-out RMS '
          f'{a.rms_before * 1e6:.2f} -> {a.rms_after * 1e6:.2f} um, max {a.max_before * 1e6:.2f} '
          f'-> {a.max_after * 1e6:.2f} um; report {a.report_path}')


def calibrated(graph, name: str, service: str, plan: str = ''):
    """Call RunCalibration ``service`` on the running ``graph``: its report, or None after
    printing why it failed."""
    start = time.monotonic()
    response, _ = run_service(graph, service, f'/{service.split("/")[0]}/progress', plan=plan)
    if response is None or not response.success:
        print(f'      {name} calibration failed: {response.message if response else "timeout"}')
        return None
    print(f'      done in {time.monotonic() - start:.1f} s; file {response.result.file_path}')
    return json.loads(response.result.report_json)


def graph_of(name: str, spec, out: Path, domain: str) -> Graph:
    return Graph(spec, env={'ROS_DOMAIN_ID': domain}, log_dir=str(out / 'logs' / name))
