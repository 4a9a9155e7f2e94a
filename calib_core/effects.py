"""The closed loop's effect library: physical effects a machine model may lack.

An effect adds a term to the machine's *channels*: the quantities it acts on directly,
such as an axis position (m), a hexapod leg length (m) or a normalised image coordinate.
Each machine says what its channels are and supplies the covariates an effect needs in a
*context* (a dict of arrays for the rows being evaluated):

``position``     (n, C) channel positions, m (axis command, gantry axis, leg length)
``direction``    (n, C) direction of approach, +1 from below, -1 from above
``time``         (n,) s, ``temperature`` (n,) K (differences matter, not the zero)
``load``         (n, C) static axial force per channel, N, compression positive
``normalized``   (n, 2) normalised image coordinates of a camera (x/z, y/z)

Names are stable (they appear in reports):

==========================  ============================================================
``offset``                  constant shift per channel (m)
``scale``                   scale error per channel, term = s * position (1)
``squareness``              non-orthogonality of two axes: channel 0 gains gamma * position 1 (rad)
``reversal``                backlash / lost motion: the carriage lags the drive by b/2 against
                            the direction of approach, term = -b/2 * direction (m)
``periodic``                cyclic error per channel, e.g. once per lead-screw revolution,
                            a cos(2 pi x / P) + b sin(2 pi x / P), period P found from the data (m)
``drift_time``              linear drift with time, term = rate * (t - t_ref) (m/s)
``drift_temperature``       thermal expansion and zero drift, term = (k x + c) (T - T_ref)
                            (k in 1/K, c in m/K)
``radial_distortion``       lens distortion k1, k2 (OpenCV): x_n (k1 r^2 + k2 r^4) (1)
``tangential_distortion``   decentring distortion p1, p2 (OpenCV) (1)
``leg_play``                joint play taken up by the static leg force,
                            term = -play/2 * sign(load) (m)
``compliance``              elastic deflection, term = -c * load (m/N)
==========================  ============================================================
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.signal import lombscargle
from scipy.stats import binomtest


@dataclass(frozen=True)
class Prepared:
    """An effect set up for one dataset: its free parameters and how they enter.

    Attributes
    ----------
    effect : Effect
    names, units : tuple of str
        One per parameter (channel names are part of the parameter names).
    initial : ndarray (p,)
    term : callable (params (p,), context) -> ndarray (n, C)
    trials : float
        Independent alternatives searched while preparing (periods scanned), for the
        look-elsewhere correction of the significance test; 1 for effects with nothing
        searched.
    determined : callable (context) -> bool ndarray (p,), optional
        Which parameters the rows of ``context`` can determine. A fit on other rows than
        those prepared on (another hold-out split) holds the others at their given values
        instead of letting them drift along a direction the data do not constrain.
    """

    effect: 'Effect'
    names: tuple
    units: tuple
    initial: np.ndarray
    term: Callable
    trials: float = 1.0
    notes: dict = field(default_factory=dict)
    determined: Callable | None = None

    def describe(self, values: np.ndarray, std_devs: np.ndarray) -> dict:
        """Parameters (SI) and their 1-sigma standard deviations, as a report entry."""
        out = {'name': self.effect.name, 'meaning': self.effect.meaning,
               'parameters': dict(zip(self.names, map(float, values))),
               'std_devs': dict(zip(self.names, map(float, std_devs))),
               'units': dict(zip(self.names, self.units))}
        out.update(self.notes)
        return out


class Effect:
    """A candidate effect. Subclasses set ``name``, ``meaning``, ``requires`` and
    implement :meth:`_prepare`."""

    name = ''
    meaning = ''
    requires: tuple = ()
    supersedes: tuple = ()   # effects this one includes and replaces when added

    def prepare(self, context: dict, channels: tuple, channel_residuals: np.ndarray):
        """A :class:`Prepared` for this data, or a string saying why the effect cannot be
        tested on it (a covariate in ``requires`` missing, or the data cannot show it)."""
        lacking = [k for k in self.requires if k not in context]
        if lacking:
            return f'needs covariate(s) {", ".join(lacking)}, which the data lack'
        return self._prepare(context, channels, channel_residuals)

    def _prepare(self, context: dict, channels: tuple, channel_residuals: np.ndarray):
        raise NotImplementedError


class _FixedParameters(Effect):
    """An effect whose parameters (``parameters``, ``units``) do not depend on the data
    and start at zero; subclasses implement :meth:`term` and may refuse data in
    :meth:`unobservable`."""

    parameters: tuple = ()
    units: tuple = ()

    def unobservable(self, context: dict) -> str | None:
        return None

    def term(self, params: np.ndarray, context: dict) -> np.ndarray:
        raise NotImplementedError

    def _prepare(self, context, channels, channel_residuals):
        reason = self.unobservable(context)
        if reason:
            return reason
        return Prepared(self, self.parameters, self.units, np.zeros(len(self.parameters)),
                        self.term)


def _varying(values: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
    """Which columns of ``values`` (n, C) take more than one value."""
    return np.ptp(values, axis=0) > tolerance


def _both_signs(values: np.ndarray, needed: int = 5) -> np.ndarray:
    """Which columns of ``values`` (n, C) have ``needed`` rows of each sign: enough for a
    sign-dependent term to be told from an offset in every cross-validation fold."""
    return ((values > 0).sum(axis=0) >= needed) & ((values < 0).sum(axis=0) >= needed)


class _PerChannel(Effect):
    """An effect linear in one parameter per channel: term[:, c] = p_c * basis[:, c]."""

    covariate = 'position'
    unit = 'm'
    suffix = ''

    def basis(self, context: dict, width: int) -> np.ndarray:
        """The term per unit parameter, shape (n, width)."""
        raise NotImplementedError

    def active(self, context: dict, width: int) -> np.ndarray:
        """Which channels the data can inform, shape (width,) bool."""
        return _varying(self.basis(context, width))

    def inactive_reason(self) -> str:
        return f'{self.covariate} does not vary in any channel'

    def _prepare(self, context, channels, channel_residuals):
        width = len(channels)
        active = self.active(context, width)
        if not active.any():
            return self.inactive_reason()
        index = np.flatnonzero(active)

        def term(params, ctx, basis=self.basis, index=index, width=width):
            b = basis(ctx, width)
            out = np.zeros((len(b), width))
            out[:, index] = b[:, index] * params
            return out

        names = tuple(f'{self.suffix}_{channels[i]}' if self.suffix else channels[i]
                      for i in index)
        return Prepared(self, names, (self.unit,) * len(index), np.zeros(len(index)), term)


class Offset(_PerChannel):
    name, meaning, requires = 'offset', 'constant shift of each channel', ('position',)
    suffix = 'offset'

    def active(self, context, width):
        return np.ones(width, dtype=bool)

    def basis(self, context, width):
        return np.ones((len(context['position']), width))


class Scale(_PerChannel):
    name, meaning, requires = 'scale', 'scale (length) error of each channel', ('position',)
    unit, suffix = '1', 'scale'

    def basis(self, context, width):
        return context['position']


class Reversal(_PerChannel):
    name = 'reversal'
    meaning = ('backlash / lost motion: the driven part lags by b/2 against the direction of '
               'approach')
    requires, covariate, suffix = ('direction',), 'direction', 'backlash'

    def active(self, context, width):
        return _both_signs(context['direction'])

    def inactive_reason(self):
        return ('no channel is approached often enough from both directions: backlash '
                'cannot be told from an offset')

    def basis(self, context, width):
        return -0.5 * context['direction']


class DriftTime(_PerChannel):
    name, meaning, requires = 'drift_time', 'linear drift of each channel with time', ('time',)
    covariate, unit, suffix = 'time', 'm/s', 'rate'

    def inactive_reason(self):
        return 'time is constant in the data'

    def basis(self, context, width):
        t = context['time'] - context.get('time_ref', 0.0)
        return np.repeat(t[:, None], width, axis=1)


class LegPlay(Effect):
    """Joint play per leg. Where the static force is large it holds the play closed on one
    side; below a closing force (found from the data among ``thresholds``, down to zero)
    the play stays where the last move left it, so the direction of approach decides,
    when known.

    A leg whose play side changes too rarely in the data for its own play to be told from
    its actuator offset (fewer than 5 rows on one side) still carries play where it does
    change: such legs take the mean play of the legs that were fitted (one design, one
    play), which the report names in ``legs_with_mean_play``."""

    name = 'leg_play'
    meaning = ('joint play taken up by the static leg force: compression shortens a leg by '
               'play/2, tension lengthens it; below the closing force the last move decides')
    requires = ('load',)
    thresholds = (0.0, 1.0, 2.0, 5.0, 10.0, 20.0)   # N

    @staticmethod
    def side(context: dict, threshold: float) -> np.ndarray:
        """Which side (+1 / -1) the play sits on, (n, C)."""
        load = context['load']
        weak = np.abs(load) < threshold
        direction = context.get('direction')
        if direction is None:
            return np.sign(load)
        return np.where(weak, direction, np.sign(load))

    @staticmethod
    def _fit_legs(side, residuals, index):
        """Per leg in ``index``: play and offset fitted to the residuals, (2, len(index))."""
        return np.array([np.linalg.lstsq(np.column_stack([-0.5 * side[:, c], np.ones(len(side))]),
                                         residuals[:, c], rcond=None)[0] for c in index]).T

    def _choose_threshold(self, context, residuals, index):
        """The closing force (N) whose play sides best explain the residuals of the legs in
        ``index``, each leg's play and offset held at their fit without a low-force regime.

        Holding the fit makes the rows whose side differs between two thresholds decide,
        each by about the play squared (refitting per threshold would let a few such rows
        move the play and offset of the whole leg). A closing force above zero must also
        win a sign test on those rows (most of them better explained by the direction of
        the last move, p < 0.05): near zero force the computed force's sign is itself
        uncertain, and a few rows where it is wrong must not switch the whole regime."""
        zero = self.side(context, 0.0)[:, index]
        play, offset = self._fit_legs(self.side(context, 0.0), residuals, index)

        def row_costs(side):
            return (residuals[:, index] + 0.5 * side * play - offset) ** 2

        base = row_costs(zero)
        best, best_cost = 0.0, float(np.sum(base))
        for threshold in self.thresholds[1:]:
            side = self.side(context, threshold)[:, index]
            cost = row_costs(side)
            differ = side != zero
            votes = int(np.sum(cost[differ] < base[differ]))
            if (float(np.sum(cost)) < best_cost and
                    binomtest(votes, int(differ.sum()), alternative='greater').pvalue < 0.05):
                best, best_cost = threshold, float(np.sum(cost))
        return best

    def _prepare(self, context, channels, channel_residuals):
        index = np.flatnonzero(_both_signs(context['load']))
        if 'direction' in context and len(index):
            threshold = self._choose_threshold(context, channel_residuals, index)
            index = np.flatnonzero(_both_signs(self.side(context, threshold)))
        else:
            threshold = 0.0
        if not len(index):
            return ('no leg\'s static force changes sign often enough: play cannot be told '
                    'from an offset')
        thresholds = self.thresholds if 'direction' in context else (0.0,)
        width = len(channels)
        # Legs whose side changes at all but too rarely to fit their own play.
        rare = np.setdiff1d(np.flatnonzero(_both_signs(self.side(context, threshold), 1)), index)

        def term(params, ctx):
            side = self.side(ctx, threshold)
            out = np.zeros((len(side), width))
            out[:, index] = -0.5 * side[:, index] * params
            out[:, rare] = -0.5 * side[:, rare] * np.mean(params)
            return out

        def determined(ctx):
            # A leg's play is told from its actuator offset only by rows on both sides.
            return _both_signs(self.side(ctx, threshold)[:, index], 1)

        notes = {'force_to_close_play_N': threshold}
        if len(rare):
            notes['legs_with_mean_play'] = [channels[i] for i in rare]
        return Prepared(self, tuple(f'play_{channels[i]}' for i in index),
                        ('m',) * len(index), np.zeros(len(index)), term,
                        trials=float(len(thresholds)), notes=notes, determined=determined)


class Compliance(_PerChannel):
    name, meaning = 'compliance', 'elastic deflection proportional to the static load'
    requires, covariate, unit, suffix = ('load',), 'load', 'm/N', 'compliance'

    def inactive_reason(self):
        return 'the static load does not vary in any channel'

    def basis(self, context, width):
        return -context['load']


class Squareness(_FixedParameters):
    name = 'squareness'
    meaning = 'non-orthogonality of two axes: the first axis picks up gamma times the second'
    requires, parameters, units = ('position',), ('gamma',), ('rad',)

    def unobservable(self, context):
        position = context['position']
        if position.shape[1] != 2:
            return f'needs exactly two axes, the model has {position.shape[1]} channel(s)'
        if not _varying(position).all():
            return 'both axes must move for squareness to be observable'
        return None

    def term(self, params, context):
        out = np.zeros_like(context['position'])
        out[:, 0] = params[0] * context['position'][:, 1]
        return out


class DriftTemperature(Effect):
    name = 'drift_temperature'
    meaning = ('thermal expansion (k, 1/K, proportional to position) and zero drift '
               '(c, m/K) with temperature')
    requires = ('temperature', 'position')

    def _prepare(self, context, channels, channel_residuals):
        if np.ptp(context['temperature']) <= 0:
            return 'temperature is constant in the data'
        count = len(channels)

        def term(params, ctx):
            k, c = params[:count], params[count:]
            dt = (ctx['temperature'] - ctx.get('temperature_ref', 0.0))[:, None]
            return (k * ctx['position'] + c) * dt

        names = tuple(f'expansion_{c}' for c in channels) + tuple(f'zero_drift_{c}' for c in channels)
        return Prepared(self, names, ('1/K',) * count + ('m/K',) * count,
                        np.zeros(2 * count), term)


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


class Periodic(Effect):
    """Cyclic error per channel, with its harmonics where the positions resolve them.

    The period comes from a Lomb-Scargle periodogram of the channel residuals against the
    channel position, searched only over the periods the distinct positions resolve
    (:func:`resolvable_periods`), then refined in the joint fit. A period whose
    periodogram has another peak almost as high (an alias, or two periods the data fit
    equally) is refused as not determined. Harmonics 2 and 3 enter when their period is
    still resolvable and the Bayesian information criterion prefers them.
    """

    name = 'periodic'
    meaning = ('cyclic error per channel (lead-screw wobble, encoder interpolation), '
               'amplitude, period and harmonics found from the data')
    requires = ('position',)
    min_samples = 20
    parameters_per_position = 2   # distinct positions needed per amplitude parameter
    alias_ratio = 0.9             # a second peak this high makes the period ambiguous
    max_harmonics = 3

    def _channel(self, x: np.ndarray, r: np.ndarray):
        """(period, harmonics, trials) for one channel, or a reason string."""
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
        power = lombscargle(x, r - r.mean(), 2 * np.pi * freqs, floating_mean=True)
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
            criterion.append(_bic(np.column_stack([np.ones_like(x)]
                                                  + _harmonic_columns(x, period, h)), r))
        chosen = harmonics[int(np.argmin(criterion))]
        return period, chosen, max((f_high - f_low) * span, 1.0) * len(harmonics)

    def _prepare(self, context, channels, channel_residuals):
        position = context['position']
        if len(position) < self.min_samples:
            return (f'{len(position)} rows are too few to find a period '
                    f'(needs {self.min_samples})')
        found, reasons, trials = [], [], 1.0
        for c in range(position.shape[1]):
            result = self._channel(position[:, c], channel_residuals[:, c])
            if isinstance(result, str):
                reasons.append(f'{channels[c]}: {result}' if len(channels) > 1 else result)
                continue
            period, harmonics, searched = result
            found.append((c, period, harmonics))
            trials *= searched
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
        if reasons:
            notes['channels_not_tested'] = reasons
        return Prepared(self, tuple(names), tuple(units), np.array(initial, float), term,
                        trials=trials, notes=notes)


def _bic(design: np.ndarray, r: np.ndarray) -> float:
    """Bayesian information criterion of the least-squares fit of ``r`` (n,) on
    ``design`` (n, p): n log(RSS / n) + p log n."""
    rss = float(np.sum((r - design @ np.linalg.lstsq(design, r, rcond=None)[0]) ** 2))
    return len(r) * np.log(max(rss, 1e-300) / len(r)) + design.shape[1] * np.log(len(r))


def _harmonic_columns(x: np.ndarray, period: float, harmonics: int) -> list:
    """cos and sin of harmonics 1..``harmonics`` of ``period`` at ``x``."""
    columns = []
    for h in range(1, harmonics + 1):
        phase = 2 * np.pi * h * x / period
        columns += [np.cos(phase), np.sin(phase)]
    return columns


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
        layout, names, reasons, trials = [], [], [], 1.0
        for c in range(position.shape[1]):
            x, r = position[:, c], channel_residuals[:, c]
            d = None if direction is None else direction[:, c]
            top = self.top_degree(x, d)
            if isinstance(top, str):
                reasons.append(f'{channels[c]}: {top}')
                continue
            low, high = float(x.min()), float(x.max())
            degrees = range(self.first_degree, top + 1)
            criterion = [_bic(np.column_stack(self.baseline(x, low, high)
                                              + [self.columns(x, d, low, high, degree)]), r)
                         for degree in degrees]
            degree = degrees[int(np.argmin(criterion))]
            layout.append((c, degree, low, high))
            names += self.parameter_names(channels[c], degree)
            trials *= len(degrees)
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
                        trials=trials, notes=notes)


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
            both = len(targets) if _both_signs(d[:, None])[0] else 0
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


class RadialDistortion(_FixedParameters):
    name = 'radial_distortion'
    meaning = 'radial lens distortion (OpenCV k1, k2): x_n (k1 r^2 + k2 r^4)'
    requires, parameters, units = ('normalized',), ('k1', 'k2'), ('1', '1')

    def term(self, params, context):
        n = context['normalized']
        r2 = np.sum(n ** 2, axis=1, keepdims=True)
        return n * (params[0] * r2 + params[1] * r2 ** 2)


class TangentialDistortion(_FixedParameters):
    name = 'tangential_distortion'
    meaning = 'decentring lens distortion (OpenCV p1, p2)'
    requires, parameters, units = ('normalized',), ('p1', 'p2'), ('1', '1')

    def term(self, params, context):
        x, y = context['normalized'][:, 0], context['normalized'][:, 1]
        p1, p2 = params
        r2 = x ** 2 + y ** 2
        return np.column_stack([2 * p1 * x * y + p2 * (r2 + 2 * x ** 2),
                                p1 * (r2 + 2 * y ** 2) + 2 * p2 * x * y])


LIBRARY = {e.name: e for e in (Offset(), Scale(), Squareness(), Reversal(), Periodic(),
                               ReversalByPosition(), LeadError(), BlockStep(), WarmUp(),
                               DriftTime(), DriftTemperature(), RadialDistortion(),
                               TangentialDistortion(), LegPlay(), Compliance())}
