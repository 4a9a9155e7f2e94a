"""``machine-align calibrate grid``: self-calibration of a 2-D stage's measuring system
with an imperfect grid plate at three placements (one region; stitching of several
regions is not built yet)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_core.errors import MachineAlignmentError  # noqa: E402
from calib_core.figures import arrow_key  # noqa: E402
from grid_calib.core.data import read_marks  # noqa: E402
from grid_calib.core.selfcal import self_calibrate  # noqa: E402
from machine_alignment.cli.common import write_json  # noqa: E402


def _plot(path: Path, result) -> None:
    """Stage error and plate error vectors (one scale each, with a key), residuals per
    placement."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    xy = result.site_positions * 1e3
    marks = result.grid.marks * result.grid.pitch * 1e3
    for ax, where, vectors, title in ((axes[0], xy, result.stage_error, 'stage error G'),
                                      (axes[1], marks, result.mark_errors, 'plate mark errors A')):
        um = vectors * 1e6
        longest = max(np.linalg.norm(um, axis=1).max(), 1e-9)
        arrows = ax.quiver(where[:, 0], where[:, 1], um[:, 0], um[:, 1], angles='xy',
                           scale_units='xy', scale=longest / (0.8 * result.grid.pitch * 1e3))
        arrow_key(ax, arrows, longest / 2, 'um')
        ax.set_title(f'{title} (longest {longest:.3g} um)', loc='left', fontsize=10)
        ax.set_xlabel('x (mm)')
        ax.set_ylabel('y (mm)')
        ax.set_aspect('equal')
    for name, residual in result.residuals.items():
        axes[2].hist(np.linalg.norm(residual, axis=1) * 1e9, bins=30, alpha=0.6, label=name)
    axes[2].set_xlabel('residual per mark (nm)')
    axes[2].set_ylabel('marks')
    axes[2].legend(title='placement')
    fig.tight_layout(rect=(0, 0.06, 1, 1))     # room for the arrow keys below the axes
    fig.savefig(path, dpi=90)
    plt.close(fig)


def cmd_calibrate_grid(args) -> int:
    grid, regions = read_marks(args.data, args.pitch)
    if len(regions) != 1:
        raise MachineAlignmentError(f'{args.data} holds {len(regions)} regions; stitching '
                                    'regions is not built yet: give one region at a time')
    result = self_calibrate(grid, next(iter(regions.values())))
    report = result.report()
    print(f'{len(result.sites)} sites ({2 * grid.half + 1} x {2 * grid.half + 1} plate, '
          f'pitch {grid.pitch * 1e3:g} mm): non-orthogonality {result.non_orthogonality * 1e6:.3f} '
          f'urad, x/y scale difference {result.scale_difference * 1e6:.3f} ppm')
    print(f'  stage error G: RMS {np.sqrt(np.mean(result.stage_error ** 2)) * 1e6:.3f} um, '
          f'max {np.abs(result.stage_error).max() * 1e6:.3f} um; plate errors A: RMS '
          f'{np.sqrt(np.mean(result.mark_errors ** 2)) * 1e6:.3f} um')
    for name, rms in report['residual_rms_m'].items():
        print(f'  residual {name}: RMS {rms * 1e9:.2f} nm')
    print(f'  measurement noise from the residuals: {result.noise * 1e9:.2f} nm; '
          + ('uncertainty of G per site not propagated (grid too large)'
             if result.uncertainty is None else
             f'uncertainty of G per site (1 sigma): up to {result.uncertainty.max() * 1e9:.2f} nm'))
    print('  isotropic scale: undetermined without an external length (0 in G)')
    report['plate_errors'] = [{'i': int(i), 'j': int(j), 'error_x': float(ax),
                               'error_y': float(ay)}
                              for (i, j), (ax, ay) in zip(grid.marks, result.mark_errors)]
    if args.json:
        write_json(args.json, report)
        plot = Path(args.json).with_suffix('.png')
        _plot(plot, result)
        print(f'wrote {plot}')
    return 0


def add_parser(what) -> None:
    grid = what.add_parser('grid', help='2-D stage error from an imperfect grid plate at '
                                        'three placements')
    grid.add_argument('--data', required=True,
                      help='CSV: region, placement (initial / rotated / shifted), i, j '
                           '(centred mark indices), x, y (stage reading, m)')
    grid.add_argument('--pitch', type=float, required=True, help='nominal plate pitch, m')
    grid.add_argument('--json', help='report to write (JSON, SI units); the plot goes beside it')
    grid.set_defaults(func=cmd_calibrate_grid)
