"""The closed loop: from a calibration's residual to the effect the model lacks.

A :class:`MachineModel` gives named base parameters, a context of covariates and residuals
(measured minus predicted) in which the effects of :mod:`calib_core.effects` enter through
the machine's channels. :func:`analyze`

1. holds out a fraction of the rows (stratified by the machine's strata) that no fit sees;
2. fits the base model on the rest;
3. refits every candidate effect jointly with the base model and the effects already
   added (effects correlate with geometric parameters, so they cannot be fitted to the
   residual alone), scores it with an extra-sum-of-squares F-test (Bonferroni-corrected
   for the number of candidates and, for searched periods, the number of periods tried)
   and with K-fold cross-validation, and adds the best candidate that is significant and
   lowers the cross-validated error; then repeats;
4. reports the held-out error of the base model and of the extended model, and tests the
   remaining residual against every covariate for structure no candidate explained.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.polynomial import legendre
from scipy import stats
from scipy.optimize import least_squares
from scipy.signal import lombscargle

from calib_core.effects import LIBRARY
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.parameters import ParameterSet


class MachineModel:
    """What the loop needs from a machine. Rows are observations (an axis target, a pose,
    an image point); ``rows`` arguments are integer index arrays into them.

    Subclasses set ``name``, ``base_model`` (a sentence), ``unit`` (of the residuals),
    ``channels`` (names of the quantities effects act on), ``candidates`` (effect names)
    and implement ``__len__``, :meth:`initial`, :meth:`context` and :meth:`residuals`.
    """

    name = ''
    base_model = ''
    unit = 'm'
    channels: tuple = ()
    candidates: tuple = ()

    def __len__(self) -> int:
        raise NotImplementedError

    def initial(self) -> ParameterSet:
        """Starting values of the base parameters (free ones are fitted)."""
        raise NotImplementedError

    def context(self, base: ParameterSet, rows: np.ndarray) -> dict:
        """Covariates of ``rows`` (see :mod:`calib_core.effects`); may depend on ``base``."""
        raise NotImplementedError

    def residuals(self, base: ParameterSet, delta: np.ndarray, rows: np.ndarray,
                  context: dict) -> np.ndarray:
        """Measured minus predicted, shape (n, k), with effect terms ``delta`` (n, C) added
        to the channels; ``context`` is :meth:`context` of the same base and rows, which
        the loop has computed already."""
        raise NotImplementedError

    def channel_residuals(self, base: ParameterSet, delta: np.ndarray, rows: np.ndarray,
                          context: dict) -> np.ndarray:
        """Residuals expressed in the channels (what ``delta`` lacks), shape (n, C)."""
        return self.residuals(base, delta, rows, context)

    def strata(self) -> np.ndarray:
        """Label per row; hold-out and folds sample every label (e.g. camera views)."""
        return np.zeros(len(self), dtype=int)

    def row_errors(self, residuals: np.ndarray) -> np.ndarray:
        """Error magnitudes in which to report max and RMS: the norm per row."""
        return np.linalg.norm(residuals, axis=1)

    def workspace(self) -> np.ndarray | None:
        """2-D position of each row for a residual vector plot, (N, 2), or None."""
        return None


SCALAR_COVARIATES = ('time', 'temperature')


def scalar_covariates(covariates: dict) -> dict:
    """The time (s) and temperature (K) columns of a dataset, with their means as the
    reference values the drift effects use (``time_ref``, ``temperature_ref``)."""
    out = {k: np.asarray(covariates[k], float) for k in SCALAR_COVARIATES if k in covariates}
    out.update({f'{k}_ref': float(np.mean(v)) for k, v in list(out.items())})
    return out


def select_rows(covariates: dict, rows: np.ndarray) -> dict:
    """``covariates`` from :func:`scalar_covariates` restricted to ``rows``."""
    return {k: v if k.endswith('_ref') else v[rows] for k, v in covariates.items()}


@dataclass(frozen=True)
class LoopConfig:
    """Settings of :func:`analyze`.

    Attributes
    ----------
    holdout_fraction : float
        Rows kept out of every fit, to report before/after on.
    folds : int
        Cross-validation folds within the fitting rows.
    alpha : float
        Family-wise significance level per round (Bonferroni over the candidates tried).
    max_effects : int
        Stop after adding this many effects.
    seed : int
        Of the random hold-out and fold assignment.
    """

    holdout_fraction: float = 0.3
    folds: int = 5
    alpha: float = 1e-3
    max_effects: int = 4
    seed: int = 0

    def __post_init__(self):
        if not 0.05 <= self.holdout_fraction <= 0.6:
            raise InvalidInputError('holdout_fraction must be in [0.05, 0.6]')
        if self.folds < 2:
            raise InvalidInputError('folds must be at least 2')
        if not 0 < self.alpha < 0.5:
            raise InvalidInputError('alpha must be in (0, 0.5)')
        if self.max_effects < 0:
            raise InvalidInputError('max_effects must be >= 0')


@dataclass
class _Fit:
    base: ParameterSet
    effects: list
    values: list          # one array per effect
    residuals: np.ndarray  # (n, k) on the rows fitted
    jacobian: np.ndarray

    @property
    def rss(self) -> float:
        return float(np.sum(self.residuals ** 2))

    @property
    def parameter_count(self) -> int:
        return len(self.base.free_names) + sum(len(v) for v in self.values)

    def std_devs(self) -> np.ndarray:
        dof = max(self.residuals.size - self.parameter_count, 1)
        cov = np.linalg.pinv(self.jacobian.T @ self.jacobian) * self.rss / dof
        return np.sqrt(np.clip(np.diag(cov), 0, None))


def _delta(machine, effects, values, context, count) -> np.ndarray:
    delta = np.zeros((count, len(machine.channels)))
    for effect, v in zip(effects, values):
        delta = delta + effect.term(v, context)
    return delta


def _residuals(machine: MachineModel, base: ParameterSet, effects: list, values: list,
               rows: np.ndarray, in_channels: bool = False) -> np.ndarray:
    """Residuals of the base model plus ``effects`` on ``rows``: (n, k), or (n, C)
    expressed in the channels."""
    context = machine.context(base, rows)
    delta = _delta(machine, effects, values, context, len(rows))
    method = machine.channel_residuals if in_channels else machine.residuals
    return method(base, delta, rows, context)


def evaluate(machine: MachineModel, fit: _Fit, rows: np.ndarray) -> np.ndarray:
    """Residuals (n, k) of a fitted model on any rows."""
    return _residuals(machine, fit.base, fit.effects, fit.values, rows)


def _channel_residuals(machine, fit: _Fit, rows) -> np.ndarray:
    return _residuals(machine, fit.base, fit.effects, fit.values, rows, in_channels=True)


def _fit(machine: MachineModel, base: ParameterSet, effects: list, values: list,
         rows: np.ndarray) -> _Fit:
    """Joint least squares of the base model and ``effects`` on ``rows``."""
    sizes = [len(v) for v in values]
    nb = len(base.free_names)
    x0 = np.concatenate([base.free_vector()] + [np.asarray(v, float) for v in values])

    def unpack(x):
        parts, start = [], nb
        for s in sizes:
            parts.append(x[start:start + s])
            start += s
        return base.with_free_vector(x[:nb]), parts

    def fun(x):
        b, parts = unpack(x)
        return _residuals(machine, b, effects, parts, rows).ravel()

    r0 = fun(x0)
    if not np.all(np.isfinite(r0)):
        raise InvalidInputError('residuals are not finite (NaN or infinite values in the data?)')
    solution = least_squares(fun, x0, method='trf', x_scale='jac')
    b, parts = unpack(solution.x)
    return _Fit(b, list(effects), parts, solution.fun.reshape(len(rows), -1), solution.jac)


def _split(labels: np.ndarray, parts: int, rng) -> np.ndarray:
    """A part number per row, balanced within each label."""
    out = np.empty(len(labels), dtype=int)
    for label in np.unique(labels):
        index = np.flatnonzero(labels == label)
        out[rng.permutation(index)] = np.arange(len(index)) % parts
    return out


def _cv_rms(machine, fit: _Fit, rows, folds) -> float:
    """RMS of the residuals each fold gets from a model fitted to the other folds."""
    total, count = 0.0, 0
    for k in np.unique(folds):
        train, test = rows[folds != k], rows[folds == k]
        refit = _fit(machine, fit.base, fit.effects, fit.values, train)
        r = evaluate(machine, refit, test)
        total += float(np.sum(r ** 2))
        count += r.size
    return float(np.sqrt(total / count))


def _summary(machine, residuals: np.ndarray) -> dict:
    errors = machine.row_errors(residuals)
    return {'rms': float(np.sqrt(np.mean(errors ** 2))), 'max': float(np.max(errors))}


@dataclass
class LoopResult:
    """Outcome of :func:`analyze`: the report (JSON-ready, SI units) and the arrays the
    plots need (all rows)."""

    report: dict
    holdout: np.ndarray                 # bool (N,)
    residuals_before: np.ndarray        # (N, k), base model fitted on the training rows
    residuals_after: np.ndarray         # (N, k), extended model
    covariates: dict = field(default_factory=dict)   # name -> (N,)


def _covariate_columns(machine, context: dict) -> dict:
    """Flatten a context into named scalar covariates per row."""
    out = {}
    for key, value in context.items():
        if key.endswith('_ref'):
            continue
        value = np.asarray(value, float)
        if value.ndim == 1:
            out[key] = value
        elif key == 'normalized':
            out['image_radius'] = np.linalg.norm(value, axis=1)
        else:
            for c, name in enumerate(machine.channels):
                out[f'{key}_{name}'] = value[:, c]
    return out


def _structure_tests(machine, residuals: np.ndarray, covariates: dict, alpha: float) -> list:
    """Structure left in channel ``residuals`` (n, C) against each covariate: a cubic trend (a step
    for two-valued covariates) and, against positions, a sinusoid at the periodogram's
    peak; F-tests, Bonferroni-corrected over the periods scanned and every test made."""
    n = len(residuals)
    tests = []
    for covariate, z in covariates.items():
        distinct = len(np.unique(z))
        if distinct < 2:
            continue
        span = float(np.ptp(z))
        scaled = 2 * (z - z.min()) / span - 1
        degree = min(3, distinct - 1)
        for j, component in enumerate(machine.channels):
            r = residuals[:, j] - residuals[:, j].mean()
            candidates = [('trend' if degree > 1 else 'step',
                           legendre.legvander(scaled, degree)[:, 1:], 1.0)]
            if covariate.startswith('position') and n >= 20:
                freqs = np.linspace(2 / span, max(2 / span, n / (2 * span)), 400)
                omega = 2 * np.pi * freqs[np.argmax(
                    lombscargle(z, r, 2 * np.pi * freqs, floating_mean=True))]
                candidates.append(('periodic', np.column_stack(
                    [np.cos(omega * z), np.sin(omega * z)]), max((freqs[-1] - freqs[0]) * span, 1.0)))
            for kind, basis, trials in candidates:
                basis = basis - basis.mean(axis=0)
                fitted = basis @ np.linalg.lstsq(basis, r, rcond=None)[0]
                rss1 = float(np.sum((r - fitted) ** 2))
                p, dof = basis.shape[1], n - basis.shape[1] - 1
                if dof <= 0 or rss1 <= 0:
                    continue
                f_stat = (float(r @ r) - rss1) / p / (rss1 / dof)
                tests.append({'covariate': covariate, 'component': f'residual_{component}',
                              'kind': kind,
                              'p_value': min(1.0, float(stats.f.sf(f_stat, p, dof)) * trials),
                              'structure_rms': float(np.sqrt(np.mean(fitted ** 2))),
                              'residual_rms': float(np.sqrt(np.mean(r ** 2)))})
    count = max(len(tests), 1)
    found = [dict(t, p_value=min(1.0, t['p_value'] * count)) for t in tests
             if t['p_value'] * count < alpha]
    return sorted(found, key=lambda t: t['p_value'])


def _minimum_residuals(parameter_count: int) -> int:
    """Residuals needed to test a model with ``parameter_count`` parameters: twice as many,
    and at least 10 degrees of freedom left."""
    return max(2 * parameter_count, parameter_count + 10)


def analyze(machine: MachineModel, config: LoopConfig = LoopConfig(), progress=None) -> LoopResult:
    """Run the closed loop on ``machine``'s data.

    ``progress(done, total, label)`` is called as candidates are scored.

    Raises
    ------
    CalibrationError
        Too few rows for the base model with a hold-out set.
    """
    unknown = [name for name in machine.candidates if name not in LIBRARY]
    if unknown:
        raise InvalidInputError(f'unknown effect(s) {", ".join(unknown)}')
    rng = np.random.default_rng(config.seed)
    count = len(machine)
    every = np.arange(count)
    holdout_parts = max(2, int(round(1 / config.holdout_fraction)))
    holdout = _split(machine.strata(), holdout_parts, rng) == 0
    train, test = every[~holdout], every[holdout]
    base = machine.initial()
    needed = _minimum_residuals(len(base.free_names))
    probe = _residuals(machine, base, [], [], train[:1])
    if len(train) * probe.shape[1] < needed or len(test) == 0:
        raise CalibrationError(
            f'{count} rows are too few for the base model ({len(base.free_names)} parameters) '
            f'with {config.holdout_fraction:.0%} held out: the fitting rows give '
            f'{len(train) * probe.shape[1]} residuals, {needed} are needed')
    folds = _split(machine.strata()[train], config.folds, rng)

    base_fit = _fit(machine, base, [], [], train)
    current = base_fit
    current_cv = _cv_rms(machine, current, train, folds)
    rounds, skipped, added = [], {}, []
    remaining = list(machine.candidates)
    while remaining and len(added) < config.max_effects:
        context = machine.context(current.base, train)
        channel_residuals = _channel_residuals(machine, current, train)
        scored = []
        for i, name in enumerate(remaining):
            if progress:
                progress(i, len(remaining), f'round {len(rounds) + 1}: {name}')
            prepared = LIBRARY[name].prepare(context, machine.channels, channel_residuals)
            if isinstance(prepared, str):
                skipped[name] = prepared
                continue
            size = current.parameter_count + len(prepared.names)
            residual_count = current.residuals.size
            if residual_count < _minimum_residuals(size):
                skipped[name] = (f'too little data to test it: {residual_count} residuals for '
                                 f'{size} parameters, {_minimum_residuals(size)} needed')
                continue
            try:
                extended = _fit(machine, current.base, current.effects + [prepared],
                                current.values + [prepared.initial], train)
            except (ValueError, np.linalg.LinAlgError) as error:
                skipped[name] = f'the joint fit failed: {error}'
                continue
            skipped.pop(name, None)
            p = len(prepared.names)
            dof = residual_count - size
            rss0, rss1 = current.rss, extended.rss
            f_stat = max(rss0 - rss1, 0.0) / p / max(rss1 / dof, 1e-300)
            p_value = min(1.0, float(stats.f.sf(f_stat, p, dof)) * prepared.trials)
            scored.append({'effect': name, 'prepared': prepared, 'fit': extended,
                           'f_statistic': f_stat, 'p_value_raw': p_value})
        tested = len(scored)
        for entry in scored:
            entry['p_value'] = min(1.0, entry['p_value_raw'] * max(tested, 1))
            entry['significant'] = bool(entry['p_value'] < config.alpha)
            entry['cv_rms'] = (_cv_rms(machine, entry['fit'], train, folds)
                               if entry['significant'] else None)
        if progress:
            progress(len(remaining), len(remaining), f'round {len(rounds) + 1} scored')
        rounds.append({'cv_rms_current': current_cv, 'candidates': [
            {k: entry[k] for k in ('effect', 'f_statistic', 'p_value', 'cv_rms', 'significant')}
            for entry in scored]})
        accepted = [e for e in scored if e['significant'] and e['cv_rms'] < current_cv]
        if not accepted:
            break
        best = min(accepted, key=lambda e: e['cv_rms'])
        added.append({'prepared': best['prepared'], 'round': len(rounds),
                      'evidence': {'f_statistic': best['f_statistic'],
                                   'p_value': best['p_value'],
                                   'periods_searched': best['prepared'].trials,
                                   'cv_rms_before': current_cv, 'cv_rms_after': best['cv_rms'],
                                   'training_rms_before': float(np.sqrt(np.mean(current.residuals ** 2))),
                                   'training_rms_after': float(np.sqrt(np.mean(best['fit'].residuals ** 2)))}})
        current, current_cv = best['fit'], best['cv_rms']
        remaining.remove(best['effect'])

    before_all = evaluate(machine, base_fit, every)
    after_all = evaluate(machine, current, every)
    covariates = _covariate_columns(machine, machine.context(current.base, every))
    unexplained = _structure_tests(
        machine, _channel_residuals(machine, current, train),
        {k: v[train] for k, v in covariates.items()}, config.alpha)
    std = current.std_devs()
    nb = len(current.base.free_names)
    effects_added = []
    for item in added:
        prepared = item['prepared']
        k = current.effects.index(prepared)
        values = current.values[k]
        offset = nb + sum(len(v) for v in current.values[:k])
        entry = prepared.describe(values, std[offset:offset + len(values)])
        entry['round'] = item['round']
        entry['evidence'] = item['evidence']
        effects_added.append(entry)
    held_before, held_after = _summary(machine, before_all[holdout]), _summary(machine, after_all[holdout])
    report = {
        'machine': machine.name,
        'base_model': machine.base_model,
        'unit': machine.unit,
        'channels': list(machine.channels),
        'rows': {'total': count, 'fitting': int(len(train)), 'held_out': int(len(test))},
        'config': {'holdout_fraction': config.holdout_fraction, 'folds': config.folds,
                   'alpha': config.alpha, 'max_effects': config.max_effects,
                   'seed': config.seed},
        'effects_added': effects_added,
        'rms_before': held_before['rms'], 'max_before': held_before['max'],
        'rms_after': held_after['rms'], 'max_after': held_after['max'],
        'fitting_rms_before': _summary(machine, before_all[~holdout])['rms'],
        'fitting_rms_after': _summary(machine, after_all[~holdout])['rms'],
        'base_parameters': {'before': base_fit.base.as_dict(), 'after': current.base.as_dict(),
                            'units': current.base.units(),
                            'std_devs_after': dict(zip(current.base.free_names,
                                                       map(float, std[:nb])))},
        'candidates': list(machine.candidates),
        'skipped': skipped,
        'rounds': rounds,
        'unexplained': unexplained,
    }
    return LoopResult(_plain(report), holdout, before_all, after_all, covariates)


def _plain(value):
    """``value`` with numpy scalars and arrays made Python numbers and lists, so the
    report serialises to JSON and YAML alike."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def format_report(report: dict) -> str:
    """A few lines for people: what was added, the held-out error before and after, what
    was skipped and what structure remains."""
    factor, unit = (1e6, 'um') if report['unit'] == 'm' else (1.0, report['unit'])
    lines = [f'{report["machine"]}: base model {report["base_model"]}',
             f'  rows: {report["rows"]["fitting"]} fitted, {report["rows"]["held_out"]} held out']
    for effect in report['effects_added']:
        values = ', '.join(f'{k} {v:.4g} {effect["units"][k]}'
                           for k, v in effect['parameters'].items())
        lines.append(f'  added {effect["name"]} (p = {effect["evidence"]["p_value"]:.2g}, '
                     f'CV RMS {effect["evidence"]["cv_rms_before"] * factor:.3g} -> '
                     f'{effect["evidence"]["cv_rms_after"] * factor:.3g} {unit}): {values}')
    if not report['effects_added']:
        lines.append('  added nothing: no candidate effect is significant')
    lines.append(f'  held out: RMS {report["rms_before"] * factor:.3g} -> '
                 f'{report["rms_after"] * factor:.3g} {unit}, max '
                 f'{report["max_before"] * factor:.3g} -> {report["max_after"] * factor:.3g} {unit}')
    for name, reason in report['skipped'].items():
        lines.append(f'  skipped {name}: {reason}')
    for item in report['unexplained']:
        lines.append(f'  UNEXPLAINED {item["kind"]} of {item["component"]} against '
                     f'{item["covariate"]}: {item["structure_rms"] * factor:.3g} {unit} RMS '
                     f'(p = {item["p_value"]:.2g})')
    return '\n'.join(lines)
