"""The closed loop on a grid self-calibration's residuals (one region).

The self-calibration's model already holds everything that depends only on the site (G),
only on the mark (the plate errors) or only on the placement (its misalignment), so a
screw's periodic error or a lead error is in G and cannot show in the residuals. What the
model lacks is a change during the run: thermal expansion as the machine warms between and
during placements (with a logged temperature), a drift in time, a reversal when the
direction of approach varies, a step within a placement. The candidates are the closed
loop's own effects (``calib_core.effects``), added to the self-calibration's linear
system as extra columns, so the joint fit is exact and one solve:

1. identifiable: the effect's columns must keep full rank once the self-calibration's
   columns are projected out (otherwise the base model holds it: reported, never added);
2. significant: the extra-sum-of-squares F-test (alpha 1e-3, Bonferroni over the
   candidates tested) and at least the minimum effect size (RMS over the readings);
3. held out: the error each reading gets from the fit without it, exact for linear least
   squares (the PRESS residual e / (1 - h), h the reading's leverage), before and after.
   Readings no other reading predicts (a site or mark seen once: h = 1) are counted and
   left out of it. An effect is kept only if it lowers this held-out error.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np
from scipy import sparse, stats

from calib_core.closed_loop.model import scalar_covariates
from calib_core.effects import LIBRARY
from calib_core.errors import InvalidInputError
from grid_calib.core.model import PLACEMENTS, Grid, site_of, stage_error
from grid_calib.core.selfcal import (
    LinearSystem, Placement, check_placements, linear_system, solve_constrained)

CANDIDATES = ('drift_temperature', 'drift_time', 'reversal', 'block_step')
CHANNELS = ('x', 'y')
ALPHA = 1e-3
MIN_EFFECT_M = 5e-9
MAX_EFFECTS = 2
LEVERAGE_BLOCK = 256
BASE_MODEL = ('the self-calibration: reading - nominal site = G(site) + A(mark, turned with '
              'the plate) + a rigid misalignment per placement (m), G and A free at every '
              'site and mark')


def _context(grid: Grid, by_name: dict) -> tuple[dict, dict]:
    """Per reading (rows in the linear system's order): position of the site (m),
    direction of approach, the logged covariates, the placement as ``block`` and the
    reading's ``sequence``; and the covariates that were incomplete (dropped)."""
    positions, directions, logged = [], [], {}
    for name in PLACEMENTS:
        p = by_name[name]
        positions.append(site_of(np.asarray(p.marks, dtype=int), name) * grid.pitch)
        covariates = p.covariates or {}
        directions.append(np.asarray(covariates.get('direction', -np.ones((len(p.marks), 2))),
                                     dtype=float).reshape(-1, 2))
        for key in ('time', 'temperature'):
            logged.setdefault(key, []).append(covariates.get(key))
    count = sum(len(p) for p in positions)
    columns, dropped = {}, {}
    for key, parts in logged.items():
        if any(part is None for part in parts):
            if any(part is not None for part in parts):
                dropped[key] = 'not logged for every placement'
            continue
        values = np.concatenate([np.asarray(v, dtype=float) for v in parts])
        if values.shape != (count,) or not np.all(np.isfinite(values)):
            raise InvalidInputError(f'the {key} column needs one finite value per reading')
        columns[key] = values
    columns['block'] = np.repeat(np.arange(len(PLACEMENTS)),
                                 [len(by_name[n].marks) for n in PLACEMENTS]).astype(float)
    columns['sequence'] = np.arange(count, dtype=float)
    context = {'position': np.vstack(positions), 'direction': np.vstack(directions)}
    context.update(scalar_covariates(columns))
    return context, dropped


class _Fit:
    """The self-calibration's system solved with extra columns (m per parameter unit)."""

    def __init__(self, system: LinearSystem, extra: np.ndarray):
        half = system.half_size
        norms = np.linalg.norm(extra, axis=0) if extra.size else np.ones(0)
        scaled = extra / np.where(norms > 0, norms, 1.0)        # unit columns, for conditioning
        self.design = sparse.hstack([system.design * half, sparse.csr_matrix(scaled)]).tocsr()
        self.gauge = sparse.hstack([system.gauge, sparse.csr_matrix((system.gauge.shape[0],
                                                                     extra.shape[1]))]).tocsr()
        x, self.factor = solve_constrained(self.design, self.gauge, system.rhs)
        self.base_columns = system.design.shape[1]
        self.x, self.extra = x, extra
        self.values = x[self.base_columns:] / np.where(norms > 0, norms, 1.0)
        self.norms = norms
        self.residual = system.rhs - self.design @ x                 # measured - model, m
        self.dof = self.design.shape[0] - (self.design.shape[1] - self.gauge.shape[0])
        self.rss = float(self.residual @ self.residual)

    def _solve_top(self, right: np.ndarray) -> np.ndarray:
        full = np.zeros((self.factor.shape[0], right.shape[1]))
        full[:right.shape[0]] = right
        return self.factor.solve(full)[:right.shape[0]]

    def std_devs(self) -> np.ndarray:
        """1-sigma of the extra parameters, from the residuals' noise."""
        count = len(self.values)
        if not count:
            return np.zeros(0)
        unit = np.zeros((self.design.shape[1], count))
        unit[self.base_columns + np.arange(count), np.arange(count)] = 1.0
        variance = np.diag(self._solve_top(unit)[self.base_columns:]) * self.rss / self.dof
        return np.sqrt(np.clip(variance, 0, None)) / np.where(self.norms > 0, self.norms, 1.0)

    def leverage(self) -> np.ndarray:
        """h per row: diag of the hat matrix of the constrained fit."""
        rows = self.design.shape[0]
        h = np.empty(rows)
        transposed = self.design.T.tocsc()
        for start in range(0, rows, LEVERAGE_BLOCK):
            block = transposed[:, start:start + LEVERAGE_BLOCK].toarray()
            z = self._solve_top(block)
            h[start:start + block.shape[1]] = np.sum(block * z, axis=0)
        return h

    @cached_property
    def held_out(self) -> dict:
        """Leave-one-out prediction errors (PRESS) over the predictable readings (one
        leverage solve per fit, however often the loop asks)."""
        h = self.leverage()
        predictable = (1 - h) > 1e-6
        press = self.residual[predictable] / (1 - h[predictable])
        return {'rms_m': float(np.sqrt(np.mean(press ** 2))),
                'max_m': float(np.abs(press).max()), 'predicted': int(predictable.sum()),
                'unpredictable': int((~predictable).sum())}


def _determined(base: _Fit, columns: np.ndarray) -> np.ndarray:
    """Which of the effect's parameters the readings determine beyond the model in force
    (bool, (p,)): its columns with the model's projected out, taken one by one while each
    adds a direction. The others are held at zero and named."""
    normal = base.design.T @ columns
    projected = columns - base.design @ base._solve_top(normal)
    scale = np.linalg.norm(columns, axis=0).max()
    keep = np.zeros(columns.shape[1], bool)
    for k in range(columns.shape[1]):
        trial = projected[:, np.append(np.flatnonzero(keep), k)]
        singular = np.linalg.svd(trial, compute_uv=False)
        keep[k] = singular.min() > 1e-7 * scale
    return keep


def _columns(prepared, context: dict) -> np.ndarray:
    """The effect's term per unit of each parameter, (2 readings, p): linear effects only."""
    count = len(prepared.names)
    out = np.empty((2 * len(context['position']), count))
    for k in range(count):
        unit = np.zeros(count)
        unit[k] = 1.0
        out[:, k] = prepared.term(unit, context).ravel()
    return out


def analyze_region(grid: Grid, placements: list[Placement],
                   min_effect: float = MIN_EFFECT_M, alpha: float = ALPHA,
                   max_effects: int = MAX_EFFECTS, detail: dict | None = None) -> dict:
    """The closed loop on one region's self-calibration; a report (SI units). ``detail``,
    when given, receives what a figure needs: ``residuals_before`` and
    ``residuals_after`` (readings, 2) m and the readings' ``covariates`` (name -> (readings,))."""
    by_name = check_placements(grid, placements)
    system = linear_system(grid, by_name)
    context, dropped = _context(grid, by_name)
    current, added = _Fit(system, np.zeros((len(system.rhs), 0))), []
    base = current
    verdicts, skipped = {}, {}
    while len(added) < max_effects:
        channel_residuals = current.residual.reshape(-1, 2)
        scored = []
        for name in CANDIDATES:
            if name in [a['name'] for a in added]:
                continue
            prepared = LIBRARY[name].prepare(context, CHANNELS, channel_residuals)
            if isinstance(prepared, str):
                skipped[name] = prepared
                continue
            columns = _columns(prepared, context)
            determined = _determined(current, columns)
            if not determined.any():
                verdicts[name] = (
                    'not identifiable: the self-calibration already holds it (it depends only '
                    'on the site, the mark or the placement)' if not added else
                    'not identifiable: the self-calibration and '
                    f'{", ".join(a["name"] for a in added)} already hold it')
                continue
            extended = _Fit(system, np.column_stack([current.extra, columns[:, determined]]))
            p = int(determined.sum())
            f_stat = max(current.rss - extended.rss, 0.0) / p / (extended.rss / extended.dof)
            scored.append({'name': name, 'prepared': prepared, 'columns': columns[:, determined],
                           'determined': determined,
                           'fit': extended, 'f_statistic': float(f_stat),
                           'p_raw': float(stats.f.sf(f_stat, p, extended.dof)),
                           'size_m': float(np.sqrt(max(current.rss - extended.rss, 0.0)
                                                   / (len(system.rhs) / 2)))})
        for entry in scored:
            entry['p_value'] = min(1.0, entry['p_raw'] * len(scored))
        significant = [e for e in scored if e['p_value'] < alpha and e['size_m'] >= min_effect]
        for entry in scored:
            if entry not in significant:
                verdicts[entry['name']] = (f'not significant (p = {entry["p_value"]:.3g}, '
                                           f'{entry["size_m"] * 1e9:.2f} nm RMS)')
        if not significant:
            break
        best = max(significant, key=lambda e: e['f_statistic'])
        before, after = current.held_out, best['fit'].held_out
        if after['rms_m'] >= before['rms_m']:
            verdicts[best['name']] = ('rejected: significant but does not lower the held-out '
                                      f'error ({before["rms_m"] * 1e9:.2f} -> '
                                      f'{after["rms_m"] * 1e9:.2f} nm)')
            break
        added.append(best)
        verdicts[best['name']] = 'added'
        current = best['fit']
    if detail is not None:
        detail.update(residuals_before=base.residual.reshape(-1, 2),
                      residuals_after=current.residual.reshape(-1, 2),
                      covariates={k: v for k, v in context.items()
                                  if np.ndim(v) == 1})   # per reading; references are scalars
    return _report(grid, system, base, current, added, verdicts, skipped, dropped)


def analyze_travel(grid: Grid, regions: dict, min_effect: float = MIN_EFFECT_M,
                   alpha: float = ALPHA, max_effects: int = MAX_EFFECTS,
                   details: dict | None = None) -> dict:
    """The loop on every region (:func:`analyze_region`), with the whole run's summary in
    the keys every machine's loop report has: ``effects_added`` (each with its
    ``region``), held-out ``rms_before``/``rms_after`` (leave-one-out, pooled over the
    regions' predicted readings) and ``max_before``/``max_after`` (m), ``unexplained``
    (none: the grid loop tests its candidates only). ``details`` receives each region's
    :func:`analyze_region` detail under its key."""
    reports, effects, pooled = {}, [], {'before': [], 'after': []}
    for key, region in regions.items():
        detail = {} if details is not None else None
        report = analyze_region(grid, region.placements, min_effect, alpha, max_effects, detail)
        if details is not None:
            details[str(key)] = detail
        reports[str(key)] = report
        effects += [dict(effect, region=str(key)) for effect in report['effects']]
        for when in pooled:
            held = report['held_out'][when]
            pooled[when].append((held['predicted'], held['rms_m'], held['max_m']))

    def rms(rows):
        count = sum(n for n, _, _ in rows)
        return float(np.sqrt(sum(n * r ** 2 for n, r, _ in rows) / max(count, 1)))
    return {'machine': 'grid', 'base_model': BASE_MODEL, 'unit': 'm', 'effects_added': effects,
            'rms_before': rms(pooled['before']), 'rms_after': rms(pooled['after']),
            'max_before': max(m for _, _, m in pooled['before']),
            'max_after': max(m for _, _, m in pooled['after']),
            'held_out': 'leave-one-out prediction (PRESS) per region, pooled',
            'unexplained': [], 'regions': reports}


def _stage_error(grid: Grid, system: LinearSystem, fit: _Fit) -> np.ndarray:
    """G at the sites (s, 2) m of a fit (in the self-calibration's gauge)."""
    x, half = fit.x, system.half_size
    n_sites = len(grid.sites)
    field = x[system.f0:system.f0 + 2 * n_sites].reshape(n_sites, 2) * half
    return stage_error(grid.sites * grid.pitch, x[system.o_col], x[system.o_col + 1], field)


def _report(grid, system, base: _Fit, final: _Fit, added, verdicts, skipped, dropped) -> dict:
    effects, offset = [], 0
    std = final.std_devs()
    for entry in added:
        determined = entry['determined']
        count = int(determined.sum())
        values, sigmas = np.zeros(len(determined)), np.full(len(determined), np.nan)
        values[determined] = final.values[offset:offset + count]
        sigmas[determined] = std[offset:offset + count]
        names = entry['prepared'].names
        effects.append({**entry['prepared'].describe(values, sigmas),
                        'not_determined': [n for n, d in zip(names, determined) if not d],
                        'f_statistic': entry['f_statistic'], 'p_value': entry['p_value'],
                        'size_rms_m': entry['size_m'], 'residual_dof': int(final.dof)})
        offset += count
    g_base, g_final = _stage_error(grid, system, base), _stage_error(grid, system, final)
    return {'machine': 'grid', 'base_model': BASE_MODEL, 'effects': effects,
            'verdicts': verdicts, 'skipped': skipped, 'dropped_covariates': dropped,
            'not_testable_here': {'periodic, lead_error, scale, squareness': (
                'depend on the position only: the self-calibration holds them in G')},
            'held_out': {'method': 'leave-one-out prediction (PRESS), exact for the linear '
                                   'fit; readings no other reading predicts left out',
                         'before': base.held_out, 'after': final.held_out},
            'fit_rms_m': {'before': float(np.sqrt(base.rss / len(system.rhs))),
                          'after': float(np.sqrt(final.rss / len(system.rhs)))},
            'stage_error_change_m': float(np.abs(g_final - g_base).max()),
            'stage_error_m': g_final.tolist()}
