"""Smooth functions of position (Legendre polynomials, degree chosen by BIC): the
reversal that changes along the travel, and the lead error."""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import Effect, Prepared, bic, both_signs


def _legendre_scaled(x: np.ndarray, low: float, high: float, degree: int) -> np.ndarray:
    """Legendre polynomials 1..``degree`` of x mapped from [low, high] onto [-1, 1], (n, degree)."""
    scaled = 2 * (np.asarray(x, float) - low) / (high - low) - 1
    return np.polynomial.legendre.legvander(scaled, degree)[:, 1:]


class _LegendreInPosition(Effect):
    """An effect that is a Legendre polynomial in channel position (over the travel seen
    when prepared), its degree per channel chosen by the Bayesian information criterion
    from ``first_degree`` to :meth:`top_degree`. Subclasses give the columns the effect
    adds, the columns always in the model that the choice is made against, the parameter
    names and why a channel cannot carry the effect."""

    first_degree = 1

    def top_degree(self, x: np.ndarray, d: np.ndarray | None) -> int | str:
        """Highest degree the channel's data determine, or why none."""
        raise NotImplementedError

    def baseline(self, x: np.ndarray, low: float, high: float) -> list:
        """Columns the degree is chosen against (in the model already)."""
        return [np.ones_like(x)]

    def columns(self, x, d, low, high, degree) -> np.ndarray:
        """The effect's columns at ``degree``, (n, parameters)."""
        raise NotImplementedError

    def parameter_names(self, channel: str, degree: int) -> list:
        raise NotImplementedError

    def _prepare(self, context, channels, channel_residuals):
        position, direction = context['position'], context.get('direction')
        layout, names, reasons, trials, searched_by_channel = [], [], [], 1.0, {}
        for c in range(position.shape[1]):
            x, r = position[:, c], channel_residuals[:, c]
            d = None if direction is None else direction[:, c]
            top = self.top_degree(x, d)
            if isinstance(top, str):
                reasons.append(f'{channels[c]}: {top}')
                continue
            low, high = float(x.min()), float(x.max())
            degrees = range(self.first_degree, top + 1)
            criterion = [bic(np.column_stack(self.baseline(x, low, high)
                                              + [self.columns(x, d, low, high, degree)]), r)
                         for degree in degrees]
            degree = degrees[int(np.argmin(criterion))]
            layout.append((c, degree, low, high))
            names += self.parameter_names(channels[c], degree)
            trials *= len(degrees)
            searched_by_channel[channels[c]] = len(degrees)
        if not layout:
            return '; '.join(reasons)
        width = len(channels)

        def term(params, ctx):
            out = np.zeros((len(ctx['position']), width))
            start = 0
            for c, degree, low, high in layout:
                d = None if 'direction' not in ctx else ctx['direction'][:, c]
                basis = self.columns(ctx['position'][:, c], d, low, high, degree)
                out[:, c] = basis @ params[start:start + basis.shape[1]]
                start += basis.shape[1]
            return out

        notes = {'degree': {channels[c]: deg for c, deg, _, _ in layout},
                 'travel_m': {channels[c]: [low, high] for c, _, low, high in layout}}
        if reasons:
            notes['channels_not_tested'] = reasons
        return Prepared(self, tuple(names), ('m',) * len(names), np.zeros(len(names)), term,
                        trials=trials, notes=notes, channel_trials=searched_by_channel)


class ReversalByPosition(_LegendreInPosition):
    """Reversal (lost motion) that changes along the travel: ISO 230-2's reversal per
    target B_i as a smooth function of position. Term per channel:
    -1/2 direction (b0 + sum_k b_k P_k(x)), P_k Legendre polynomials over the travel; the
    degree (up to one less than the targets approached both ways, at most 4) is chosen by
    the Bayesian information criterion. It includes constant ``reversal``, which it
    replaces when added."""

    name = 'reversal_by_position'
    meaning = ('reversal (backlash, lost motion) that changes along the travel: '
               '-1/2 direction (b0 + sum_k b_k P_k(x)), Legendre P_k over the travel')
    requires = ('direction', 'position')
    supersedes = ('reversal',)
    max_degree = 4

    def top_degree(self, x, d):
        targets = np.unique(x)
        if len(targets) > len(x) / 2:       # random positions, not targets
            both = len(targets) if both_signs(d[:, None])[0] else 0
            return self.max_degree if both else (
                'needs three or more targets each approached at least twice from both '
                'directions (0 are)')
        both = sum(1 for t in targets if (d[x == t] > 0).sum() >= 2 and (d[x == t] < 0).sum() >= 2)
        if both - 1 < 1:
            return (f'needs three or more targets each approached at least twice from both '
                    f'directions ({both} are)')
        return min(self.max_degree, both - 1)

    def columns(self, x, d, low, high, degree):
        return -0.5 * d[:, None] * np.column_stack(
            [np.ones_like(x), _legendre_scaled(x, low, high, degree)])

    def parameter_names(self, channel, degree):
        return [f'backlash_{channel}'] + [f'backlash_p{k}_{channel}' for k in range(1, degree + 1)]


class LeadError(_LegendreInPosition):
    """A smooth position error along the travel beyond the base model's scale (cumulative
    lead-screw error, guide or scale non-linearity): Legendre polynomials of degree 2..d
    in position per channel, d chosen by the Bayesian information criterion and kept at
    least two below the number of distinct positions, so the position means stay
    over-determined."""

    name = 'lead_error'
    meaning = ('smooth non-linear position error along the travel (cumulative lead error): '
               'sum_k c_k P_k(x), k = 2..d, Legendre P_k over the travel')
    requires = ('position',)
    first_degree = 2
    max_degree = 5

    def top_degree(self, x, d):
        distinct = len(np.unique(x))
        if distinct - 2 < 2:
            return (f'{distinct} distinct positions are too few (4 needed for a quadratic '
                    f'beyond offset and scale)')
        return min(self.max_degree, distinct - 2)

    def baseline(self, x, low, high):
        # offset and scale: the base model's
        return [np.ones_like(x), _legendre_scaled(x, low, high, 1)[:, 0]]

    def columns(self, x, d, low, high, degree):
        return _legendre_scaled(x, low, high, degree)[:, 1:]

    def parameter_names(self, channel, degree):
        return [f'p{k}_{channel}' for k in range(2, degree + 1)]
