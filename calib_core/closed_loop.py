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
from scipy import stats
from scipy.optimize import least_squares

from calib_core.effects import CATEGORICAL_COVARIATES, LIBRARY
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.loop_structure import structure_tests
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
    min_effect = 50e-9   # smallest effect worth adding, RMS in the residuals' unit

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

    def replicates(self) -> np.ndarray | None:
        """A label per row that repeated measurements of one setting share (an ISO 230-2
        target approached from one direction), or None. With replicates, the loop's
        F-tests take the noise from the scatter within them (pure error), which structure
        not yet modelled does not inflate."""
        return None

    def row_errors(self, residuals: np.ndarray) -> np.ndarray:
        """Error magnitudes in which to report max and RMS: the norm per row."""
        return np.linalg.norm(residuals, axis=1)

    def workspace(self) -> np.ndarray | None:
        """2-D position of each row for a residual vector plot, (N, 2), or None."""
        return None


SCALAR_COVARIATES = ('time', 'temperature', 'sequence') + CATEGORICAL_COVARIATES


def _is_reference(key: str) -> bool:
    """Context entries that are one value for the whole dataset, not a column."""
    return key.endswith(('_ref', '_start'))


def scalar_covariates(covariates: dict) -> dict:
    """The per-row covariates of a dataset the effects use: time (s), temperature (K),
    sequence (approach number, 0 first) and the categorical columns (block, setup, run,
    cycle), with the reference values the effects need: the means of time and temperature
    (``time_ref``, ``temperature_ref``) and the starts of time and sequence
    (``time_start``, ``sequence_start``), all over every row of the dataset."""
    out = {k: np.asarray(covariates[k], float) for k in SCALAR_COVARIATES if k in covariates}
    references = {f'{k}_ref': float(np.mean(out[k])) for k in ('time', 'temperature') if k in out}
    references.update({f'{k}_start': float(np.min(out[k])) for k in ('time', 'sequence')
                       if k in out})
    out.update(references)
    return out


def select_rows(covariates: dict, rows: np.ndarray) -> dict:
    """``covariates`` from :func:`scalar_covariates` restricted to ``rows``."""
    return {k: v if _is_reference(k) else v[rows] for k, v in covariates.items()}


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
        Of the first random hold-out and fold assignment; split k uses ``seed + k``.
    splits : int
        Hold-out splits the selection is repeated over.
    min_frequency : float
        An effect is added only if the selection chose it in at least this share of the
        splits.
    min_effect : float or None
        Smallest effect worth adding, as the RMS of the structure it explains, in the
        residuals' unit (m or px); None takes the machine's ``min_effect``.
    """

    holdout_fraction: float = 0.3
    folds: int = 5
    alpha: float = 1e-3
    max_effects: int = 4
    seed: int = 0
    splits: int = 5
    min_frequency: float = 0.6
    min_effect: float | None = None

    def __post_init__(self):
        if not 0.05 <= self.holdout_fraction <= 0.6:
            raise InvalidInputError('holdout_fraction must be in [0.05, 0.6]')
        if self.folds < 2:
            raise InvalidInputError('folds must be at least 2')
        if not 0 < self.alpha < 0.5:
            raise InvalidInputError('alpha must be in (0, 0.5)')
        if self.max_effects < 0:
            raise InvalidInputError('max_effects must be >= 0')
        if self.splits < 1:
            raise InvalidInputError('splits must be at least 1')
        if not 0 < self.min_frequency <= 1:
            raise InvalidInputError('min_frequency must be in (0, 1]')
        if self.min_effect is not None and not (np.isfinite(self.min_effect)
                                                and self.min_effect >= 0):
            raise InvalidInputError('min_effect must be a finite number >= 0')


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

    def covariance(self, noise_variance: float | None = None) -> np.ndarray:
        """Parameter covariance; the noise variance defaults to the residuals'."""
        if noise_variance is None:
            noise_variance = self.rss / max(self.residuals.size - self.parameter_count, 1)
        return np.linalg.pinv(self.jacobian.T @ self.jacobian) * noise_variance

    def std_devs(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance()), 0, None))

    def effect_slice(self, k: int) -> slice:
        """Where effect ``k``'s parameters sit in the fit's vector."""
        start = len(self.base.free_names) + sum(len(v) for v in self.values[:k])
        return slice(start, start + len(self.values[k]))

    def names(self) -> list:
        return [e.effect.name for e in self.effects]


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


