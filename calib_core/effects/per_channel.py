"""Effects with one term per channel and a closed form: offset, scale, reversal
(backlash), drift with time, compliance, squareness, drift with temperature."""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import (
    Effect, FixedParameters, PerChannel, Prepared, both_signs, varying)


class Offset(PerChannel):
    name, meaning, requires = 'offset', 'constant shift of each channel', ('position',)
    suffix = 'offset'

    def active(self, context, width):
        return np.ones(width, dtype=bool)

    def basis(self, context, width):
        return np.ones((len(context['position']), width))


class Scale(PerChannel):
    name, meaning, requires = 'scale', 'scale (length) error of each channel', ('position',)
    unit, suffix = '1', 'scale'

    def basis(self, context, width):
        return context['position']


class Reversal(PerChannel):
    name = 'reversal'
    meaning = ('backlash / lost motion: the driven part lags by b/2 against the direction of '
               'approach')
    requires, covariate, suffix = ('direction',), 'direction', 'backlash'

    def active(self, context, width):
        return both_signs(context['direction'])

    def inactive_reason(self):
        return ('no channel is approached often enough from both directions: backlash '
                'cannot be told from an offset')

    def basis(self, context, width):
        return -0.5 * context['direction']


class DriftTime(PerChannel):
    name, meaning, requires = 'drift_time', 'linear drift of each channel with time', ('time',)
    covariate, unit, suffix = 'time', 'm/s', 'rate'

    def inactive_reason(self):
        return 'time is constant in the data'

    def basis(self, context, width):
        t = context['time'] - context.get('time_ref', 0.0)
        return np.repeat(t[:, None], width, axis=1)


class Compliance(PerChannel):
    name, meaning = 'compliance', 'elastic deflection proportional to the static load'
    requires, covariate, unit, suffix = ('load',), 'load', 'm/N', 'compliance'

    def inactive_reason(self):
        return 'the static load does not vary in any channel'

    def basis(self, context, width):
        return -context['load']


class Squareness(FixedParameters):
    name = 'squareness'
    meaning = 'non-orthogonality of two axes: the first axis picks up gamma times the second'
    requires, parameters, units = ('position',), ('gamma',), ('rad',)

    def unobservable(self, context):
        position = context['position']
        if position.shape[1] != 2:
            return f'needs exactly two axes, the model has {position.shape[1]} channel(s)'
        if not varying(position).all():
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
