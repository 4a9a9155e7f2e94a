"""Cyclic errors (a lead screw's once-per-revolution error and its harmonics), with
the periods a sampling grid can and cannot resolve."""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import Effect, Prepared, bic
from calib_core.periodogram import explained_power


def resolvable_periods(position: np.ndarray) -> tuple[float, float, str]:
    """The periods (m) the distinct positions of one channel can resolve.

    The shortest is twice the median spacing of the distinct positions (their Nyquist
    period; a shorter period aliases onto a longer one on a regular grid); the longest
    is half the travel (a longer one is a trend that scale and offset already describe).

    Returns
    -------
    shortest, longest : float
        m; ``shortest >= longest`` when no period is resolvable.
    need : str
        What the data would need to resolve periods, for the report.
    """
    distinct = np.unique(position)
    span = float(np.ptp(distinct)) if len(distinct) else 0.0
    if len(distinct) < 3 or span <= 0:
        return np.inf, 0.0, 'positions at three or more distinct targets'
    spacing = float(np.median(np.diff(distinct)))
    shortest, longest = 2 * spacing, span / 2
    need = (f'targets every {spacing * 1e3:.3g} mm resolve periods from '
            f'{shortest * 1e3:.3g} mm to {longest * 1e3:.3g} mm (half the travel); targets '
            f'every P/2 or closer (irregularly spaced, as ISO 230-2 recommends) resolve '
            f'periods down to P')
    return shortest, longest, need


SEARCH_TRIALS_PER_RESOLUTION = 3.0
"""Independent alternatives a refined periodogram search counts per resolution element
(1 / span of frequency): a peak searched continuously finds the best of about three times
as many independent frequencies as the band holds resolution elements (Horne and
Baliunas 1986 find about 120 for 100 points searched to their Nyquist frequency, which
hold 50). Counted as one per element, the structure test on pure noise claimed a period
in 7.8 % of 400 runs at a nominal 2.5 %; with three, 2.5 % (test/test_significance.py)."""


def search_trials(f_low: float, f_high: float, span: float) -> float:
    """Independent alternatives of a periodogram search over [f_low, f_high] (1/m) of
    positions spanning ``span`` m, for the look-elsewhere correction: at least 1."""
    return max(SEARCH_TRIALS_PER_RESOLUTION * (f_high - f_low) * span, 1.0)


def grid_spacing(position: np.ndarray, tolerance: float = 0.01) -> float | None:
    """The step (m) of the regular grid the distinct positions lie on (each within
    ``tolerance`` of a step from the first), or None when they are irregular."""
    distinct = np.unique(position)
    if len(distinct) < 3:
        return None
    step = float(np.median(np.diff(distinct)))
    if step <= 0:
        return None
    offsets = (distinct - distinct[0]) / step
    return step if np.all(np.abs(offsets - np.round(offsets)) < tolerance) else None


def alias_periods(period: float, spacing: float, count: int = 4) -> list:
    """The periods (m) that take the same values as ``period`` at every position of a grid
    of step ``spacing``: 1 / |k / spacing -+ 1 / period| for k = 1, 2, ..., the ``count``
    longest (shorter ones need ever finer screws)."""
    f, fs = 1.0 / period, 1.0 / spacing
    found = sorted({1.0 / abs(k * fs + sign * f) for k in range(1, count + 1)
                    for sign in (-1, 1) if abs(k * fs + sign * f) > 1e-12}, reverse=True)
    return [p for p in found if abs(p - period) > 1e-3 * period][:count]