def refit(machine: MachineModel, fit: _Fit, rows: np.ndarray, effects: bool = True) -> _Fit:
    """``fit``'s model (its base and, with ``effects``, its effects) fitted again on ``rows``."""
    if effects:
        return _fit(machine, fit.base, fit.effects, fit.values, rows)
    return _fit(machine, machine.initial(), [], [], rows)


def _channel_residuals(machine, fit: _Fit, rows) -> np.ndarray:
    return _residuals(machine, fit.base, fit.effects, fit.values, rows, in_channels=True)


def _fit(machine: MachineModel, base: ParameterSet, effects: list, values: list,
         rows: np.ndarray) -> _Fit:
    """Joint least squares of the base model and ``effects`` on ``rows``."""
    sizes = [len(v) for v in values]
    nb = len(base.free_names)
    start = np.concatenate([base.free_vector()] + [np.asarray(v, float) for v in values])
    free = np.ones(len(start), bool)
    if any(e.determined is not None for e in effects):
        context, offset = machine.context(base, rows), nb
        for effect, size in zip(effects, sizes):
            if effect.determined is not None:
                free[offset:offset + size] = effect.determined(context)
            offset += size
    x0 = start[free]

    def unpack(x):
        full = start.copy()
        full[free] = x
        parts, offset = [], nb
        for s in sizes:
            parts.append(full[offset:offset + s])
            offset += s
        return base.with_free_vector(full[:nb]), parts

    def fun(x):
        b, parts = unpack(x)
        return _residuals(machine, b, effects, parts, rows).ravel()

    r0 = fun(x0)
    if not np.all(np.isfinite(r0)):
        raise InvalidInputError('residuals are not finite (NaN or infinite values in the data?)')
    solution = least_squares(fun, x0, method='trf', x_scale='jac')
    b, parts = unpack(solution.x)
    # Held parameters get zero columns: the rows say nothing about them.
    jacobian = np.zeros((solution.jac.shape[0], len(start)))
    jacobian[:, free] = solution.jac
    return _Fit(b, list(effects), parts, solution.fun.reshape(len(rows), -1), jacobian)


def _without(fit: _Fit, names) -> tuple[list, list]:
    """``fit``'s effects and values, less those named."""
    kept = [k for k, e in enumerate(fit.effects) if e.effect.name not in names]
    return [fit.effects[k] for k in kept], [fit.values[k] for k in kept]


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
    """Outcome of :func:`analyze`: the report (JSON-ready, SI units), the arrays the
    plots need (all rows) and the extended model as fitted on the fitting rows."""

    report: dict
    holdout: np.ndarray                 # bool (N,)
    residuals_before: np.ndarray        # (N, k), base model fitted on the training rows
    residuals_after: np.ndarray         # (N, k), extended model
    covariates: dict = field(default_factory=dict)   # name -> (N,)
    fit: _Fit | None = None


def _covariate_columns(machine, context: dict) -> dict:
    """Flatten a context into named scalar covariates per row."""
    out = {}
    for key, value in context.items():
        if _is_reference(key):
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


def _minimum_residuals(parameter_count: int) -> int:
    """Residuals needed to test a model with ``parameter_count`` parameters: twice as many,
    and at least 10 degrees of freedom left."""
    return max(2 * parameter_count, parameter_count + 10)


MAX_TERM_UNCERTAINTY = 0.5
"""An effect's term is undetermined when its standard deviation (RMS over the rows) is
more than this share of the term's own RMS."""


