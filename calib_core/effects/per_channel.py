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
    name, requires = 'scale', ('position',)
    meaning = ('scale (length) error of each channel: a lead screw\'s lead, an encoder\'s '
               'or a read-out\'s conversion factor off by a share')
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


class DriftSequence(PerChannel):
    name = 'drift_sequence'
    meaning = ('linear drift of each channel over the run by approach number, where no '
               'clock was logged (thermal drift of the machine or the instrument)')
    requires, covariate, unit, suffix = ('sequence',), 'sequence', 'm/approach', 'rate'

    def inactive_reason(self):
        return 'the approach number is constant in the data'

    def basis(self, context, width):
        s = context['sequence'] - context.get('sequence_ref', 0.0)
        return np.repeat(s[:, None], width, axis=1)


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
    """Thermal expansion and zero drift, term = (k (x - x_mean) + g) (T - T_ref) per
    channel, with x_mean the channel's mean position on the rows prepared on.

    Written about the mean position, not zero, because only the growth there (g, m/K) is
    determined on a short stroke: k x + c at a 0.64 m leg moving +-5 mm tells k and c apart
    no better than 0.005 m / 0.64 m of the growth. The loop's report flags k as not
    determined where it is below twice its standard deviation (see ``undetermined``)."""

    name = 'drift_temperature'
    meaning = ('thermal expansion (k, 1/K, about the mean position) and the growth at the '
               'mean position (g, m/K) with temperature')
    requires = ('temperature', 'position')

    def _prepare(self, context, channels, channel_residuals):
        if np.ptp(context['temperature']) <= 0:
            return 'temperature is constant in the data'
        count = len(channels)
        centre = np.mean(context['position'], axis=0)

        def term(params, ctx):
            k, g = params[:count], params[count:]
            dt = (ctx['temperature'] - ctx.get('temperature_ref', 0.0))[:, None]
            return (k * (ctx['position'] - centre) + g) * dt

        names = tuple(f'expansion_{c}' for c in channels) + tuple(f'growth_{c}' for c in channels)
        notes = {'mean_position_m': dict(zip(channels, map(float, centre))),
                 'stroke_m': dict(zip(channels, map(float, np.ptp(context['position'], axis=0))))}
        return Prepared(self, names, ('1/K',) * count + ('m/K',) * count,
                        np.zeros(2 * count), term, notes=notes)

    @staticmethod
    def undetermined(parameters: dict, std_devs: dict, notes: dict) -> dict:
        """Parameter name -> why it is not determined: an expansion below twice its standard
        deviation (the stroke too short to tell it from the growth at the mean position)."""
        out = {}
        for name, value in parameters.items():
            if name.startswith('expansion_') and not abs(value) >= 2 * std_devs[name]:
                channel = name[len('expansion_'):]
                stroke = notes.get('stroke_m', {}).get(channel, float('nan'))
                out[name] = (f'{value:.3g} +- {std_devs[name]:.2g} 1/K: a stroke of '
                             f'{stroke * 1e3:.3g} mm does not tell expansion from the growth at '
                             f'the mean position; growth_{channel} is what the data determine')
        return out
