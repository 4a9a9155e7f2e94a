"""The figure of the grid loop (:func:`grid_calib.core.residual_loop.analyze_travel`): per
region, each reading's residual (the norm of its x and y, nm) against the run's covariates
(reading order, and time and temperature where logged), before and after the effects
added, on one scale."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

SHOWN_REGIONS = 4
AXES = {'sequence': 'reading number', 'time': 'time since the first reading (s)',
        'temperature': 'temperature - mean (K)'}


def plot_grid_loop(path: Path, report: dict, details: dict) -> None:
    """Write the figure to ``path`` (PNG). ``details``: region -> the detail
    :func:`analyze_region` fills; at most :data:`SHOWN_REGIONS` regions are drawn."""
    regions = list(details)[:SHOWN_REGIONS]
    kinds = [k for k in AXES if any(k in details[r]['covariates'] for r in regions)]
    figure, axes = plt.subplots(len(regions), len(kinds), squeeze=False,
                                figsize=(4.2 * len(kinds), 2.8 * len(regions) + 0.6))
    top = max(float(np.linalg.norm(details[r]['residuals_before'], axis=1).max())
              for r in regions) * 1e9 * 1.05
    for row, region in enumerate(regions):
        detail = details[region]
        names = [e['name'] for e in report['regions'][region]['effects']] or ['nothing']
        for col, kind in enumerate(kinds):
            ax = axes[row, col]
            values = detail['covariates'].get(kind)
            if values is None:
                ax.set_axis_off()
                continue
            x = values - (values.min() if kind != 'temperature' else values.mean())
            for when, colour in (('before', '0.6'), ('after', 'tab:blue')):
                size = np.linalg.norm(detail[f'residuals_{when}'], axis=1) * 1e9
                ax.plot(x, size, '.', ms=3, color=colour,
                        label=f'{when} ({np.sqrt(np.mean(size ** 2)):.3g} nm RMS)')
            ax.set_ylim(0, top)
            ax.set_xlabel(AXES[kind])
            ax.set_ylabel('fit residual, |x, y| (nm)')
            ax.set_title(f'region {region}: added {", ".join(names)}', fontsize=9)
            ax.legend(fontsize=7, loc='upper right')
    figure.suptitle(f'grid loop: held-out (leave-one-out) RMS {report["rms_before"] * 1e9:.3g} '
                    f'-> {report["rms_after"] * 1e9:.3g} nm', fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