def _rank(jacobian: np.ndarray) -> int:
    """Numerical rank of a Jacobian with its columns scaled to unit norm."""
    norms = np.linalg.norm(jacobian, axis=0)
    scaled = jacobian[:, norms > 0] / norms[norms > 0]
    if scaled.size == 0:
        return 0
    return int(np.linalg.matrix_rank(scaled, tol=1e-8 * np.linalg.norm(scaled, 2)))


def _term_spread(prepared, values: np.ndarray, covariance: np.ndarray, context: dict):
    """RMS of an effect's term over the rows and the RMS of its standard deviation
    (first-order propagation of the parameters' covariance)."""
    term = prepared.term(values, context).ravel()
    sensitivity = np.empty((term.size, len(values)))
    for j in range(len(values)):
        step = 1e-6 * max(abs(values[j]), 1e-9)
        shifted = np.array(values, float)
        shifted[j] += step
        sensitivity[:, j] = (prepared.term(shifted, context).ravel() - term) / step
    variance = np.sum((sensitivity @ covariance) * sensitivity, axis=1)
    return float(np.sqrt(np.mean(term ** 2))), float(np.sqrt(np.mean(variance)))


def _undetermined(machine, current: _Fit, entry: dict, rows) -> str | None:
    """Why the candidate scored in ``entry`` (by :func:`_try_candidate` on ``rows``) is not
    identifiable from the data, or None.

    The noise is the one its F-test used. Three checks: its parameters add as many
    independent directions to the joint fit's Jacobian as the model gains parameters
    (else they are not separable from the model's); the term they make is known to better
    than :data:`MAX_TERM_UNCERTAINTY` of its size (the covariance is the joint fit's, so
    correlation with the base model counts); and a fitted period is known to 10 %.
    """
    extended, extra = entry['fit'], entry['extra']
    k = len(extended.effects) - 1
    prepared, values = extended.effects[k], extended.values[k]
    columns = extended.effect_slice(k)
    gained = _rank(extended.jacobian) - _rank(current.jacobian)
    if gained < extra:
        return (f'its parameters are not separable from the model\'s: they add {gained} '
                f'of {extra} independent directions to the fit')
    covariance = extended.covariance(entry['noise'])[columns, columns]
    size, spread = _term_spread(prepared, values, covariance,
                                machine.context(extended.base, rows))
    if not spread <= MAX_TERM_UNCERTAINTY * size:
        return (f'undetermined: its term (RMS {size:.3g}) has a standard deviation of '
                f'{spread:.3g}: correlated with the base model, or too few distinct '
                f'positions')
    sigma = np.sqrt(np.clip(np.diag(covariance), 0, None))
    ranges = prepared.notes.get('resolvable_periods_m', {})
    for name, value, s in zip(prepared.names, values, sigma):
        if not name.startswith('period_'):
            continue
        if not s <= 0.1 * abs(value):
            return f'period not determined: {name} = {value:.4g} +- {s:.2g} m'
        shortest, longest = ranges.get(name[len('period_'):], (0.0, np.inf))
        if not 0.95 * shortest <= abs(value) <= 1.05 * longest:
            return (f'the fitted period ({abs(value) * 1e3:.4g} mm) left the periods the '
                    f'positions resolve ({shortest * 1e3:.4g} to {longest * 1e3:.4g} mm): '
                    f'an alias of a shorter period or a trend, not determined')
    return None


@dataclass
class _Split:
    """One hold-out split and the selection made on it."""

    holdout: np.ndarray       # bool (N,)
    train: np.ndarray         # row indices
    folds: np.ndarray         # fold per training row
    base_fit: _Fit
    added: list               # dicts: prepared, round, evidence
    rounds: list
    skipped: dict
    not_identifiable: dict
    too_small: dict


