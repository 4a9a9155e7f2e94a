"""The demo's grid-plate step: the printer's gantry self-calibrated over two regions, and
the stage error map it found."""
from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np

from calib_core.figures import arrow_key, save_figure
from machine_alignment.demo.common import DemoRun, calibrated, graph_of
from machine_alignment.launcher import grid_graph
from printer_alignment.sim.gantry import GantryErrors

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)


def grid(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('grid-plate self-calibration of the camera gantry (a 5 x 5 mark plate over 2 '
          'regions, the simulated operator places it)')
    spec = run.noisy('grid', grid_graph(str(out / 'calibration'), str(out / 'runs'), half=2,
                                        columns=2, rows=1))
    with graph_of('grid', spec, out, domain) as graph:
        report = calibrated(graph, 'grid', 'grid_calibrator/calibrate')
    if report is None:
        return 1
    errors = np.array([[s['error_x'], s['error_y']] for s in report['sites']])
    # G's symmetric shear O is half the Y axis's turn from square (the turn of the whole
    # is each placement's): the gantry model's non-orthogonality is twice it.
    square = 2 * report['non_orthogonality_rad']
    print(f'      {len(errors)} sites in {report["stitching"]["regions"]} regions stitched '
          f'({report["stitching"]["method"]}); stage error up to '
          f'{np.abs(errors).max() * 1e6:.2f} um; non-orthogonality (twice the map\'s shear) = '
          f'{square * 1e6:.1f} urad (the simulated gantry: '
          f'{GantryErrors().model.non_orthogonality * 1e6:.1f} urad)')
    sites = np.array([[s['x'], s['y']] for s in report['sites']])
    _plot_grid_map(out / 'grid_map.png', sites, errors)
    print(f'      wrote {out}/grid_map.png')
    run.row(f'grid plate ({len(errors)} sites, {report["stitching"]["regions"]} regions)',
            f'stage error up to {np.abs(errors).max() * 1e6:.2f} um at the sites',
            f'mapped; non-orthogonality {square * 1e6:.1f} urad (simulated '
            f'{GantryErrors().model.non_orthogonality * 1e6:.1f} urad)', '', 'grid_map.png',
            run.noise_text('grid'))
    return 0


def _plot_grid_map(path: Path, sites: np.ndarray, errors: np.ndarray) -> None:
    """The stage error map the grid calibration found: an arrow per site, scale bar in um."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    arrows = ax.quiver(sites[:, 0] * 1e3, sites[:, 1] * 1e3, errors[:, 0] * 1e6,
                       errors[:, 1] * 1e6, angles='xy', color='tab:blue')
    arrow_key(ax, arrows, float(np.abs(errors).max() * 1e6 / 2), 'um')
    ax.set_xlabel('x (mm)')
    ax.set_ylabel('y (mm)')
    ax.set_aspect('equal')
    ax.margins(0.1, 0.3)                   # room for the arrows at the edges
    ax.set_title('stage error map from the grid plate (self-calibrated, 2 regions)', fontsize=10)
    fig.subplots_adjust(bottom=0.24)       # the arrow key sits below the axes
    save_figure(fig, path, [__file__])
    plt.close(fig)
