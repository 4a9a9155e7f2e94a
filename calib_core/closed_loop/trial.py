"""Trying one candidate effect on one split: prepared on the current residuals, refitted
jointly with the model in force (replacing what it supersedes), scored by the extra-sum-
of-squares F-test against the pure-error noise, narrowed to the channels the data
determine it on (:func:`try_candidate`); judged for significance, identifiability and size
(:func:`judge`); and, among those accepted in one round, a general effect kept over the
special one it supersedes only when its extra terms are significant
(:func:`prefer_the_simpler`)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.special import fdtrc      # the F distribution's survival function

from calib_core.closed_loop.channels import (
    channel_groups, channel_p_values, determined_channels)
from calib_core.closed_loop.fitting import Fit, fit_model, without_effects
from calib_core.closed_loop.identifiability import (
    minimum_residuals, pure_error_variance, undetermined_reason)
from calib_core.closed_loop.model import prepare_effect
from calib_core.effects import LIBRARY


def try_candidate(machine, current: Fit, name: str, train, context, channel_residuals,
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
             'p_value_raw': min(1.0, float(fdtrc(extra, dof, f_stat)) * prepared.trials),
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
    narrowed = try_candidate(
        machine, current, name, train, context, channel_residuals, alpha, kept,
        {c: f'its term is not significant there (p = {p:.2g})' for c, p in dropped.items()})
    if isinstance(narrowed, str):
        return entry
    narrowed['p_value_raw'] = min(1.0, narrowed['p_value_raw'] * len(p_values))
    return narrowed


def judge(machine, current: Fit, entry: dict, train, min_effect: float, alpha: float,
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


def nested_terms_p_value(general: dict, special: dict) -> float:
    """p-value of the terms a candidate has beyond one it supersedes, both fitted in the
    same round (nested models: F-test of the extra terms against the general one's noise)."""
    extra = general['extra'] - special['extra']
    if extra <= 0:
        return 1.0
    gain = max(special['fit'].rss - general['fit'].rss, 0.0)
    f_stat = gain / extra / max(general['noise'], 1e-300)
    return float(fdtrc(extra, general['dof'], f_stat))


def prefer_the_simpler(accepted: list, alpha: float) -> list:
    """The accepted candidates less those that supersede another accepted one without
    their extra terms being significant at ``alpha``: a reversal that changes along the
    travel is not claimed over a constant one for a 1-sigma slope that happened to lower
    the cross-validated error. The general effect is tried again in the next round, on top
    of the simple one, where only its extra terms are tested."""
    by_name = {e['effect']: e for e in accepted}
    kept = []
    for entry in accepted:
        special = [by_name[n] for n in entry['prepared'].effect.supersedes if n in by_name]
        entry['nested_p_value'] = min((nested_terms_p_value(entry, s) for s in special),
                                      default=None)
        if entry['nested_p_value'] is None or entry['nested_p_value'] < alpha:
            kept.append(entry)
    return kept