def _make_split(machine, config: LoopConfig, seed: int):
    """Hold-out rows, fitting rows, folds and the base model's fit for one seed."""
    rng = np.random.default_rng(seed)
    every = np.arange(len(machine))
    holdout_parts = max(2, int(round(1 / config.holdout_fraction)))
    holdout = _split(machine.strata(), holdout_parts, rng) == 0
    train = every[~holdout]
    base = machine.initial()
    needed = _minimum_residuals(len(base.free_names))
    probe = _residuals(machine, base, [], [], train[:1])
    if len(train) * probe.shape[1] < needed or holdout.sum() == 0:
        raise CalibrationError(
            f'{len(machine)} rows are too few for the base model ({len(base.free_names)} '
            f'parameters) with {config.holdout_fraction:.0%} held out: the fitting rows give '
            f'{len(train) * probe.shape[1]} residuals, {needed} are needed')
    folds = _split(machine.strata()[train], config.folds, rng)
    return holdout, train, folds, _fit(machine, base, [], [], train)


def _try_candidate(machine, current: _Fit, name: str, train, context, channel_residuals):
    """Prepare effect ``name`` on the current residuals and refit it jointly (replacing
    any effect it supersedes). Returns a scored entry, or a string: why it was not tested."""
    prepared = LIBRARY[name].prepare(context, machine.channels, channel_residuals)
    if isinstance(prepared, str):
        return prepared
    effects, values = _without(current, prepared.effect.supersedes)
    extra = len(prepared.names) - (current.parameter_count - len(current.base.free_names)
                                   - sum(len(v) for v in values))
    size = current.parameter_count + extra
    residual_count = current.residuals.size
    if extra <= 0:
        return 'it adds no parameter to the model in force'
    if residual_count < _minimum_residuals(size):
        return (f'too little data to test it: {residual_count} residuals for {size} '
                f'parameters, {_minimum_residuals(size)} needed')
    try:
        extended = _fit(machine, current.base, effects + [prepared],
                        values + [prepared.initial], train)
    except (ValueError, np.linalg.LinAlgError) as error:
        return f'the joint fit failed: {error}'
    rss0, rss1 = current.rss, extended.rss
    noise, dof = _noise_variance(machine, extended, train, extra, residual_count - size)
    f_stat = max(rss0 - rss1, 0.0) / extra / max(noise, 1e-300)
    return {'effect': name, 'prepared': prepared, 'fit': extended, 'f_statistic': f_stat,
            'p_value_raw': min(1.0, float(stats.f.sf(f_stat, extra, dof)) * prepared.trials),
            'size': float(np.sqrt(max(rss0 - rss1, 0.0) / len(train))),
            'extra': extra, 'noise': noise}


MIN_PURE_ERROR_DOF = 10


def _noise_variance(machine, extended: _Fit, train, extra: int, residual_dof: int):
    """The noise variance for a candidate's F-test and its degrees of freedom: from the
    scatter of the extended model's residuals within replicate groups (pure error) when
    the machine has them and they leave :data:`MIN_PURE_ERROR_DOF`, else from the
    residuals. The candidate's own parameters are taken off the pure error's degrees of
    freedom, since an effect that varies within a group (a transient) absorbs some of it."""
    groups = machine.replicates()
    residual_variance = extended.rss / max(residual_dof, 1)
    if groups is None:
        return residual_variance, residual_dof
    labels = groups[train]
    r = extended.residuals
    within, cells = 0.0, 0
    for label in np.unique(labels):
        block = r[labels == label]
        within += float(np.sum((block - block.mean(axis=0)) ** 2))
        cells += 1
    dof = r.size - cells * r.shape[1] - extra
    if dof < MIN_PURE_ERROR_DOF:
        return residual_variance, residual_dof
    return within / dof, dof


def _judge(machine, current: _Fit, entry: dict, train, min_effect: float, alpha: float,
           tested: int) -> str:
    """Status of a scored candidate: 'candidate', or why it cannot be added."""
    entry['p_value'] = min(1.0, entry['p_value_raw'] * max(tested, 1))
    entry['significant'] = bool(entry['p_value'] < alpha)
    if not entry['significant']:
        return 'not significant'
    entry['reason'] = _undetermined(machine, current, entry, train)
    if entry['reason']:
        return 'not identifiable'
    if entry['size'] < min_effect:
        return 'below the minimum effect size'
    return 'candidate'


