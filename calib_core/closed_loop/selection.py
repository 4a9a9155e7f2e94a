"""Choosing effects: every candidate is refitted jointly with the base model and the
effects already added, scored (F-test, cross-validation, identifiability, minimum
size) on several hold-out splits; effects chosen often enough are built into the final
model and pruned while the held-out error allows (:func:`analyze`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.effects import LIBRARY
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.closed_loop.fitting import (
    Fit, cross_validated_rms, fit_model, heldout_errors, holdout_split, model_residuals,
    residuals_by_channel, without_effects)
from calib_core.loop_structure import structure_tests
from calib_core.closed_loop.evidence import (
    MIN_HELDOUT_GAIN, describe_gain, earns_its_place, matching_candidate, pooled_gain,
    seen_not_added)
from calib_core.closed_loop.identifiability import (
    minimum_residuals, undetermined_reason)
from calib_core.closed_loop.linearised import LinearisedModel
from calib_core.closed_loop.model import (
    LoopConfig, MachineModel, covariate_columns, prepare_effect)
from calib_core.closed_loop.report import LoopResult, loop_result
from calib_core.closed_loop.trial import judge, prefer_the_simpler, try_candidate


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


def _make_split(machine, config: LoopConfig, k: int):
    """Hold-out rows, fitting rows, folds and the base model's fit for split ``k``.

    The rows are partitioned into 1 / ``holdout_fraction`` parts (balanced within each
    stratum); split k holds out part k of a partition, a new partition every round of
    parts, so that the first rounds hold every row out once and the figures pooled over the
    splits speak for every row."""
    every = np.arange(len(machine))
    holdout_parts = max(2, int(round(1 / config.holdout_fraction)))
    partition = holdout_split(machine.strata(), holdout_parts,
                              np.random.default_rng([config.seed, k // holdout_parts]))
    holdout = partition == k % holdout_parts
    train = every[~holdout]
    base = machine.initial()
    needed = minimum_residuals(len(base.free_names))
    probe = model_residuals(machine, base, [], [], train[:1])
    if len(train) * probe.shape[1] < needed or holdout.sum() == 0:
        raise CalibrationError(
            f'{len(machine)} rows are too few for the base model ({len(base.free_names)} '
            f'parameters) with {config.holdout_fraction:.0%} held out: the fitting rows give '
            f'{len(train) * probe.shape[1]} residuals, {needed} are needed')
    folds = holdout_split(machine.strata()[train], config.folds,
                          np.random.default_rng([config.seed, k, 1]))
    return holdout, train, folds, fit_model(machine, base, [], [], train)


def _select(machine, config: LoopConfig, k: int, min_effect: float, progress=None) -> _Split:
    """Forward selection on hold-out split ``k`` (steps 2 and 3 of the module's list)."""
    holdout, train, folds, base_fit = _make_split(machine, config, k)
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
            follows = LIBRARY[name].follows
            if follows and follows not in current.names():
                skipped[name] = f'a higher order of {follows}, tried once that is in the model'
                continue
            entry = try_candidate(machine, current, name, train, context, channel_residuals,
                                   config.alpha)
            if isinstance(entry, str):
                skipped[name] = entry
                continue
            skipped.pop(name, None)
            scored.append(entry)
        for entry in scored:
            entry['status'] = judge(machine, current, entry, train, min_effect, config.alpha,
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
        accepted = prefer_the_simpler(
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
        entry = try_candidate(machine, current, name, primary.train, context,
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


def _prune(machine, splits: list, current: Fit, rejected: dict, gains: dict) -> Fit:
    """Reject, one at a time, each effect that does not earn its place on held-out rows
    (:func:`earns_its_place`); the effect that gains least goes first. Its reason goes into
    ``rejected`` and its figures into ``gains``."""
    while current.effects:
        failing = []
        with_all = heldout_errors(machine, splits, current.effects, current.values, current)
        for name in current.names():
            gain = pooled_gain(machine, splits, current, name, with_all)
            if not earns_its_place(gain):
                failing.append((gain['gain'], name, gain))
        if not failing:
            return current
        _, name, gain = min(failing, key=lambda f: f[0])
        gains[name] = gain
        rejected[name] = f'it does not earn its place on held-out rows: {describe_gain(gain)}'
        effects, values = without_effects(current, (name,))
        current = (fit_model(machine, current.base, effects, values, splits[0].train)
                   if effects else splits[0].base_fit)
    return current


def _p_value_beyond(machine, fit: Fit, name: str, train, alpha: float) -> float:
    """p-value of effect ``name``'s terms added to ``fit`` (replacing what it supersedes):
    1 where it adds no parameter or cannot be tested."""
    context = machine.context(fit.base, train)
    entry = try_candidate(machine, fit, name, train, context,
                           residuals_by_channel(machine, fit, train), alpha)
    return 1.0 if isinstance(entry, str) else entry['p_value_raw']


def _simplify(machine, splits: list, current: Fit, config: LoopConfig, evidence: dict,
              replaced: dict) -> Fit:
    """Each added effect replaced by a candidate with fewer parameters where that does as
    well on the held-out rows of every split (pooled RMS within :data:`MIN_HELDOUT_GAIN`)
    or where the effect's own terms, added to the candidate, are not significant (the data
    do not ask for its extra parameters) and the held-out RMS is within its own sampling
    spread, repeated until no replacement is left.

    Forward selection adds the best candidate of its round given the effects it has then:
    a drift over a run, half of it seen as a difference between directions before the
    backlash is in, loses its round to a step per cycle (four parameters for one slope).
    On an ISO 230-2 run the run order makes a step per cycle plus a reversal that varies
    with position span a drift by approach number plus a constant reversal exactly, so only
    parsimony can tell them apart; the second replacement (the reversal) is only possible
    once the first (the drift) is in, hence the repetition. The alternatives are every
    candidate of the machine; ``replaced`` gets, per effect replaced, what replaced it and
    why."""
    primary = splits[0]
    pooled = None
    changed = True
    while changed:
        changed = False
        for name in list(current.names()):
            size = len(current.values[current.names().index(name)])
            alternatives = [c for c in machine.candidates
                            if c not in current.names() and c not in replaced]
            if size < 2 or not alternatives:
                continue        # nothing has fewer than one parameter
            effects, values = without_effects(current, (name,))
            reduced = (fit_model(machine, current.base, effects, values, primary.train)
                       if effects else primary.base_fit)
            context = machine.context(reduced.base, primary.train)
            residuals = residuals_by_channel(machine, reduced, primary.train)
            best = None
            for alternative in alternatives:
                prepared = prepare_effect(LIBRARY[alternative], machine, context, residuals)
                if isinstance(prepared, str) or len(prepared.names) >= size:
                    continue    # not simpler: no joint fit needed to know
                entry = try_candidate(machine, reduced, alternative, primary.train, context,
                                       residuals, config.alpha)
                # The selection's own rules (no minimum size: it stands in for an effect
                # that passed it).
                if (isinstance(entry, str) or entry['extra'] >= size or judge(
                        machine, reduced, entry, primary.train, 0.0, config.alpha, 1)
                        != 'candidate'):
                    continue
                fit = entry['fit']
                pooled = pooled or heldout_errors(machine, splits, current.effects,
                                                  current.values, current)
                sum_of_squares = heldout_errors(machine, splits, fit.effects, fit.values,
                                                fit)['sum_of_squares']
                ratio = float(np.sqrt(sum_of_squares / pooled['sum_of_squares']))
                beyond = _p_value_beyond(machine, fit, name, primary.train, config.alpha)
                # Not significant beyond it, and no worse held out than the held-out RMS's
                # own spread (two standard errors of an RMS over that many values).
                spread = 2 / np.sqrt(2 * pooled['count'])
                if ((ratio <= 1 + MIN_HELDOUT_GAIN
                     or (beyond >= config.alpha and ratio <= 1 + spread))
                        and (best is None or ratio < best[0])):
                    best = (ratio, alternative, entry, beyond)
            if best is None:
                continue
            ratio, alternative, entry, beyond = best
            current, pooled, changed = entry['fit'], None, True
            replaced[name] = (f'{alternative} describes the same with fewer parameters: '
                              f'held-out RMS pooled over the splits x {ratio:.3f} with it in '
                              f'its place; {name} added to it: p = {beyond:.2g}')
            evidence[alternative] = {'round': 'simplified', 'evidence': {
                'f_statistic': entry['f_statistic'], 'p_value': entry['p_value_raw'],
                'explained_rms': entry['size'], 'replaces': name,
                'heldout_ratio_to_replaced': ratio}}
            break           # the names changed: start again from the new model
    return current


def _second_look(machine, splits: list, final: Fit, config: LoopConfig, min_effect: float,
                 evidence: dict) -> tuple[Fit, dict, list | None]:
    """Try, on the final model, the effect that would explain each structure the tests
    flag in its residuals (a period, a trend, a step on one channel), with a flagged
    period among its trial periods. An effect is added where it is significant (its own
    searches counted), identifiable, at least ``min_effect`` and earns its place on the
    held-out rows of every split (``earns_its_place``); then the tests run again.

    Returns the model, per (kind, component, covariate) of a flagged structure what trying
    its effect gave (for the report), and the structure left in the model returned (None
    where it was not tested again)."""
    primary = splits[0]
    tried, notes, flagged = set(), {}, None
    while len(final.effects) < config.max_effects:
        residuals = residuals_by_channel(machine, final, primary.train)
        context = machine.context(final.base, primary.train)
        flagged = structure_tests(machine.channels, residuals,
                                  covariate_columns(machine, context), config.alpha)
        grown = False
        for item in flagged:
            match = matching_candidate(item, machine)
            key = (item['kind'], item['component'], item['covariate'])
            if match is None or match in tried:
                continue
            tried.add(match)
            name, channel = match
            if name in final.names():
                notes[key] = f'{name} is in the model already (a second one is not tried)'
                continue
            hinted = dict(context, period_hint={channel: item['period']}) \
                if 'period' in item else context
            entry = try_candidate(machine, final, name, primary.train, hinted, residuals,
                                   config.alpha, (channel,), {})
            if isinstance(entry, str):
                notes[key] = f'{name} on {channel} not tested: {entry}'
                continue
            # The selection's own rules, the effect's own searches its only trials.
            status = judge(machine, final, entry, primary.train, min_effect, config.alpha, 1)
            why = {'candidate': None, 'not identifiable': entry.get('reason'),
                   'not significant': f'not significant jointly with the model '
                                      f'(p = {entry["p_value"]:.2g})',
                   'below the minimum effect size': f'explains {entry["size"]:.3g} RMS, below '
                                                    'the minimum effect size'}[status]
            if why is None:
                gain = pooled_gain(machine, splits, entry['fit'], name)
                if not earns_its_place(gain):
                    why = f'it does not earn its place on held-out rows: {describe_gain(gain)}'
            if why is not None:
                notes[key] = f'{name} on {channel} tried: {why}'
                continue
            final = entry['fit']
            evidence[name] = {'round': 'structure test', 'evidence': {
                'f_statistic': entry['f_statistic'], 'p_value': entry['p_value_raw'],
                'explained_rms': entry['size'], 'periods_searched': entry['prepared'].trials,
                'from_structure': {k: item[k] for k in ('kind', 'component', 'covariate',
                                                        'p_value') if k in item}}}
            grown = True
            break
        if not grown:
            return final, notes, flagged
        flagged = None
    return final, notes, flagged


def _against_the_inputs(machine, measured, splits: list, final: Fit, config: LoopConfig,
                        rejected: dict) -> tuple[Fit, dict]:
    """``final`` less the effects the uncertainty of the calibration the data were measured
    through could give (:func:`calib_core.closed_loop.inputs.within_calibration`, on every
    row of ``measured``, the machine before any linearisation), their reasons into
    ``rejected``; as it is where the machine has no such calibration or nothing was
    added. What is left is fitted again as the selection fitted it (``machine``, the first
    split's fitting rows). Also each effect's standard deviations from that calibration
    alone (name -> parameter -> sigma; empty without one)."""
    if not final.effects:
        return final, {}
    variants = measured.input_variants()
    if not variants:
        return final, {}
    from calib_core.closed_loop.inputs import within_calibration
    found, shares = within_calibration(measured, variants, final, np.arange(len(measured)),
                                       config.alpha)
    if not found:
        return final, shares
    rejected.update(found)
    effects, values = without_effects(final, tuple(found))
    return (fit_model(machine, final.base, effects, values, splits[0].train)
            if effects else splits[0].base_fit), shares


def analyze(machine: MachineModel, config: LoopConfig = LoopConfig(), progress=None) -> LoopResult:
    """Run the closed loop on ``machine``'s data.

    The selection (steps 2-3 of the module's list) runs on ``config.splits`` hold-out
    splits; an effect is added only if it was chosen in ``config.min_frequency`` of them,
    is identifiable on the first split, explains at least ``min_effect`` and earns its
    place on the held-out rows pooled over every split (no one split vetoes it). Then the
    structure left is tested, and the effect that would explain a flagged structure is
    tried under the same rules (:func:`_second_look`). Before/after are pooled over the
    splits' held-out rows (every row held out at least once), with the spread over the
    splits; an effect chosen on some split but not added is reported under
    ``unexplained`` with its evidence. Where the machine's rows were measured through a
    calibrated instrument (:meth:`MachineModel.input_variants`), each effect is weighed
    against that calibration's uncertainty too, and one it could give is not added
    (:mod:`calib_core.closed_loop.inputs`).

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
    measured = machine            # the machine itself, for what its inputs' calibration gives
    if config.linearise and machine.linearise:
        every = np.arange(len(machine))
        machine = LinearisedModel(machine, fit_model(machine, machine.initial(), [], [],
                                                     every).base)
    splits = []
    for k in range(config.splits):
        report = (lambda done, total, label, k=k: progress(
            done, total, f'split {k + 1}/{config.splits}, {label}')) if progress else None
        splits.append(_select(machine, config, k, min_effect, report))
    positions = {}
    for split in splits:
        for position, item in enumerate(split.added):
            positions.setdefault(item['prepared'].effect.name, []).append(position)
    frequency = {name: len(v) / config.splits for name, v in positions.items()}
    chosen = sorted((n for n in positions if frequency[n] >= config.min_frequency),
                    key=lambda n: (-frequency[n], np.mean(positions[n])))
    final, evidence, not_identifiable, rejected = _build(machine, splits, chosen, config)
    gains = {}
    final = _prune(machine, splits, final, rejected, gains)
    for name in positions:
        if frequency[name] < config.min_frequency:
            rejected[name] = (f'chosen in {len(positions[name])} of {config.splits} hold-out '
                              f'splits, fewer than {config.min_frequency:.0%}: the data do '
                              f'not decide it')
    for split in splits:
        for name, reason in split.not_identifiable.items():
            if name not in final.names():
                not_identifiable.setdefault(name, reason)
    replaced = {}
    final = _simplify(machine, splits, final, config, evidence, replaced)
    looked_at = final.names()
    final, tried, structure = _second_look(machine, splits, final, config, min_effect, evidence)
    if final.names() != looked_at:
        # What the second look added may make an earlier effect replaceable (a drift by
        # approach number and a constant reversal for a step per cycle and a reversal
        # varying with position).
        final = _simplify(machine, splits, final, config, evidence, replaced)
    for name in final.names():
        rejected.pop(name, None)
        not_identifiable.pop(name, None)
    rejected.update(replaced)
    final, shares = _against_the_inputs(machine, measured, splits, final, config, rejected)
    seen = seen_not_added(machine, splits, final, rejected, not_identifiable, gains,
                          explained=set(replaced))
    result = loop_result(machine, config, splits, final, evidence, frequency,
                         not_identifiable, rejected, min_effect, seen, tried, structure)
    result.report['replaced_by_simpler'] = replaced
    for entry in result.report['effects_added']:
        if entry['name'] in shares:
            # What the calibration the data were measured through leaves uncertain, beside
            # the data's own std_devs.
            entry['calibration_std_devs'] = shares[entry['name']]
    return result
