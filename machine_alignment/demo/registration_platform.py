"""The demo's platform step: identification by the laser tracker, one registration,
and the held-out poses before and after."""
from __future__ import annotations

import json
from pathlib import Path

import matplotlib
import numpy as np
from alignment_msgs.srv import RegisterScreen

from calib_core.bags import decode_bag
from calib_core.figures import save_figure
from machine_alignment.demo.common import DemoRun, calibrated, graph_of
from machine_alignment.launcher import platform_graph
from machine_alignment.live import LiveClient
from platform_calib.core.compensation import composite_error
from platform_calib.core.records import MEASUREMENTS_TOPIC as PLATFORM_MEASUREMENTS
from platform_calib.core.records import stop_from_message

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)


def registration_platform(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('the screen-registration platform: identification by the laser tracker, then '
          'registration of a screen')
    spec = run.noisy('platform', platform_graph(str(out / 'calibration'), str(out / 'runs')))
    with graph_of('platform', spec, out, domain) as graph:
        report = calibrated(graph, 'platform', 'platform_calibrator/calibrate', '{poses: 20}')
        if report is None:
            return 1
        evaluation = report['evaluation']
        print(f'      held-out poses, median error: nominal '
              f'{evaluation["evaluate_nominal"]["median_m"] * 1e6:.1f} um, calibrated '
              f'{evaluation["evaluate_calibrated"]["median_m"] * 1e6:.1f} um')
        with LiveClient('demo_platform_client') as client:
            answer = client.call(RegisterScreen, 'platform_calibrator/register',
                                 RegisterScreen.Request(method='exact'), timeout=120.0)
    if not answer.success:
        print(f'      registration failed: {answer.message}')
        return 1
    before = json.loads(answer.report_json)['error_before_m']
    print(f'      registered (exact compensation): marks off by {before * 1e3:.3f} mm before, '
          f'{answer.measured_error * 1e6:.2f} um after the move')
    _plot_platform_evaluation(out / 'platform_evaluation.png', out / 'runs')
    print(f'      wrote {out}/platform_evaluation.png')
    run.row(f'screen-registration platform ({evaluation["evaluate_calibrated"]["poses"]} '
            'held-out poses, tracker-measured; one registration)',
            f'median {evaluation["evaluate_nominal"]["median_m"] * 1e6:.1f} um (nominal model); '
            f'screen placed {before * 1e3:.2f} mm off',
            f'median {evaluation["evaluate_calibrated"]["median_m"] * 1e6:.1f} um; marks '
            f'{answer.measured_error * 1e6:.1f} um off after the move',
            '0.21-1.96 mm -> about 0.10 mm', 'platform_evaluation.png',
            run.noise_text('platform'))
    return 0


def _plot_platform_evaluation(path: Path, runs: Path) -> None:
    """Each held-out pose's composite mark error, measured by the tracker, with the nominal
    and the calibrated commands (from the run's bag), on one scale."""
    bag = next(b for b in sorted(runs.glob('platform_*')) if 'analysis' not in b.name)
    stops = [stop_from_message(msg) for topic, _, msg in decode_bag(bag)
             if topic == PLATFORM_MEASUREMENTS]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for phase, colour, label in (('evaluate_nominal', 'tab:red', 'nominal geometry'),
                                 ('evaluate_calibrated', 'tab:blue', 'identified geometry')):
        rows = [s for s in stops if s.phase == phase]
        errors = composite_error(np.array([s.measured for s in rows]),
                                 np.array([s.target for s in rows])) * 1e6
        ax.semilogy(np.arange(1, len(errors) + 1), errors, 'o', color=colour,
                    label=f'{label}: median {np.median(errors):.1f} um')
    ax.set_xlabel('held-out pose')
    ax.set_ylabel("composite mark error |AA'| + |BB'| (um, log)")
    ax.set_title('platform: held-out poses measured by the laser tracker', fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which='both')
    fig.tight_layout()
    save_figure(fig, path, [__file__])
    plt.close(fig)