def _select(machine, config: LoopConfig, seed: int, min_effect: float, progress=None) -> _Split:
    """Forward selection on one hold-out split (steps 2 and 3 of the module's list)."""
    holdout, train, folds, base_fit = _make_split(machine, config, seed)
    current = base_fit
    current_cv = _cv_rms(machine, current, train, folds)
    rounds, skipped, added, not_identifiable, too_small = [], {}, [], {}, {}
    remaining = list(machine.candidates)
    while remaining and len(added) < config.max_effects:
        context = machine.context(current.base, train)
        channel_residuals = _channel_residuals(machine, current, train)
        scored = []
        for i, name in enumerate(remaining):
            if progress:
                progress(i, len(remaining), f'round {len(rounds) + 1}: {name}')
            entry = _try_candidate(machine, current, name, train, context, channel_residuals)
            if isinstance(entry, str):
                skipped[name] = entry
                continue
            skipped.pop(name, None)
            scored.append(entry)
        for entry in scored:
            entry['status'] = _judge(machine, current, entry, train, min_effect, config.alpha,
                                     len(scored))
            if entry['status'] == 'not identifiable':
                not_identifiable[entry['effect']] = entry['reason']
            elif entry['status'] == 'below the minimum effect size':
                too_small[entry['effect']] = entry['size']
            entry['cv_rms'] = (_cv_rms(machine, entry['fit'], train, folds)
                               if entry['status'] == 'candidate' else None)
        rounds.append({'cv_rms_current': current_cv, 'candidates': [
            {k: entry[k] for k in ('effect', 'f_statistic', 'p_value', 'cv_rms', 'significant',
                                   'size', 'status')} for entry in scored]})
        accepted = [e for e in scored if e['status'] == 'candidate' and e['cv_rms'] < current_cv]
        if not accepted:
            break
        best = min(accepted, key=lambda e: e['cv_rms'])
        added.append({'prepared': best['prepared'], 'round': len(rounds), 'evidence': {
            'f_statistic': best['f_statistic'], 'p_value': best['p_value'],
            'periods_searched': best['prepared'].trials,
            'cv_rms_before': current_cv, 'cv_rms_after': best['cv_rms'],
            'explained_rms': best['size'],
            'training_rms_before': float(np.sqrt(np.mean(current.residuals ** 2))),
            'training_rms_after': float(np.sqrt(np.mean(best['fit'].residuals ** 2)))}})
        current, current_cv = best['fit'], best['cv_rms']
        gone = {best['effect'], *best['prepared'].effect.supersedes}
        remaining = [name for name in remaining if name not in gone]
    return _Split(holdout, train, folds, base_fit, added, rounds, skipped, not_identifiable,
                  too_small)


def _heldout_ss(machine, splits: list, effects: list, values: list, start: _Fit) -> tuple:
    """Sum of squared held-out residuals over ``splits`` of the model with ``effects``,
    refitted on each split's fitting rows, and the number of residuals summed."""
    total, count = 0.0, 0
    for split in splits:
        fit = _fit(machine, start.base, effects, values, split.train)
        r = evaluate(machine, fit, np.flatnonzero(split.holdout))
        total += float(np.sum(r ** 2))
        count += r.size
    return total, count


def _build(machine, primary: _Split, chosen: list):
    """The effects ``chosen`` added in order on the first split's fitting rows; those that
    cannot be prepared or are not identifiable there are left out, with the reason."""
    current, evidence, not_identifiable, rejected = primary.base_fit, {}, {}, {}
    first = {item['prepared'].effect.name: item for item in primary.added}
    for name in chosen:
        context = machine.context(current.base, primary.train)
        entry = _try_candidate(machine, current, name, primary.train, context,
                               _channel_residuals(machine, current, primary.train))
        if isinstance(entry, str):
            rejected[name] = f'chosen on other splits, but on the first: {entry}'
            continue
        reason = _undetermined(machine, current, entry, primary.train)
        if reason:
            not_identifiable[name] = reason
            continue
        current = entry['fit']
        evidence[name] = first.get(name, {'round': None, 'evidence': {
            # not chosen on this split: its p-value is corrected for its own search only
            'f_statistic': entry['f_statistic'], 'p_value': entry['p_value_raw'],
            'explained_rms': entry['size']}})
    return current, evidence, not_identifiable, rejected