class Periodic(Effect):
    """Cyclic error per channel, with its harmonics where the positions resolve them.

    The period comes from a Lomb-Scargle periodogram of the channel residuals against the
    channel position, searched only over the periods the distinct positions resolve
    (:func:`resolvable_periods`), then refined in the joint fit. A period whose
    periodogram has another peak almost as high (an alias, or two periods the data fit
    equally) is refused as not determined. Harmonics 2 and 3 enter when their period is
    still resolvable and the Bayesian information criterion prefers them. On a regular grid
    of targets, a period outside the searched band takes the same values at every target as
    one inside it: the report names the grid's step (``grid_spacing_m``), and the loop's
    report the aliases of the fitted period (``aliases_m``).
    """

    name = 'periodic'
    meaning = ('cyclic error per channel (lead-screw wobble, encoder interpolation), '
               'amplitude, period and harmonics found from the data')
    requires = ('position',)
    min_samples = 20
    parameters_per_position = 2   # distinct positions needed per amplitude parameter
    alias_ratio = 0.9             # a second peak this high makes the period ambiguous
    max_harmonics = 3

    def _channel(self, x: np.ndarray, r: np.ndarray, hint: float | None = None):
        """(period, harmonics, trials) for one channel, or a reason string. A ``hint``
        (m; a period the loop's structure test found by the same search) is taken as the
        period where the positions resolve it; the search's trials still count."""
        shortest, longest, need = resolvable_periods(x)
        distinct = len(np.unique(x))
        if shortest >= longest:
            return f'no period is resolvable: {need}'
        # offset, scale and one sine (2 amplitudes + period) must leave position means over
        needed = 2 + self.parameters_per_position * 3
        if distinct < needed:
            return (f'{distinct} distinct positions are too few for a free-period sine '
                    f'on top of offset and scale (needs {needed}): {need}')
        f_low, f_high = 1 / longest, 1 / shortest
        span = float(np.ptp(x))
        count = int(min(20000, max(200, 10 * (f_high - f_low) * span)))
        freqs = np.linspace(f_low, f_high, count)
        power = explained_power(x, r - r.mean(), freqs)
        if hint is not None and f_low <= 1 / hint <= f_high:
            # The hinted peak wins; its rivals were weighed by the search that found it.
            freqs = np.append(freqs, 1 / hint)
            power = np.append(power, np.inf)
        best = int(np.argmax(power))
        # Peaks closer than 1/span are one peak; harmonics of the best are not rivals.
        separation = 1.0 / span
        related = [freqs[best] * k for k in (1, 2, 3, 1 / 2, 1 / 3)]
        apart = np.all([np.abs(freqs - f) > separation for f in related], axis=0)
        rivals = power[apart]
        if rivals.size and rivals.max() >= self.alias_ratio * power[best]:
            rival = freqs[apart][np.argmax(rivals)]
            return (f'period not determined: {1e3 / freqs[best]:.4g} mm and '
                    f'{1e3 / rival:.4g} mm fit the data almost equally ({need})')
        period = 1.0 / freqs[best]
        # The fundamental is resolvable by construction (rounding aside); harmonics must be.
        harmonics = [1] + [h for h in range(2, self.max_harmonics + 1) if period / h >= shortest
                           and distinct >= 2 + self.parameters_per_position * (2 * h + 1)]
        criterion = []
        for h in harmonics:
            criterion.append(bic(np.column_stack([np.ones_like(x)]
                                                  + _harmonic_columns(x, period, h)), r))
        chosen = harmonics[int(np.argmin(criterion))]
        return period, chosen, search_trials(f_low, f_high, span) * len(harmonics)

    def _prepare(self, context, channels, channel_residuals):
        position = context['position']
        if len(position) < self.min_samples:
            return (f'{len(position)} rows are too few to find a period '
                    f'(needs {self.min_samples})')
        found, reasons, trials, searched_by_channel = [], [], 1.0, {}
        hints = context.get('period_hint', {})
        for c in range(position.shape[1]):
            result = self._channel(position[:, c], channel_residuals[:, c],
                                   hints.get(channels[c]))
            if isinstance(result, str):
                reasons.append(f'{channels[c]}: {result}' if len(channels) > 1 else result)
                continue
            period, harmonics, searched = result
            found.append((c, period, harmonics))
            trials *= searched
            searched_by_channel[channels[c]] = searched
        if not found:
            return '; '.join(reasons)
        width = len(channels)
        names, units, initial, layout = [], [], [], []
        for c, period, harmonics in found:
            x, r = position[:, c], channel_residuals[:, c]
            columns = _harmonic_columns(x, period, harmonics)
            design = np.column_stack([np.ones_like(x)] + columns)
            amplitudes = np.linalg.lstsq(design, r, rcond=None)[0][1:]
            for h in range(1, harmonics + 1):
                suffix = '' if h == 1 else str(h)
                names += [f'cos{suffix}_{channels[c]}', f'sin{suffix}_{channels[c]}']
            names.append(f'period_{channels[c]}')
            units += ['m'] * (2 * harmonics + 1)
            initial += list(amplitudes) + [period]
            layout.append((c, harmonics))

        def term(params, ctx):
            out = np.zeros((len(ctx['position']), width))
            start = 0
            for c, harmonics in layout:
                amplitudes = params[start:start + 2 * harmonics]
                period = params[start + 2 * harmonics]
                columns = _harmonic_columns(ctx['position'][:, c], period, harmonics)
                out[:, c] = np.column_stack(columns) @ amplitudes
                start += 2 * harmonics + 1
            return out

        notes = {'harmonics': {channels[c]: h for c, h in layout},
                 'resolvable_periods_m': {channels[c]: list(resolvable_periods(position[:, c])[:2])
                                          for c, _ in layout}}
        spacing = {channels[c]: grid_spacing(position[:, c]) for c, _ in layout}
        if any(step is not None for step in spacing.values()):
            notes['grid_spacing_m'] = {k: v for k, v in spacing.items() if v is not None}
        if reasons:
            notes['channels_not_tested'] = reasons
        return Prepared(self, tuple(names), tuple(units), np.array(initial, float), term,
                        trials=trials, notes=notes, channel_trials=searched_by_channel)


def _harmonic_columns(x: np.ndarray, period: float, harmonics: int) -> list:
    """cos and sin of harmonics 1..``harmonics`` of ``period`` at ``x``."""
    columns = []
    for h in range(1, harmonics + 1):
        phase = 2 * np.pi * h * x / period
        columns += [np.cos(phase), np.sin(phase)]
    return columns
