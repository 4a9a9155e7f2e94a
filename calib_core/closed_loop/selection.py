"""Choosing effects: every candidate is refitted jointly with the base model and the
effects already added, scored (F-test, cross-validation, identifiability, minimum
size) on several hold-out splits; effects chosen often enough are built into the final
model and pruned while the held-out error allows (:func:`analyze`)."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from calib_core.effects import LIBRARY
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.closed_loop.channels import (
    channel_groups, channel_p_values, determined_channels)
from calib_core.closed_loop.fitting import (
    Fit, cross_validated_rms, fit_model, heldout_errors, holdout_split, model_residuals,
    residuals_by_channel, without_effects)
from calib_core.closed_loop.identifiability import (
    minimum_residuals, pure_error_variance, undetermined_reason)
from calib_core.closed_loop.linearised import LinearisedModel
from calib_core.closed_loop.model import LoopConfig, MachineModel, prepare_effect
from calib_core.closed_loop.report import LoopResult, loop_result


@dataclass
class _Split:
    """One hold-out split and the selection made on it."""

    holdout: np.ndarray       # bool (N,)
    train: np.ndarray         # row indices
    folds: np.ndarray         # fold per training row
    base_fit: Fit
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
    holdout = holdout_split(machine.strata(), holdout_parts, rng) == 0
    train = every[~holdout]
    base = machine.initial()
    needed = minimum_residuals(len(base.free_names))
    probe = model_residuals(machine, base, [], [], train[:1])
    if len(train) * probe.shape[1] < needed or holdout.sum() == 0:
        raise CalibrationError(
            f'{len(machine)} rows are too few for the base model ({len(base.free_names)} '
            f'parameters) with {config.holdout_fraction:.0%} held out: the fitting rows give '
            f'{len(train) * probe.shape[1]} residuals, {needed} are needed')
    folds = holdout_split(machine.strata()[train], config.folds, rng)
    return holdout, train, folds, fit_model(machine, base, [], [], train)


def _try_candidate(machine, current: Fit, name: str, train, context, channel_residuals,
                   alpha: float, channels: tuple | None = None, undetermined: dict | None = None):
    """Prepare effect ``name`` on the current residuals and refit it jointly (replacing
    any effect it supersedes). Returns a scored entry, or a string: why it was not tested.

    Without ``channels``, the effect is fitted on every channel it may act on and then,
    if the data determine it on some of them only (:mod:`.channels`), refitted and scored
    on those; its p-value then also counts the choice among the channels. With
    ``channels``, it is fitted there and ``undetermined`` (channel -> why) is reported."""
    prepared = prepare_effect(LIBRARY[name], machine, context, channel_residuals, channels)
    if isinstance(prepared, str):
        return prepared
    if undetermined:
        prepared = replace(prepared, notes=dict(prepared.notes,
                                                channels_not_determined=dict(undetermined)))
    effects, values = without_effects(current, prepared.effect.supersedes)
    extra = len(prepared.names) - (current.parameter_count - len(current.base.free_names)
                                   - sum(len(v) for v in values))
    size = current.parameter_count + extra
    residual_count = current.residuals.size
    if extra <= 0:
        return 'it adds no parameter to the model in force'
    if residual_count < minimum_residuals(size):
        return (f'too little data to test it: {residual_count} residuals for {size} '
                f'parameters, {minimum_residuals(size)} needed')
    try:
        extended = fit_model(machine, current.base, effects + [prepared],
                        values + [prepared.initial], train)
    except (ValueError, np.linalg.LinAlgError) as error:
        return f'the joint fit failed: {error}'
    rss0, rss1 = current.rss, extended.rss
    noise, dof = pure_error_variance(machine, extended, train, extra, residual_count - size)
    f_stat = max(rss0 - rss1, 0.0) / extra / max(noise, 1e-300)
    groups = channel_groups(prepared, machine.channels)
    entry = {'effect': name, 'prepared': prepared, 'fit': extended, 'f_statistic': f_stat,
             'p_value_raw': min(1.0, float(stats.f.sf(f_stat, extra, dof)) * prepared.trials),
             'size': float(np.sqrt(max(rss0 - rss1, 0.0) / len(train))),
             'extra': extra, 'noise': noise, 'dof': dof,
             'channels': tuple(groups or ()) if prepared.separable else None}
    if channels is not None:
        return entry
    k = len(extended.effects) - 1
    columns = extended.effect_slice(k)
    p_values = channel_p_values(prepared, groups, extended.values[k],
                                extended.covariance(noise)[columns, columns], dof)
    decision = determined_channels(p_values, alpha)
    if decision is None:
        return entry
    kept, dropped = decision
    narrowed = _try_candidate(
        machine, current, name, train, context, channel_residuals, alpha, kept,
        {c: f'its term is not significant there (p = {p:.2g})' for c, p in dropped.items()})
    if isinstance(narrowed, str):
        return entry
    narrowed['p_value_raw'] = min(1.0, narrowed['p_value_raw'] * len(p_values))
    return narrowed


def _judge(machine, current: Fit, entry: dict, train, min_effect: float, alpha: float,
           tested: int) -> str:
    """Status of a scored candidate: 'candidate', or why it cannot be added."""
    entry['p_value'] = min(1.0, entry['p_value_raw'] * max(tested, 1))
    entry['significant'] = bool(entry['p_value'] < alpha)
    if not entry['significant']:
        return 'not significant'
    entry['reason'] = undetermined_reason(machine, current, entry, train)
    if entry['reason']:
        return 'not identifiable'
    if entry['size'] < min_effect:
        return 'below the minimum effect size'
    return 'candidate'


def _nested_terms_p_value(general: dict, special: dict) -> float:
    """p-value of the terms a candidate has beyond one it supersedes, both fitted in the
    same round (nested models: F-test of the extra terms against the general one's noise)."""
    extra = general['extra'] - special['extra']
    if extra <= 0:
        return 1.0
    gain = max(special['fit'].rss - general['fit'].rss, 0.0)
    f_stat = gain / extra / max(general['noise'], 1e-300)
    return float(stats.f.sf(f_stat, extra, general['dof']))


def _prefer_the_simpler(accepted: list, alpha: float) -> list:
    """The accepted candidates less those that supersede another accepted one without
    their extra terms being significant at ``alpha``: a reversal that changes along the
    travel is not claimed over a constant one for a 1-sigma slope that happened to lower
    the cross-validated error. The general effect is tried again in the next round, on top
    of the simple one, where only its extra terms are tested."""
    by_name = {e['effect']: e for e in accepted}
    kept = []
    for entry in accepted:
        special = [by_name[n] for n in entry['prepared'].effect.supersedes if n in by_name]
        entry['nested_p_value'] = min((_nested_terms_p_value(entry, s) for s in special),
                                      default=None)
        if entry['nested_p_value'] is None or entry['nested_p_value'] < alpha:
            kept.append(entry)
    return kept


def _select(machine, config: LoopConfig, seed: int, min_effect: float, progress=None) -> _Split:
    """Forward selection on one hold-out split (steps 2 and 3 of the module's list)."""
    holdout, train, folds, base_fit = _make_split(machine, config, seed)
    current = base_fit
    current_cv = cross_validated_rms(machine, current, train, folds)
    rounds, skipped, added, not_identifiable, too_small = [], {}, [], {}, {}
    remaining = list(machine.candidates)
    while remaining and len(added) < config.max_effects:
        context = machine.context(current.base, train)
        channel_residuals = residuals_by_channel(machine, current, train)
        scored = []
        for i, name in enumerate(remaining):
            if progress:
                progress(i, len(remaining), f'round {len(rounds) + 1}: {name}')
            entry = _try_candidate(machine, current, name, train, context, channel_residuals,
                                   config.alpha)
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
            entry['cv_rms'] = (cross_validated_rms(machine, entry['fit'], train, folds)
                               if entry['status'] == 'candidate' else None)
        rounds.append({'cv_rms_current': current_cv, 'candidates': [
            {k: entry[k] for k in ('effect', 'f_statistic', 'p_value', 'cv_rms', 'significant',
                                   'size', 'status')} for entry in scored]})
        accepted = _prefer_the_simpler(
            [e for e in scored if e['status'] == 'candidate' and e['cv_rms'] < current_cv],
            config.alpha)
        if not accepted:
            break
        best = min(accepted, key=lambda e: e['cv_rms'])
        added.append({'prepared': best['prepared'], 'round': len(rounds),
                      'channels': best['channels'], 'evidence': {
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


def _consistent_channels(machine, splits: list, name: str, min_frequency: float):
    """The channels effect ``name`` was chosen on in ``min_frequency`` of the splits and
    the others with their counts: (kept, undetermined), or None when its parameters are
    not per channel (on some split, channels shared them)."""
    counts = {}
    for split in splits:
        for item in split.added:
            if item['prepared'].effect.name == name:
                if item['channels'] is None:
                    return None
                for channel in item['channels']:
                    counts[channel] = counts.get(channel, 0) + 1
    if not counts:
        return None
    allowed = machine.effect_channels.get(name) or machine.channels
    kept = tuple(c for c in allowed if counts.get(c, 0) / len(splits) >= min_frequency)
    undetermined = {c: f'chosen there in {counts.get(c, 0)} of {len(splits)} hold-out splits'
                    for c in allowed if c not in kept}
    return kept, undetermined


def _build(machine, splits: list, chosen: list, config: LoopConfig):
    """The effects ``chosen`` added in order on the first split's fitting rows, each on
    the channels it was chosen on consistently; those that cannot be prepared or are not
    identifiable there are left out, with the reason."""
    primary = splits[0]
    current, evidence, not_identifiable, rejected = primary.base_fit, {}, {}, {}
    first = {item['prepared'].effect.name: item for item in primary.added}
    for name in chosen:
        channels = _consistent_channels(machine, splits, name, config.min_frequency)
        if channels is not None and not channels[0]:
            rejected[name] = ('chosen consistently, but on no channel consistently: '
                              + '; '.join(f'{c}: {why}' for c, why in channels[1].items()))
            continue
        kept, undetermined = channels or (None, None)
        context = machine.context(current.base, primary.train)
        entry = _try_candidate(machine, current, name, primary.train, context,
                               residuals_by_channel(machine, current, primary.train),
                               config.alpha, kept, undetermined)
        if isinstance(entry, str):
            rejected[name] = f'chosen on other splits, but on the first: {entry}'
            continue
        reason = undetermined_reason(machine, current, entry, primary.train)
        if reason:
            not_identifiable[name] = reason
            continue
        current = entry['fit']
        evidence[name] = first.get(name, {'round': None, 'evidence': {
            # not chosen on this split: its p-value is corrected for its own search only
            'f_statistic': entry['f_statistic'], 'p_value': entry['p_value_raw'],
            'explained_rms': entry['size']}})
    return current, evidence, not_identifiable, rejected


MIN_HELDOUT_GAIN = 0.01
"""An effect must lower the held-out RMS, pooled over the splits, by this share to stay:
a gain of less than 1 % is no reason to change a machine's model. The held-out maximum
may not grow by more than this share or by more than the RMS falls (a row it does not
touch keeps its error to rounding, hence a share, not zero)."""


def _prune(machine, splits: list, current: Fit, rejected: dict) -> Fit:
    """Reject, one at a time, each effect that does not earn its place on held-out rows:
    removing it leaves the held-out RMS pooled over the splits within
    :data:`MIN_HELDOUT_GAIN` (or lowers it), the held-out maximum grows with it by more
    than the pooled RMS falls (and by more than that share) on most splits, or on the
    reported split the held-out RMS is larger with it. The effect that gains least goes
    first; the reason goes into ``rejected``."""
    while current.effects:
        with_all = heldout_errors(machine, splits, current.effects, current.values, current)
        failing = []
        for name in current.names():
            effects, values = without_effects(current, (name,))
            without = heldout_errors(machine, splits, effects, values, current)
            gain = 1 - np.sqrt(with_all['sum_of_squares'] / without['sum_of_squares'])
            max_ratios = np.array(with_all['maxima']) / np.array(without['maxima'])
            # The maximum may grow by no more than the RMS falls: a few rows the effect
            # does not describe (named under outliers) must not veto a real effect, and a
            # small RMS gain must not buy a larger worst error.
            allowed = 1 + MIN_HELDOUT_GAIN if gain <= 0 else max(1 + MIN_HELDOUT_GAIN,
                                                                 1 / (1 - gain))
            # The first split's held-out rows are the ones reported before and after. Its
            # maximum alone does not veto (one split's worst row is mostly noise: it vetoed
            # the hexapod's real play on 60 poses); the report says when it grew.
            reported_worse = with_all['sums'][0] > without['sums'][0]
            if gain < MIN_HELDOUT_GAIN or np.median(max_ratios) > allowed or reported_worse:
                failing.append((gain, name, with_all, without, max_ratios, allowed))
        if not failing:
            return current
        gain, name, with_all, without, max_ratios, allowed = min(failing, key=lambda f: f[0])
        rms = [np.sqrt(e['sum_of_squares'] / e['count']) for e in (with_all, without)]
        reported = np.sqrt(with_all['sums'][0] / without['sums'][0])
        rejected[name] = (
            f'it does not earn its place on held-out rows: RMS over the splits {rms[0]:.3g} '
            f'with it, {rms[1]:.3g} without ({gain:+.1%}, {MIN_HELDOUT_GAIN:.0%} needed); '
            f'held-out max with / without it {np.median(max_ratios):.3f} (median over the '
            f'splits, at most {allowed:.3f} allowed); on the reported split RMS '
            f'x {reported:.3f}, max x {max_ratios[0]:.3f}')
        effects, values = without_effects(current, (name,))
        current = (fit_model(machine, current.base, effects, values, splits[0].train)
                   if effects else splits[0].base_fit)
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
    if config.linearise and machine.linearise:
        every = np.arange(len(machine))
        machine = LinearisedModel(machine, fit_model(machine, machine.initial(), [], [],
                                                     every).base)
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
    final, evidence, not_identifiable, rejected = _build(machine, splits, chosen, config)
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
    return loop_result(machine, config, splits, final, evidence, frequency, not_identifiable,
                   rejected, min_effect)
