"""A whole travel calibrated region by region: each region self-calibrated from its three
placements, the regions stitched into one frame, the isotropic scale taken from a
certified plate pitch when one is given. This is what the CLI and the node run."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.sanity import SanityGate
from grid_calib.core.model import Grid, linear_parts
from grid_calib.core.selfcal import self_calibrate
from grid_calib.core.stitching import StitchedMap, stitch, stitched_draws
from grid_calib.errors import PlacementError

UNDETERMINED_SCALE = ('undetermined: no external length given (a certified plate pitch); '
                      'G carries no isotropic scale')


@dataclass
class TravelCalibration:
    """Every region's solution and the stitched stage error (SI units)."""

    grid: Grid
    origins: dict                     # region -> (m0, n0) site indices of its centre
    results: dict                     # region -> SelfCalibration
    stitched: StitchedMap
    isotropic_scale: float | None     # of the stage, 1; None if undetermined

    @property
    def plate_errors(self) -> np.ndarray:
        """The plate's mark errors A (N^2, 2) m, averaged over the regions (each region
        measures the same plate, in the same gauge)."""
        return np.mean([r.mark_errors for r in self.results.values()], axis=0)

    def gauge(self) -> dict:
        return {'translation': 'G over all sites has zero mean: a stage offset is the '
                               'plate\'s position',
                'rotation': 'G has no net rotation over all sites: a turned stage frame is '
                            'a turned plate',
                'isotropic_scale': (UNDETERMINED_SCALE if self.isotropic_scale is None else
                                    'from the certified plate pitch'),
                'plate': 'the plate errors have zero mean and no net rotation (the '
                         'placements\' misalignments hold those)',
                'regions': 'each region\'s shift, rotation and scale are fixed by its '
                           'overlaps with the others (stitching)'}

    def report(self) -> dict:
        """The JSON report: sites in the stitched frame, the gauge, the plate errors,
        per-region misalignments, uncertainties and residuals (m, rad)."""
        stitched = self.stitched
        whole = linear_parts(stitched.site_positions, stitched.stage_error)
        regions = {}
        for r, result in self.results.items():
            one = result.report()
            offset = np.asarray(self.origins[r]) * self.grid.pitch
            for row in one['uncertainty_m'] or []:
                row['x'] += float(offset[0])
                row['y'] += float(offset[1])
            del one['sites'], one['gauge']
            one['origin_m'] = [float(offset[0]), float(offset[1])]
            one['residual_max_m'] = {k: float(np.abs(v).max())
                                     for k, v in result.residuals.items()}
            regions[str(r)] = one
        sigma = (stitched.uncertainty if stitched.uncertainty is not None
                 else np.full_like(stitched.stage_error, np.nan))
        draws = stitched.uncertainty_draws if stitched.uncertainty is not None else 0
        return {'sites': [{'x': float(x), 'y': float(y), 'error_x': float(gx),
                           'error_y': float(gy), 'sigma_x': float(sx), 'sigma_y': float(sy)}
                          for (x, y), (gx, gy), (sx, sy) in zip(
                              stitched.site_positions, stitched.stage_error, sigma)],
                'uncertainty': (
                    f'sigma_x, sigma_y: 1-sigma of G per site (m) from the measurement noise '
                    f'each region\'s residuals show, {draws} draws through each region\'s '
                    f'solve and the stitching (each sigma to +-{100 / np.sqrt(2 * draws):.1f} '
                    f'%), in the travel\'s gauge'
                    + ('; the certified scale\'s own uncertainty is not included'
                       if self.isotropic_scale is not None else '')) if draws else
                    'not propagated',
                'gauge': self.gauge(),
                'isotropic_scale': self.isotropic_scale,
                'non_orthogonality_rad': float(whole['non_orthogonality']),
                'scale_difference': float(whole['scale_difference']),
                'stitching': {'method': stitched.method, 'regions': len(self.results),
                              'overlap_rms_m': stitched.overlap_rms,
                              'similarities': {str(r): dict(zip(
                                  ('shift_x_m', 'shift_y_m', 'angle_rad', 'scale'),
                                  map(float, s))) for r, s in stitched.similarities.items()}},
                'plate_errors': [{'i': int(i), 'j': int(j), 'error_x': float(ax),
                                  'error_y': float(ay)}
                                 for (i, j), (ax, ay) in zip(self.grid.marks, self.plate_errors)],
                'regions': regions}


MAX_DRAWN_VALUES = 5_000_000   # draws x stitched sites carried through the stitching
MIN_STITCHED_DRAWS = 32         # each stitched sigma to 1 / sqrt(64) = 12.5 % at the least


