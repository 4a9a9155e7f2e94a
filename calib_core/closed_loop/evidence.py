"""Nothing the loop saw is lost: structure the tests flag is tried by the effect that would
explain it, and an effect chosen on some hold-out splits but not added is reported with
its evidence and the rule that kept it out."""
from __future__ import annotations

import numpy as np

from calib_core.effects import CATEGORICAL_COVARIATES, LIBRARY
from calib_core.closed_loop.fitting import Fit, heldout_errors, without_effects

SEEN_NOT_ADDED = 'seen, not added'
"""The ``kind`` of an ``unexplained`` entry for an effect the selection chose on some
splits that is not in the final model."""

MIN_SPLITS_SEEN = 2
"""An effect chosen on this many splits and not added is reported as seen. Chosen on one
split only it stays under ``rejected``: each split's choice is a test at the loop's alpha,
so on clean data one split of five chooses something about once in 200 runs (a 0.1 um
reversal at p = 1e-4 on a clean stage), which is no finding."""

# (kind of structure, covariate's kind) -> the effect that describes it, most specific
# first; the covariate's kind is its name before the channel suffix (position_leg2 ->
# position), None for any categorical covariate.
_MATCHING = {
    ('periodic', 'position'): ('periodic',),
    ('trend', 'position'): ('scale', 'lead_error'),
    ('trend', 'time'): ('drift_time',),
    ('trend', 'temperature'): ('drift_temperature',),
    ('trend', 'sequence'): ('drift_sequence', 'drift_time'),
    ('trend', 'load'): ('compliance',),
    ('step', None): ('block_step',),
    ('reversal changing with position', 'position'): ('reversal_by_position', 'reversal'),
}


def matching_candidate(item: dict, machine) -> tuple[str, str] | None:
    """(effect, channel) among ``machine``'s candidates that describes the flagged
    structure ``item`` (from :func:`structure_tests`), or None."""
    channel = item['component'].removeprefix('residual_')
    if channel not in machine.channels:
        return None
    covariate = item['covariate']
    kind = None if covariate in CATEGORICAL_COVARIATES else covariate
    for name in machine.channels:
        if covariate.endswith(f'_{name}'):
            if name != channel:
                return None     # another channel's covariate: no per-channel effect says so
            kind = covariate[:-len(name) - 1]
    for effect in _MATCHING.get((item['kind'], kind), ()):
        if effect in machine.candidates:
            return effect, channel
    return None


MIN_HELDOUT_GAIN = 0.01
"""An effect must lower the held-out RMS, pooled over the splits, by this share to stay:
a gain of less than 1 % is no reason to change a machine's model. The held-out maximum
may not grow by more than this share or by more than the RMS falls (a row it does not
touch keeps its error to rounding, hence a share, not zero)."""


def pooled_gain(machine, splits: list, fit: Fit, name: str, with_all: dict | None = None) -> dict:
    """How much effect ``name`` of ``fit`` lowers the held-out error over every split (each
    refitted on the split's fitting rows with and without it): ``gain`` (share of the pooled
    held-out RMS), the pooled RMS with and without it, the held-out maxima's ratio per split
    (``max_ratios``) and the ratio the maximum may grow by (``allowed``). ``with_all``:
    ``fit``'s own held-out errors where they were computed already."""
    with_all = with_all or heldout_errors(machine, splits, fit.effects, fit.values, fit)
    effects, values = without_effects(fit, (name,))
    without = heldout_errors(machine, splits, effects, values, fit)
    gain = 1 - np.sqrt(with_all['sum_of_squares'] / without['sum_of_squares'])
    # The maximum may grow by no more than the RMS falls: a few rows the effect does not
    # describe (named under outliers) must not veto a real effect, and a small RMS gain
    # must not buy a larger worst error.
    allowed = 1 + MIN_HELDOUT_GAIN if gain <= 0 else max(1 + MIN_HELDOUT_GAIN, 1 / (1 - gain))
    return {'gain': float(gain),
            'rms_with': float(np.sqrt(with_all['sum_of_squares'] / with_all['count'])),
            'rms_without': float(np.sqrt(without['sum_of_squares'] / without['count'])),
            'max_ratios': np.array(with_all['maxima']) / np.array(without['maxima']),
            'allowed': float(allowed)}


def earns_its_place(gain: dict) -> bool:
    """The rule of :func:`_prune` on a :func:`pooled_gain`: the pooled held-out RMS falls by
    :data:`MIN_HELDOUT_GAIN` and the maximum grows by no more than allowed on most splits.
    All the splits decide together: no one split's rows (a random third) veto an effect the
    others support."""
    return gain['gain'] >= MIN_HELDOUT_GAIN and np.median(gain['max_ratios']) <= gain['allowed']


def describe_gain(gain: dict) -> str:
    return (f'held-out RMS pooled over the splits {gain["rms_with"]:.3g} with it, '
            f'{gain["rms_without"]:.3g} without ({gain["gain"]:+.1%}, {MIN_HELDOUT_GAIN:.0%} '
            f'needed); held-out max with / without it {np.median(gain["max_ratios"]):.3f} '
            f'(median over the splits, at most {gain["allowed"]:.3f} allowed)')


def seen_not_added(machine, splits: list, final: Fit, rejected: dict,
                   not_identifiable: dict, gains: dict, explained: set = frozenset()) -> list:
    """An ``unexplained`` entry for every effect the selection chose (significant after
    every correction) on :data:`MIN_SPLITS_SEEN` splits or more, on one channel that often
    where it acts per channel, that is not in the final model: the splits it was chosen
    on, its p-values and size there, the channels, the pooled held-out gain where it was
    measured and the rule that kept it out. Effects ``explained`` by another in the model
    (replaced by a simpler one) are not."""
    chosen = {}
    for split in splits:
        for item in split.added:
            chosen.setdefault(item['prepared'].effect.name, []).append(item)
    out = []
    for name, items in chosen.items():
        if name in final.names() or name in explained or len(items) < MIN_SPLITS_SEEN:
            continue
        counts = {}
        for item in items:
            for channel in item['channels'] or ():
                counts[channel] = counts.get(channel, 0) + 1
        channels = sorted(c for c, n in counts.items() if n >= MIN_SPLITS_SEEN)
        if counts and not channels:
            continue    # chosen on a different channel each time: no channel's finding
        p_values = [item['evidence']['p_value'] for item in items]
        why = rejected.get(name) or not_identifiable.get(name) or 'not kept in the final model'
        entry = {'kind': SEEN_NOT_ADDED, 'effect': name,
                 'component': f'residual_{channels[0]}' if len(channels) == 1 else 'residual',
                 'channels': channels, 'channel_counts': counts,
                 'covariate': next(iter(LIBRARY[name].requires), 'block'),
                 'splits_chosen': len(items), 'splits': len(splits),
                 'p_value': float(np.median(p_values)), 'p_values': p_values,
                 'structure_rms': float(np.median([i['evidence']['explained_rms']
                                                   for i in items])),
                 'why_not_added': why,
                 'likely_causes': f'{LIBRARY[name].meaning}, which the data support too '
                                  'weakly or too unevenly to put in the model'}
        if name in gains:
            entry['pooled_gain'] = gains[name]['gain']
        out.append(entry)
    return sorted(out, key=lambda e: (-e['splits_chosen'], e['p_value']))