def _prune(machine, splits: list, current: _Fit, rejected: dict) -> _Fit:
    """Reject, one at a time, each effect whose removal lowers the held-out error summed
    over every split; the reason goes into ``rejected``."""
    while current.effects:
        with_all, count = _heldout_ss(machine, splits, current.effects, current.values, current)
        worst = None
        for name in current.names():
            effects, values = _without(current, (name,))
            without = _heldout_ss(machine, splits, effects, values, current)[0]
            if without < with_all and (worst is None or without < worst[1]):
                worst = (name, without)
        if worst is None:
            return current
        rejected[worst[0]] = (f'it makes the held-out error worse: RMS over the splits '
                              f'{np.sqrt(with_all / count):.3g} with it, '
                              f'{np.sqrt(worst[1] / count):.3g} without')
        effects, values = _without(current, (worst[0],))
        current = _fit(machine, current.base, effects, values, splits[0].train)
    return current


def analyze(machine: MachineModel, config: LoopConfig = LoopConfig(), progress=None) -> LoopResult:
    """Run the closed loop on ``machine``'s data.

    The selection (steps 2-3 of the module's list) runs on ``config.splits`` hold-out
    splits; an effect is added only if it was chosen in ``config.min_frequency`` of them,
    is identifiable on the first split, explains at least ``min_effect`` and does not make
    the held-out error summed over the splits worse. Before/after are reported on the
    first split's held-out rows, with the spread over all splits.

    ``progress(done, total, label)`` is called as candidates are scored.

    Raises
    ------
    CalibrationError
        Too few rows for the base model with a hold-out set.
    """
    unknown = [name for name in machine.candidates if name not in LIBRARY]
    if unknown:
        raise InvalidInputError(f'unknown effect(s) {", ".join(unknown)}')
    min_effect = machine.min_effect if config.min_effect is None else config.min_effect
    splits = []
    for k in range(config.splits):
        report = (lambda done, total, label, k=k: progress(
            done, total, f'split {k + 1}/{config.splits}, {label}')) if progress else None
        splits.append(_select(machine, config, config.seed + k, min_effect, report))
    positions = {}
    for split in splits:
        for position, item in enumerate(split.added):
            positions.setdefault(item['prepared'].effect.name, []).append(position)
    frequency = {name: len(v) / config.splits for name, v in positions.items()}
    chosen = sorted((n for n in positions if frequency[n] >= config.min_frequency),
                    key=lambda n: (-frequency[n], np.mean(positions[n])))
    final, evidence, not_identifiable, rejected = _build(machine, splits[0], chosen)
    final = _prune(machine, splits, final, rejected)
    for name in positions:
        if frequency[name] < config.min_frequency:
            rejected[name] = (f'chosen in {len(positions[name])} of {config.splits} hold-out '
                              f'splits, fewer than {config.min_frequency:.0%}: the data do '
                              f'not decide it')
    for split in splits:
        for name, reason in split.not_identifiable.items():
            if name not in final.names():
                not_identifiable.setdefault(name, reason)
    return _result(machine, config, splits, final, evidence, frequency, not_identifiable,
                   rejected, min_effect)


OUTLIER_SIGMAS = 5.0


