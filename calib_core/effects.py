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
    """

    effect: 'Effect'
    names: tuple
    units: tuple
    initial: np.ndarray
    term: Callable
    trials: float = 1.0
    notes: dict = field(default_factory=dict)

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
    side; below a closing force (found from the data among ``thresholds``) the play stays
    where the last move left it, so the direction of approach decides, when known."""

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

    def _prepare(self, context, channels, channel_residuals):
        load = context['load']
        active = _both_signs(load)
        if not active.any():
            return ('no channel\'s static force changes sign often enough: play cannot be '
                    'told from an offset')
        index = np.flatnonzero(active)
        thresholds = self.thresholds if 'direction' in context else (0.0,)
        best = None
        for threshold in thresholds:
            basis = -0.5 * self.side(context, threshold)[:, index]
            rss = 0.0
            for k, c in enumerate(index):
                design = np.column_stack([basis[:, k], np.ones(len(basis))])
                fit = np.linalg.lstsq(design, channel_residuals[:, c], rcond=None)[0]
                rss += float(np.sum((channel_residuals[:, c] - design @ fit) ** 2))
            if best is None or rss < best[0]:
                best = (rss, threshold)
        threshold = best[1]
        width = len(channels)

        def term(params, ctx):
            out = np.zeros((len(ctx['load']), width))
            out[:, index] = -0.5 * self.side(ctx, threshold)[:, index] * params
            return out

        return Prepared(self, tuple(f'play_{channels[i]}' for i in index),
                        ('m',) * len(index), np.zeros(len(index)), term,
                        trials=float(len(thresholds)),
                        notes={'force_to_close_play_N': threshold})


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


class Periodic(Effect):
    """Cyclic error per channel; its period comes from a Lomb-Scargle periodogram of the
    channel residuals against channel position and is then refined in the joint fit."""

    name = 'periodic'
    meaning = ('cyclic error per channel (lead-screw wobble, encoder interpolation), '
               'amplitude and period found from the data')
    requires = ('position',)
    min_samples = 20

    def _prepare(self, context, channels, channel_residuals):
        position = context['position']
        if len(position) < self.min_samples:
            return (f'{len(position)} rows are too few to find a period '
                    f'(needs {self.min_samples})')
        periods, trials, index = [], 1.0, []
        for c in range(position.shape[1]):
            x, r = position[:, c], channel_residuals[:, c]
            span = np.ptp(x)
            if span <= 0:
                continue
            distinct = np.unique(x)
            # Periods down to the mean target spacing, or twice the median one; irregular
            # targets (as ISO 230-2 asks for) resolve periods down to there.
            f_low = 2.0 / span
            f_high = max(len(distinct) / span, 0.5 / np.median(np.diff(distinct))) \
                if len(distinct) > 2 else f_low
            if f_high <= f_low:
                continue
            count = int(min(20000, max(200, 10 * (f_high - f_low) * span)))
            freqs = np.linspace(f_low, f_high, count)
            power = lombscargle(x, r, 2 * np.pi * freqs, floating_mean=True)
            periods.append(1.0 / freqs[np.argmax(power)])
            trials *= max((f_high - f_low) * span, 1.0)
            index.append(c)
        if not index:
            return 'no channel moves far enough to show a period'
        index = np.array(index)
        count = len(index)
        width = len(channels)

        def term(params, ctx):
            a, b, period = params[:count], params[count:2 * count], params[2 * count:]
            phase = 2 * np.pi * ctx['position'][:, index] / period
            out = np.zeros((len(phase), width))
            out[:, index] = a * np.cos(phase) + b * np.sin(phase)
            return out

        initial = []
        for c, period in zip(index, periods):
            phase = 2 * np.pi * position[:, c] / period
            design = np.column_stack([np.cos(phase), np.sin(phase), np.ones_like(phase)])
            initial.append(np.linalg.lstsq(design, channel_residuals[:, c], rcond=None)[0][:2])
        initial = np.array(initial)
        names = (tuple(f'cos_{channels[i]}' for i in index) + tuple(f'sin_{channels[i]}' for i in index)
                 + tuple(f'period_{channels[i]}' for i in index))
        units = ('m',) * (2 * count) + ('m',) * count
        return Prepared(self, names, units,
                        np.concatenate([initial[:, 0], initial[:, 1], periods]), term,
                        trials=trials)


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
                               DriftTime(), DriftTemperature(), RadialDistortion(),
                               TangentialDistortion(), LegPlay(), Compliance())}
