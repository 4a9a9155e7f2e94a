"""Choosing effects: every candidate is refitted jointly with the base model and the
effects already added, scored (F-test, cross-validation, identifiability, minimum
size) on several hold-out splits; effects chosen often enough are built into the final
model and pruned while the held-out error allows (:func:`analyze`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from calib_core.effects import LIBRARY
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.closed_loop.fitting import (
    Fit, cross_validated_rms, fit_model, heldout_sum_of_squares, holdout_split, model_residuals,
    residuals_by_channel, without_effects)
from calib_core.closed_loop.identifiability import (
    minimum_residuals, pure_error_variance, undetermined_reason)
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


def _try_candidate(machine, current: Fit, name: str, train, context, channel_residuals):
    """Prepare effect ``name`` on the current residuals and refit it jointly (replacing
    any effect it supersedes). Returns a scored entry, or a string: why it was not tested."""
    prepared = prepare_effect(LIBRARY[name], machine, context, channel_residuals)
    if isinstance(prepared, str):
        return prepared
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
    return {'effect': name, 'prepared': prepared, 'fit': extended, 'f_statistic': f_stat,
            'p_value_raw': min(1.0, float(stats.f.sf(f_stat, extra, dof)) * prepared.trials),
            'size': float(np.sqrt(max(rss0 - rss1, 0.0) / len(train))),
            'extra': extra, 'noise': noise}


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
            entry['cv_rms'] = (cross_validated_rms(machine, entry['fit'], train, folds)
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


def _build(machine, primary: _Split, chosen: list):
    """The effects ``chosen`` added in order on the first split's fitting rows; those that
    cannot be prepared or are not identifiable there are left out, with the reason."""
    current, evidence, not_identifiable, rejected = primary.base_fit, {}, {}, {}
    first = {item['prepared'].effect.name: item for item in primary.added}
    for name in chosen:
        context = machine.context(current.base, primary.train)
        entry = _try_candidate(machine, current, name, primary.train, context,
                               residuals_by_channel(machine, current, primary.train))
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


def _prune(machine, splits: list, current: Fit, rejected: dict) -> Fit:
    """Reject, one at a time, each effect whose removal lowers the held-out error summed
    over every split; the reason goes into ``rejected``."""
    while current.effects:
        with_all, count = heldout_sum_of_squares(machine, splits, current.effects, current.values, current)
        worst = None
        for name in current.names():
            effects, values = without_effects(current, (name,))
            without = heldout_sum_of_squares(machine, splits, effects, values, current)[0]
            if without < with_all and (worst is None or without < worst[1]):
                worst = (name, without)
        if worst is None:
            return current
        rejected[worst[0]] = (f'it makes the held-out error worse: RMS over the splits '
                              f'{np.sqrt(with_all / count):.3g} with it, '
                              f'{np.sqrt(worst[1] / count):.3g} without')
        effects, values = without_effects(current, (worst[0],))
        current = fit_model(machine, current.base, effects, values, splits[0].train)
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
    return loop_result(machine, config, splits, final, evidence, frequency, not_identifiable,
                   rejected, min_effect)