def calibrate_travel(grid: Grid, regions: dict, method: str = 'joint',
                     certified_pitch: float | None = None,
                     description=None) -> TravelCalibration:
    """Self-calibrate every region (region -> ``data.Region``) and stitch them.

    ``certified_pitch`` (m): the plate's calibrated mean pitch. The data show the sum of
    the stage's and the plate's isotropic scales (the plate's errors carry it, G is held at
    none); a known plate scale leaves the stage's.

    Raises
    ------
    PlacementError
        Bad placements in a region, regions that do not overlap, a certified pitch that is
        not a length near the nominal one.
    """
    if certified_pitch is not None and not (np.isfinite(certified_pitch)
                                            and abs(certified_pitch / grid.pitch - 1) < 1e-3):
        raise PlacementError(f'certified pitch {certified_pitch!r} m is not within 0.1 % of '
                             f'the nominal {grid.pitch} m')
    # Each region draws its own noise (the draws behind the stitched uncertainty).
    results = {r: self_calibrate(grid, region.placements, draw_seed=k)
               for k, (r, region) in enumerate(regions.items())}
    origins = {r: region.origin for r, region in regions.items()}
    placed = {r: (origins[r], results[r]) for r in results}
    stitched = stitch(placed, grid.pitch, method)
    # Each region's noise (its own sigma, drawn independently of the others') through the
    # stitching: the stitched map's per-site uncertainty.
    # Draws x sites bounded (memory: the stitching holds a few such arrays at once).
    count = int(np.clip(MAX_DRAWN_VALUES // len(stitched.sites),
                        MIN_STITCHED_DRAWS, len(next(iter(results.values())).noise_draws)))
    draws = stitched_draws(placed, grid.pitch, method,
                           {r: res.noise_draws[:count] * res.noise for r, res in results.items()})
    stitched.uncertainty, stitched.uncertainty_draws = draws.std(axis=0), count
    scale = None
    if certified_pitch is not None:
        plate_scale = certified_pitch / grid.pitch - 1
        marks = grid.marks * grid.pitch
        where = {tuple(s): k for k, s in enumerate(stitched.sites)}
        estimates = []
        for r, result in results.items():
            seen = linear_parts(marks, result.mark_errors)['scale']
            rows = [where[tuple(s)] for s in result.sites + origins[r]]
            here = linear_parts(stitched.site_positions[rows], stitched.stage_error[rows])['scale']
            estimates.append(seen - plate_scale - here)
        scale = float(np.mean(estimates))
        stitched.stage_error = stitched.stage_error + scale * stitched.site_positions
    calibration = TravelCalibration(grid, origins, results, stitched, scale)
    check_travel_calibration(calibration, description)
    return calibration


# The sanity gate's bounds: a camera reads a mark to a few tenths of a um, a stage errs
# by tens of um over its travel (1 mm is a wrong pitch, unit or plate); stitched regions
# agree at their shared sites to about the readings' noise.
MAX_READING_RESIDUAL_RMS_M = 2e-6
MAX_STAGE_ERROR_M = 1e-3
MAX_OVERLAP_RMS_M = 20e-6


def check_travel_calibration(calibration: TravelCalibration, description=None) -> None:
    """Refuse a grid calibration that cannot be the stage before it is written or put in
    force: a placement's readings fitted worse than :data:`MAX_READING_RESIDUAL_RMS_M`
    RMS (with a ``description``, :class:`grid_calib.core.description.GridDescription`, a
    region's reading noise estimated from its residuals above the limit from the declared
    noise), a stage error beyond :data:`MAX_STAGE_ERROR_M`, regions disagreeing at shared
    sites by more than :data:`MAX_OVERLAP_RMS_M`, or anything not finite.

    Raises
    ------
    CalibrationError
        Every failure named."""
    gate = SanityGate('the grid calibration')
    if description is None:
        # The worst placement speaks for all: one line, however many regions.
        rms = {(r, placement): float(np.sqrt(np.mean(np.square(residual))))
               for r, result in calibration.results.items()
               for placement, residual in result.residuals.items()}
        worst = max(rms, key=lambda k: rms[k] if np.isfinite(rms[k]) else np.inf)
        gate.residual(rms[worst] * 1e6, MAX_READING_RESIDUAL_RMS_M * 1e6, 'um',
                      f'region {worst[0]}, {worst[1]}, the worst of {len(rms)} placements: a '
                      'camera reads the marks to a few tenths of a um')
    else:
        # Against the declared noise, the noise each region's residuals show with their
        # degrees of freedom counted (a fit of a value per site and per mark leaves about
        # half the readings' scatter in the residuals).
        noise = {r: result.noise for r, result in calibration.results.items()}
        worst = max(noise, key=lambda r: noise[r] if np.isfinite(noise[r]) else np.inf)
        gate.within(f'region {worst}\'s reading noise from its residuals (the worst of '
                    f'{len(noise)} regions)', noise[worst] * 1e9, 0.0,
                    description.residual_limit() * 1e9, 'nm',
                    f'{description.expected_text()}: {description.causes()}')
    error = calibration.stitched.stage_error
    largest = float(np.abs(error).max()) if np.all(np.isfinite(error)) else float('nan')
    gate.within('largest stage error', largest, 0.0, MAX_STAGE_ERROR_M, 'm',
                'a stage errs by tens of um over its travel')
    overlap = calibration.stitched.overlap_rms
    if overlap is not None:
        gate.within('regions\' disagreement at shared sites (RMS)', overlap, 0.0,
                    MAX_OVERLAP_RMS_M, 'm', 'stitched regions agree to the readings\' noise')
    gate.enforce()


def grid_result_content(calibration: TravelCalibration) -> dict:
    """What a grid calibration file holds: the stage error map (site indices, G in m, the
    pitch) that ``compensation.StageErrorMap`` is built from, and the full report."""
    stitched = calibration.stitched
    return {'pitch': calibration.grid.pitch,
            'sites': stitched.sites.astype(int).tolist(),
            'stage_error': stitched.stage_error.tolist(),
            'report': calibration.report()}
