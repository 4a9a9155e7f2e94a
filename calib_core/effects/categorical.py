"""Effects of labels rather than numbers: a step between measurement blocks or set-ups,
and the first-approach (warm-up) transient."""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import Effect, Prepared


CATEGORICAL_COVARIATES = ('block', 'setup', 'run', 'cycle')
"""Covariate columns read as categories (labels, not quantities): a step between their
levels is the ``block_step`` effect and a structure test."""


class BlockStep(Effect):
    """A step between measurement blocks or set-ups: a constant shift per level of a
    categorical covariate, the first level the reference (its shift is the base model's
    offset). Among the covariates present, the Bayesian information criterion chooses."""

    name = 'block_step'
    meaning = ('step between measurement blocks or set-ups: a constant shift per level of '
               'a categorical covariate (block, setup, run or cycle), first level = reference')
    min_rows_per_level = 3

    def prepare(self, context, channels, channel_residuals):
        present = [k for k in CATEGORICAL_COVARIATES if k in context]
        if not present:
            return ('needs a categorical covariate (block, setup, run or cycle), which the '
                    'data lack')
        usable, reasons = [], []
        for key in present:
            levels, counts = np.unique(context[key], return_counts=True)
            if len(levels) < 2:
                reasons.append(f'{key} takes one value')
            elif counts.min() < self.min_rows_per_level:
                reasons.append(f'{key} has a level with {counts.min()} row(s), '
                               f'{self.min_rows_per_level} needed per level')
            else:
                usable.append((key, levels))
        if not usable:
            return '; '.join(reasons)
        best = None
        for key, levels in usable:
            design = np.column_stack([np.ones(len(context[key]))]
                                     + [context[key] == level for level in levels[1:]])
            rss = sum(float(np.sum((r - design @ np.linalg.lstsq(design, r, rcond=None)[0]) ** 2))
                      for r in channel_residuals.T)
            # Bayesian information criterion: more levels must earn their parameters
            count = channel_residuals.size
            criterion = (count * np.log(max(rss, 1e-300) / count)
                         + design.shape[1] * channel_residuals.shape[1] * np.log(count))
            if best is None or criterion < best[0]:
                best = (criterion, key, levels)
        _, key, levels = best
        width = len(channels)
        steps = levels[1:]

        def term(params, ctx):
            indicator = np.column_stack([ctx[key] == level for level in steps]).astype(float)
            return indicator @ params.reshape(len(steps), width)

        names = tuple(f'step_{key}{_label(level)}_{channel}' for level in steps
                      for channel in channels)
        return Prepared(self, names, ('m',) * len(names), np.zeros(len(names)), term,
                        trials=float(len(usable)),
                        notes={'covariate': key, 'reference_level': _label(levels[0])})


def _label(level: float) -> str:
    return str(int(level)) if float(level).is_integer() else f'{level:g}'


class WarmUp(Effect):
    """A transient at the start of a run (warm-up, the first approach from far away):
    term = a exp(-s / tau) per channel, s the approach number from the start of the run
    (``sequence``, 0 first) or the time since the start; tau is searched over a grid."""

    name = 'warm_up'
    meaning = ('transient at the start of a run (warm-up, first approach): '
               'a exp(-s / tau), s the approach number or time since the start')
    sequence_taus = (0.5, 1.0, 2.0, 4.0, 8.0)         # approaches
    time_fractions = (0.01, 0.03, 0.1, 0.3)            # of the run's duration

    def prepare(self, context, channels, channel_residuals):
        if 'sequence' in context:
            key, taus, unit = 'sequence', self.sequence_taus, 'approaches'
        elif 'time' in context:
            key, unit = 'time', 's'
            taus = tuple(f * max(float(np.ptp(context['time'])), 1e-9) for f in self.time_fractions)
        else:
            return 'needs covariate sequence (approach number) or time, which the data lack'
        since = context[key] - context.get(f'{key}_start', float(np.min(context[key])))
        if np.ptp(since) <= 0:
            return f'{key} is constant in the data'
        best = None
        for tau in taus:
            basis = np.exp(-since / tau)
            if np.sum(basis > 0.05) < 1:
                continue
            design = np.column_stack([np.ones_like(basis), basis])
            rss = sum(float(np.sum((r - design @ np.linalg.lstsq(design, r, rcond=None)[0]) ** 2))
                      for r in channel_residuals.T)
            if best is None or rss < best[0]:
                best = (rss, tau)
        if best is None:
            return f'no approach lies near the start of the run ({key})'
        tau = best[1]
        width = len(channels)
        start = context.get(f'{key}_start', float(np.min(context[key])))

        def term(params, ctx):
            return np.exp(-(ctx[key] - start) / tau)[:, None] * params[None, :width]

        return Prepared(self, tuple(f'amplitude_{c}' for c in channels), ('m',) * width,
                        np.zeros(width), term, trials=float(len(taus)),
                        notes={'time_constant': tau, 'time_constant_unit': unit,
                               'covariate': key})
