"""Checking a grid self-calibration against an independent map of the same stage error:
a laser interferometer's or a certified plate's, or a simulation's truth. Both maps are
compared in one gauge over the sites they share: the translation, rotation and (unless
the self-calibration had a certified pitch) isotropic scale that a self-calibration cannot
see are taken out of each over those sites, so only what the method claims is compared.

The reference CSV (a contract): ``x, y, error_x, error_y`` (m; the site's position in the
travel frame and the stage error G = reading - true position there)."""
from __future__ import annotations

import numpy as np

from calib_core.checks import MAX_POSITION_M
from calib_core.errors import InvalidInputError
from calib_core.files import read_csv_rows
from calib_core.schema import Column, Schema
from calib_core.storage import write_atomic
from grid_calib.core.model import without_similarity

COLUMNS = ('x', 'y', 'error_x', 'error_y')
MAX_STAGE_ERROR_M = 1e-3
SCHEMA = Schema((
    Column('x', 'm', -MAX_POSITION_M, MAX_POSITION_M, 'site position x'),
    Column('y', 'm', -MAX_POSITION_M, MAX_POSITION_M, 'site position y'),
    Column('error_x', 'm', -MAX_STAGE_ERROR_M, MAX_STAGE_ERROR_M, 'stage error x'),
    Column('error_y', 'm', -MAX_STAGE_ERROR_M, MAX_STAGE_ERROR_M, 'stage error y')))
SAME_SITE = 1e-3        # of the pitch: positions this close are one site


def write_reference(path, positions: np.ndarray, errors: np.ndarray,
                    sigmas: np.ndarray | None = None) -> None:
    """A stage error map as CSV: positions (k, 2) m, the stage error there (k, 2) m and,
    when given, its 1-sigma (k, 2) m (columns ``sigma_x``, ``sigma_y``). The same file
    is the reference ``evaluate grid`` reads and the table a controller's 2-D compensation
    loads (subtract the error at the reading: the true position)."""
    columns = list(COLUMNS) + (['sigma_x', 'sigma_y'] if sigmas is not None else [])
    values = np.column_stack([positions, errors] + ([sigmas] if sigmas is not None else []))
    lines = [','.join(columns)] + [','.join(f'{v:.12g}' for v in row) for row in values]
    write_atomic(path, '\n'.join(lines) + '\n')


def read_reference(path) -> tuple[np.ndarray, np.ndarray]:
    """(positions (k, 2) m, stage errors (k, 2) m) of a reference CSV.

    Raises
    ------
    InvalidInputError
        Unreadable, missing columns, not numbers, mm for m."""
    rows = read_csv_rows(path, 'a reference map CSV (x, y, error_x, error_y in m)', COLUMNS)
    try:
        values = {c: np.array([float(r[c]) for r in rows]) for c in COLUMNS}
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f'{path}: x, y, error_x, error_y must be numbers ({exc})') from None
    SCHEMA.check(values, str(path))
    return (np.column_stack([values['x'], values['y']]),
            np.column_stack([values['error_x'], values['error_y']]))


def compare(positions: np.ndarray, errors: np.ndarray, sigmas: np.ndarray | None,
            reference_positions: np.ndarray, reference_errors: np.ndarray, pitch: float,
            keep_scale: bool = False) -> dict:
    """The self-calibration's map (positions, errors (s, 2) m, 1-sigma (s, 2) m or None)
    against a reference at the sites both have, in one gauge (module docstring): the
    difference's RMS and max per site (m), the stage error itself there (what a machine
    without the map shows), and with sigmas the differences in sigma (their RMS is 1 when
    the stated uncertainty is right and the reference exact).

    Raises
    ------
    InvalidInputError
        Fewer than 3 shared sites (no gauge can be taken out)."""
    key = np.round(np.asarray(positions) / (SAME_SITE * pitch)).astype(np.int64)
    reference_key = np.round(np.asarray(reference_positions) / (SAME_SITE * pitch)).astype(np.int64)
    where = {tuple(k): i for i, k in enumerate(reference_key)}
    mine = [i for i, k in enumerate(key) if tuple(k) in where]
    theirs = [where[tuple(key[i])] for i in mine]
    if len(mine) < 3:
        raise InvalidInputError(f'the reference shares {len(mine)} sites with the map (3 or '
                                'more needed): another pitch, origin or unit?')
    at = np.asarray(positions)[mine]
    found = without_similarity(at, np.asarray(errors)[mine], keep_scale)
    true = without_similarity(at, np.asarray(reference_errors)[theirs], keep_scale)
    difference = np.linalg.norm(found - true, axis=1)
    before = np.linalg.norm(true, axis=1)
    report = {'sites_compared': len(mine), 'sites_in_map': len(positions),
              'gauge': ('translation, rotation' + ('' if keep_scale else ' and isotropic scale')
                        + ' taken out of both maps over the shared sites'),
              'stage_error_m': {'rms': float(np.sqrt(np.mean(before ** 2))),
                                'max': float(before.max())},
              'map_minus_reference_m': {'rms': float(np.sqrt(np.mean(difference ** 2))),
                                        'max': float(difference.max())}}
    if sigmas is not None:
        z = (found - true) / np.asarray(sigmas)[mine]
        report['in_sigma'] = {'rms': float(np.sqrt(np.mean(z ** 2))),
                              'within_2_sigma': float(np.mean(np.abs(z) <= 2)),
                              'note': '(map - reference) / stated sigma per component; 1 RMS '
                                      'when the uncertainty is right and the reference exact'}
    return report
