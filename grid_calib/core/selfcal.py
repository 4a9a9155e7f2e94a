"""Self-calibration of one region: the global linear least-squares route (Qiao 2018 style;
route B of SEEDS_CDE.md section 002). The unknowns are the residual stage error F at every
site, O and R, every mark's own error A and each placement's misalignment; the plate
errors are solved for and drop out of G, so a plate worse than the stage still calibrates
it. One sparse linear system with the gauge as extra rows:

- F has zero mean and zero first moments in x and y, per component (six rows): G carries
  no translation, rotation or isotropic scale (the data cannot show them), and O and R
  hold the shear and the scale difference;
- A has zero mean and no net rotation (three rows): a rigid motion of the whole plate is
  the same data as the placements' misalignments.

The isotropic scale of G is therefore 0 by convention and stated as undetermined: it needs
an external length (a certified pitch or an interferometer reading).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from grid_calib.core.bordered import factor_kkt
from grid_calib.core.model import PLACEMENTS, Grid, site_of, stage_error
from grid_calib.errors import PlacementError

GAUGE = {
    'translation': 'sum of G over the sites is 0: a stage offset is the plates\' position',
    'rotation': 'G has no net rotation: a turned stage frame is a turned plate',
    'isotropic_scale': 'undetermined without an external length: set to 0 in G',
    'plate': 'the plate errors have zero mean and no net rotation (the placements\' '
             'misalignments hold those)',
}


@dataclass(frozen=True)
class Placement:
    """One placement of the plate: which marks were measured and the stage reading minus
    the nominal site position for each (m)."""

    name: str
    marks: np.ndarray         # (k, 2) int, mark indices (i, j)
    deviation: np.ndarray     # (k, 2) m
    covariates: dict | None = None   # per mark: 'time' (s), 'temperature' (K), if logged


@dataclass
class SelfCalibration:
    """The solution of one region (SI units)."""

    grid: Grid
    non_orthogonality: float          # O, rad
    scale_difference: float           # R, 1
    sites: np.ndarray                 # (s, 2) site indices
    stage_error: np.ndarray           # G at the sites, (s, 2) m
    residual_field: np.ndarray        # F at the sites, (s, 2) m
    mark_errors: np.ndarray           # A, (N^2, 2) m, in grid.marks order
    misalignments: dict               # placement -> (shift_x m, shift_y m, angle rad)
    residuals: dict                   # placement -> (k, 2) m, measured minus model
    noise: float                      # measurement noise sigma estimated from the residuals, m
    noise_gain: np.ndarray | None     # (s, 2) std of G per unit of noise sigma; None if not propagated
    # (draws, s, 2): G's estimation error for draws of unit measurement noise (what the
    # stitching propagates); the method behind noise_gain ('exact' or 'sampled, ...').
    noise_draws: np.ndarray | None = None
    uncertainty_method: str = 'not propagated'

    @property
    def uncertainty(self) -> np.ndarray | None:
        """1-sigma uncertainty of G at each site (s, 2) m, propagated from the noise the
        residuals show; None where the grid was too large to propagate."""
        return None if self.noise_gain is None else self.noise_gain * self.noise

    @property
    def site_positions(self) -> np.ndarray:
        return self.sites * self.grid.pitch

    def report(self) -> dict:
        rms = {k: float(np.sqrt(np.mean(r ** 2))) for k, r in self.residuals.items()}
        return {'non_orthogonality_rad': self.non_orthogonality,
                'scale_difference': self.scale_difference,
                'sites': [{'x': float(x), 'y': float(y), 'error_x': float(gx),
                           'error_y': float(gy)}
                          for (x, y), (gx, gy) in zip(self.site_positions, self.stage_error)],
                'gauge': GAUGE, 'residual_rms_m': rms, 'noise_sigma_m': self.noise,
                'uncertainty_method': self.uncertainty_method,
                'uncertainty_m': (None if self.uncertainty is None else
                                  [{'x': float(x), 'y': float(y), 'sigma_x': float(sx),
                                    'sigma_y': float(sy)} for (x, y), (sx, sy)
                                   in zip(self.site_positions, self.uncertainty)]),
                'misalignments': {k: dict(zip(('shift_x_m', 'shift_y_m', 'angle_rad'),
                                              map(float, v)))
                                  for k, v in self.misalignments.items()}}


def check_placements(grid: Grid, placements: list[Placement]) -> dict:
    by_name = {p.name: p for p in placements}
    missing = [n for n in PLACEMENTS if n not in by_name]
    if missing or len(by_name) != len(placements):
        raise PlacementError(f'the method needs each of {PLACEMENTS} once; missing '
                             f'{missing or "none"}, given {[p.name for p in placements]}')
    full = {tuple(m) for m in grid.marks}
    for p in placements:
        marks = [tuple(m) for m in np.asarray(p.marks, dtype=int)]
        if len(set(marks)) != len(marks):
            raise PlacementError(f'{p.name}: a mark is measured twice')
        if set(marks) != full:
            raise PlacementError(f'{p.name}: {len(full - set(marks))} of the plate\'s '
                                 f'{len(full)} marks are missing')
        if p.deviation.shape != (len(marks), 2) or not np.all(np.isfinite(p.deviation)):
            raise PlacementError(f'{p.name}: need one finite (x, y) deviation per mark')
    return by_name


def _gauge_rows(grid: Grid, f0: int, a0: int, columns: int) -> sparse.csr_matrix:
    """The nine gauge constraints (9, columns): F with zero mean and first moments per
    component; A with zero mean and no net rotation."""
    sites, marks = grid.sites / grid.half, grid.marks / grid.half
    n_sites, n_marks = len(sites), len(marks)
    rows = []
    for component in (0, 1):
        for weights in (np.ones(n_sites), sites[:, 0], sites[:, 1]):
            rows.append((f0 + 2 * np.arange(n_sites) + component, weights))
    rows.append((a0 + 2 * np.arange(n_marks), np.ones(n_marks)))
    rows.append((a0 + 2 * np.arange(n_marks) + 1, np.ones(n_marks)))
    rows.append((np.concatenate([a0 + 2 * np.arange(n_marks), a0 + 2 * np.arange(n_marks) + 1]),
                 np.concatenate([-marks[:, 1], marks[:, 0]])))
    r = np.concatenate([np.full(len(c), k) for k, (c, _) in enumerate(rows)])
    c = np.concatenate([c for c, _ in rows])
    v = np.concatenate([w for _, w in rows]) / np.sqrt(n_sites)
    return sparse.csr_matrix((v, (r, c)), shape=(len(rows), columns))


# Work of the exact per-site uncertainty (right-hand sides x unknowns): up to N = 21 or so.
# Beyond, the sampled route: at N = 41 it takes 0.3 s where the exact one takes 3 s, and
# N = 101 would take minutes (bench_results/grid_uncertainty.md).
MAX_PROPAGATED = 5e6
PROPAGATION_BLOCK = 256   # right-hand sides solved at once
NOISE_DRAWS = 256         # draws of the sampled route: each sigma to 1 / sqrt(2 x 256) = 4.4 %


def _along_sites(grid: Grid, o_col: int, f0: int, columns: int,
                 scale_sign_y: float) -> sparse.csc_matrix:
    """(columns, 2 s): G at every site (x then y) as a combination of the unknowns (F, O, R;
    unknowns in units of the region's half size)."""
    n_sites = len(grid.sites)
    xs, ys = grid.sites[:, 0] / grid.half, grid.sites[:, 1] / grid.half
    rows = np.repeat(np.arange(2 * n_sites), 3)
    cols = np.column_stack([f0 + np.arange(2 * n_sites), np.full(2 * n_sites, o_col),
                            np.full(2 * n_sites, o_col + 1)]).ravel()
    values = np.column_stack([np.ones(2 * n_sites),
                              np.column_stack([ys, xs]).ravel(),
                              np.column_stack([xs, scale_sign_y * ys]).ravel()]).ravel()
    return sparse.csr_matrix((values, (rows, cols)), shape=(2 * n_sites, columns)).T.tocsc()


def _noise_gain(factor, design, along, columns: int) -> np.ndarray:
    """Std of G at every site per unit of measurement noise, (s, 2), exactly: for the
    constrained estimate x = P D^T b (P the KKT inverse's top block), Cov(x) = sigma^2 P D^T
    D P, taken along each site's G (one solve per site and component)."""
    variance = np.empty(along.shape[1])
    # In blocks of right-hand sides: the dense solve would otherwise hold two (unknowns x
    # 2 sites) matrices at once (about 0.5 GB at N = 41).
    for start in range(0, along.shape[1], PROPAGATION_BLOCK):
        block = along[:, start:start + PROPAGATION_BLOCK].toarray()
        right = np.zeros((factor.shape[0], block.shape[1]))
        right[:columns] = block
        dz = design @ factor.solve(right)[:columns]
        variance[start:start + block.shape[1]] = np.sum(dz * dz, axis=0)
    return np.sqrt(variance).reshape(-1, 2)


def noise_draws(factor, design, along, columns: int, count: int = NOISE_DRAWS,
                seed: int = 0) -> np.ndarray:
    """G's estimation error (count, s, 2) for ``count`` draws e of unit, independent
    measurement noise: x = P D^T e, whose covariance is exactly P D^T D P, the estimate's
    own. One solve per draw, whatever the grid's size: the sampled route to the per-site
    uncertainty (each sigma to 1 / sqrt(2 count)), and what the stitching propagates."""
    rng = np.random.default_rng(seed)
    out = np.empty((count, along.shape[1]))
    for start in range(0, count, PROPAGATION_BLOCK // 4):
        take = min(PROPAGATION_BLOCK // 4, count - start)
        right = np.zeros((factor.shape[0], take))
        right[:columns] = design.T @ rng.standard_normal((design.shape[0], take))
        out[start:start + take] = (along.T @ factor.solve(right)[:columns]).T
    return out.reshape(count, -1, 2)


@dataclass(frozen=True)
class LinearSystem:
    """One region's self-calibration as a linear least-squares problem with the gauge as
    exact constraints. Unknowns are in units of the region's half size (``half_size``, m)
    for conditioning: F, A and the shifts as lengths over it, O, R and the angles as they
    are times it. Rows: the placements in ``PLACEMENTS`` order, their marks in the order
    given, x then y."""

    design: sparse.csr_matrix       # (rows, columns)
    rhs: np.ndarray                 # (rows,) m: reading minus nominal site
    gauge: sparse.csr_matrix        # (9, columns)
    half_size: float                # m
    f0: int                         # first column of F
    o_col: int                      # O, then R
    a0: int                         # first column of A
    e0: int                         # first column of the misalignments (3 per placement)


def linear_system(grid: Grid, by_name: dict, scale_sign_y: float = -1.0) -> LinearSystem:
    """The design of ``check_placements``' placements (name -> Placement)."""
    n_sites, n_marks, side = len(grid.sites), len(grid.marks), 2 * grid.half + 1
    f0, o_col, a0, e0 = 0, 2 * n_sites, 2 * n_sites + 2, 2 * n_sites + 2 + 2 * n_marks
    columns = e0 + 3 * len(PLACEMENTS)
    rows, cols, values, rhs = [], [], [], []
    row = 0
    for p_index, name in enumerate(PLACEMENTS):
        placement = by_name[name]
        mark_ids = np.asarray(placement.marks, dtype=int)
        m, n = site_of(mark_ids, name).T
        # Indices in the orders of Grid.sites (n major, N + 1 columns) and Grid.marks.
        s = (n + grid.half) * (side + 1) + m + grid.half
        a = (mark_ids[:, 1] + grid.half) * side + mark_ids[:, 0] + grid.half
        x, y = m / grid.half, n / grid.half             # site position / half size
        e = np.full(len(s), e0 + 3 * p_index)
        one = np.ones(len(s))
        # A as seen: rotated placements swap and negate (A_x, A_y) -> (-A_y, A_x).
        if name == 'rotated':
            seen_x, sign_x, seen_y = a0 + 2 * a + 1, -one, a0 + 2 * a
        else:
            seen_x, sign_x, seen_y = a0 + 2 * a, one, a0 + 2 * a + 1
        row_x = row + 2 * np.arange(len(s))
        # Per row: F, O, R, A as seen, shift, turn (the x row, then the y row).
        rows += [np.repeat(row_x, 6), np.repeat(row_x + 1, 6)]
        cols += [np.column_stack([f0 + 2 * s, np.full(len(s), o_col), np.full(len(s), o_col + 1),
                                  seen_x, e, e + 2]).ravel(),
                 np.column_stack([f0 + 2 * s + 1, np.full(len(s), o_col),
                                  np.full(len(s), o_col + 1), seen_y, e + 1, e + 2]).ravel()]
        values += [np.column_stack([one, y, x, sign_x, one, -y]).ravel(),
                   np.column_stack([one, x, scale_sign_y * y, one, one, x]).ravel()]
        rhs.append(np.asarray(placement.deviation, dtype=float).ravel())
        row += 2 * len(s)
    rows, cols, values = (np.concatenate(v) for v in (rows, cols, values))
    design = sparse.csr_matrix((values, (rows, cols)), shape=(row, columns))
    return LinearSystem(design, np.concatenate(rhs), _gauge_rows(grid, f0, a0, columns),
                        grid.half * grid.pitch, f0, o_col, a0, e0)


def solve_constrained(design: sparse.csr_matrix, gauge: sparse.csr_matrix, b: np.ndarray):
    """Least squares ``design x ~ b`` with ``gauge x = 0`` exactly (Lagrange multipliers):
    (x, the factor of the KKT matrix, whose top-left block of the inverse maps the normal
    right-hand side to x)."""
    # Not as rows of the fit: the gauge rows span every site and would fill the normal
    # matrix. The dense columns and the gauge are a border of the sparse block
    # (grid_calib.core.bordered: 0.73 s at N = 101 where the whole KKT matrix takes 15.6 s).
    factor = factor_kkt(design, gauge)
    x = factor.solve(np.concatenate([design.T @ b, np.zeros(gauge.shape[0])]))
    return x[:design.shape[1]], factor


def self_calibrate(grid: Grid, placements: list[Placement], scale_sign_y: float = -1.0,
                   propagate: bool = True, draw_seed: int = 0) -> SelfCalibration:
    """Solve one region from its three placements.

    ``scale_sign_y`` is the sign of R in G_y: -1 is the corrected model; +1, the source's
    literal claim, is kept to show that it cannot describe a stage with a scale difference.
    ``propagate`` False skips the per-site uncertainty: exact up to about N = 21
    (:data:`MAX_PROPAGATED`), sampled beyond (:func:`noise_draws`, seeded by ``draw_seed``:
    regions stitched together need different seeds, their noise being independent).

    Raises
    ------
    PlacementError
        A placement missing or doubled, marks missing or measured twice, bad values.
    """
    system = linear_system(grid, check_placements(grid, placements), scale_sign_y)
    design, gauge, half_size = system.design, system.gauge, system.half_size
    f0, o_col, a0, e0 = system.f0, system.o_col, system.a0, system.e0
    sites, n_marks = grid.sites, len(grid.marks)
    n_sites, columns = len(sites), design.shape[1]
    solution, factor = solve_constrained(design, gauge, system.rhs / half_size)
    solution = solution * half_size
    residual = (design @ solution - system.rhs).reshape(3, n_marks, 2)
    # Noise: the residual's variance over the degrees of freedom the fit leaves.
    dof = design.shape[0] - (columns - gauge.shape[0])
    sigma = float(np.sqrt(np.sum(residual ** 2) / dof)) if dof > 0 else float('nan')
    gain, draws, method = None, None, 'not propagated'
    if propagate:
        along = _along_sites(grid, o_col, f0, columns, scale_sign_y)
        draws = noise_draws(factor, design, along, columns, seed=draw_seed)
        if along.shape[1] * factor.shape[0] <= MAX_PROPAGATED:
            gain, method = _noise_gain(factor, design, along, columns), 'exact'
        else:
            gain = draws.std(axis=0)
            method = (f'sampled: {NOISE_DRAWS} draws of the noise through the solve, each '
                      f'sigma to +-{100 / np.sqrt(2 * NOISE_DRAWS):.1f} %')
    if not np.all(np.isfinite(solution)):
        raise PlacementError('the placements do not determine the stage error (singular)')
    o_value, r_value = solution[o_col] / half_size, solution[o_col + 1] / half_size
    field = solution[f0:f0 + 2 * n_sites].reshape(n_sites, 2)
    mis = {name: (solution[e0 + 3 * k], solution[e0 + 3 * k + 1],
                  solution[e0 + 3 * k + 2] / half_size) for k, name in enumerate(PLACEMENTS)}
    by_placement = {name: -residual[k] for k, name in enumerate(PLACEMENTS)}
    g = stage_error(sites * grid.pitch, o_value, r_value, field, scale_sign_y)
    return SelfCalibration(grid, float(o_value), float(r_value), sites, g, field,
                           solution[a0:e0].reshape(n_marks, 2), mis, by_placement, sigma, gain,
                           draws, method)