def _outliers(machine, residuals: np.ndarray, covariates: dict, min_effect: float) -> dict:
    """Rows whose error under the extended model lies more than :data:`OUTLIER_SIGMAS`
    robust standard deviations (1.4826 x the median absolute deviation) from the median:
    a transient, a gross error or an effect of a few rows, which no smooth effect
    describes. They stay in every fit and figure; the report names them."""
    errors = machine.row_errors(residuals)
    centre = float(np.median(errors))
    sigma = 1.4826 * float(np.median(np.abs(errors - centre)))
    limit = max(centre + OUTLIER_SIGMAS * sigma, min_effect)
    per_row = max(len(errors) // len(residuals), 1)   # a machine may report per leg
    flagged = np.flatnonzero(errors > limit)
    flagged = flagged[np.argsort(-errors[flagged])]
    rows = list(dict.fromkeys(int(i) // per_row for i in flagged))
    worst = {}
    for i in flagged:
        worst.setdefault(int(i) // per_row, float(errors[i]))
    return {'limit': limit, 'robust_sigma': sigma,
            'rows': [{'row': row, 'error': worst[row],
                      'covariates': {k: float(v[row]) for k, v in covariates.items()}}
                     for row in rows[:20]],
            'count': len(rows)}


def _merged(splits: list, attribute: str, keep: list) -> dict:
    """A per-split dict merged over the splits (first split first), less the ``keep`` names."""
    out = {}
    for split in splits:
        for name, value in getattr(split, attribute).items():
            if name not in keep and name not in out:
                out[name] = value
    return out


def _result(machine, config, splits: list, final: _Fit, evidence: dict, frequency: dict,
            not_identifiable: dict, rejected: dict, min_effect: float) -> LoopResult:
    """The report and arrays of :func:`analyze` (step 4 of the module's list)."""
    primary = splits[0]
    every = np.arange(len(machine))
    holdout, train = primary.holdout, primary.train
    before_all = evaluate(machine, primary.base_fit, every)
    after_all = evaluate(machine, final, every)
    covariates = _covariate_columns(machine, machine.context(final.base, every))
    unexplained = structure_tests(
        machine.channels, _channel_residuals(machine, final, train),
        {k: v[train] for k, v in covariates.items()}, config.alpha)
    std = final.std_devs()
    nb = len(final.base.free_names)
    effects_added = []
    for k, prepared in enumerate(final.effects):
        item = evidence[prepared.effect.name]
        entry = prepared.describe(final.values[k], std[final.effect_slice(k)])
        entry['round'] = item['round']
        entry['evidence'] = dict(item['evidence'],
                                 selection_frequency=frequency.get(prepared.effect.name, 0.0))
        effects_added.append(entry)
    by_split = []
    for split in splits:
        rows = np.flatnonzero(split.holdout)
        refit = _fit(machine, final.base, final.effects, final.values, split.train)
        by_split.append({'rms_before': _summary(machine, evaluate(machine, split.base_fit, rows))['rms'],
                         'rms_after': _summary(machine, evaluate(machine, refit, rows))['rms']})
    held_before, held_after = _summary(machine, before_all[holdout]), _summary(machine, after_all[holdout])
    names = final.names()
    outliers = _outliers(machine, after_all, covariates, min_effect)
    report = {
        'machine': machine.name,
        'base_model': machine.base_model,
        'unit': machine.unit,
        'channels': list(machine.channels),
        'rows': {'total': len(machine), 'fitting': int(len(train)),
                 'held_out': int(holdout.sum())},
        'config': {'holdout_fraction': config.holdout_fraction, 'folds': config.folds,
                   'alpha': config.alpha, 'max_effects': config.max_effects,
                   'seed': config.seed, 'splits': config.splits,
                   'min_frequency': config.min_frequency, 'min_effect': min_effect},
        'effects_added': effects_added,
        'rms_before': held_before['rms'], 'max_before': held_before['max'],
        'rms_after': held_after['rms'], 'max_after': held_after['max'],
        'held_out_by_split': by_split,
        'fitting_rms_before': _summary(machine, before_all[~holdout])['rms'],
        'fitting_rms_after': _summary(machine, after_all[~holdout])['rms'],
        'base_parameters': {'before': primary.base_fit.base.as_dict(),
                            'after': final.base.as_dict(),
                            'units': final.base.units(),
                            'std_devs_after': dict(zip(final.base.free_names,
                                                       map(float, std[:nb])))},
        'candidates': list(machine.candidates),
        'selection_frequency': frequency,
        'skipped': _merged(splits, 'skipped', names),
        'not_identifiable': not_identifiable,
        'rejected': rejected,
        'below_minimum_effect': _merged(splits, 'too_small', names),
        'rounds': primary.rounds,
        'unexplained': unexplained,
        'outliers': outliers,
    }
    return LoopResult(_plain(report), holdout, before_all, after_all, covariates, final)


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
    """Lines for people: what was added and how consistently, the held-out error before
    and after, what the data cannot determine, what was rejected or skipped, and what
    structure remains."""
    factor, unit = (1e6, 'um') if report['unit'] == 'm' else (1.0, report['unit'])
    config = report['config']
    lines = [f'{report["machine"]}: base model {report["base_model"]}',
             f'  rows: {report["rows"]["fitting"]} fitted, {report["rows"]["held_out"]} held '
             f'out; selection repeated over {config["splits"]} hold-out splits, an effect is '
             f'added when chosen in {config["min_frequency"]:.0%} of them and it explains at '
             f'least {config["min_effect"] * factor:.3g} {unit} RMS']
    for effect in report['effects_added']:
        values = ', '.join(f'{k} {v:.4g} +- {effect["std_devs"][k]:.2g} {effect["units"][k]}'
                           for k, v in effect['parameters'].items())
        evidence = effect['evidence']
        lines.append(f'  added {effect["name"]} (chosen in '
                     f'{evidence["selection_frequency"]:.0%} of splits, p = '
                     f'{evidence["p_value"]:.2g}, explains {evidence["explained_rms"] * factor:.3g} '
                     f'{unit} RMS): {values}')
    if not report['effects_added']:
        lines.append('  added nothing: no candidate effect is significant, identifiable and '
                     'chosen consistently')
    spread = report.get('held_out_by_split', [])
    lines.append(f'  held out: RMS {report["rms_before"] * factor:.3g} -> '
                 f'{report["rms_after"] * factor:.3g} {unit}, max '
                 f'{report["max_before"] * factor:.3g} -> {report["max_after"] * factor:.3g} {unit}')
    ratios = [s['rms_after'] / s['rms_before'] for s in spread if s['rms_before'] > 0]
    if len(ratios) > 1:
        lines.append(f'  held-out RMS after / before over the {len(spread)} splits: '
                     f'{min(ratios):.2f} to {max(ratios):.2f}')
    for name, reason in report.get('not_identifiable', {}).items():
        lines.append(f'  NOT IDENTIFIABLE {name}: {reason}')
    for name, reason in report.get('rejected', {}).items():
        lines.append(f'  rejected {name}: {reason}')
    for name, size in report.get('below_minimum_effect', {}).items():
        lines.append(f'  below the minimum effect size {name}: explains {size * factor:.3g} {unit} RMS')
    for name, reason in report['skipped'].items():
        lines.append(f'  not tested {name}: {reason}')
    outliers = report.get('outliers', {})
    if outliers.get('count'):
        described = '; '.join(
            f'row {o["row"]} ({", ".join(f"{k} {v:.4g}" for k, v in o["covariates"].items())}):'
            f' {o["error"] * factor:.3g} {unit}' for o in outliers['rows'][:5])
        lines.append(f'  OUTLIERS: {outliers["count"]} row(s) off by more than '
                     f'{outliers["limit"] * factor:.3g} {unit} ({OUTLIER_SIGMAS:g} robust sigma) '
                     f'under the extended model, e.g. {described}')
    for item in report['unexplained']:
        period = f' (period {item["period"] * 1e3:.4g} mm)' if 'period' in item else ''
        lines.append(f'  UNEXPLAINED {item["kind"]}{period} of {item["component"]} against '
                     f'{item["covariate"]}: {item["structure_rms"] * factor:.3g} {unit} RMS '
                     f'(p = {item["p_value"]:.2g})')
    return '\n'.join(lines)
