"""Error motion of a rotary axis (ISO 230-7): the rotor's translation, perpendicular to the
axis (radial) and along it (axial), repeating every turn, when the angle itself is right.
A two-lobed bearing race or a lobed spindle moves the table twice per turn; a camera or a
tracker sees the target shift with no angle error.

The machine supplies, per row, each rotary axis's housing frame: ``rotor_frame`` (n, C, C,
3), whose ``[:, i]`` maps a displacement of rotary channel i's rotor, written as (radial_1,
radial_2, axial) in m, to the terms of the machine's channels (a target's shift in a camera
frame, say); zero for a channel that is not a rotary axis. The effect is

    displacement_i(theta) = sum over the chosen orders k of a_k cos(k theta) + b_k sin(k theta)

per component (m), the radial pair sharing its orders. Order 1 is left out: a radial
motion once per turn is the target's distance from the axis (its centring) and an axial
one the axis line's tilt, both in every rotary model's base parameters (ISO 230-7 removes
them as well). Tilt error motion turns the rotor about a radial direction; it is not a
translation and not modelled here.
"""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import Effect, Prepared
from calib_core.effects.rotary import (
    FURTHER, harmonic_columns, resolvable_orders, select_orders)

COMPONENTS = ('radial_1', 'radial_2', 'axial')
GROUPS = (('radial', (0, 1)), ('axial', (2,)))
FIRST_ORDER = 2


class ErrorMotion(Effect):
    """Radial and axial error motion of each rotary channel (ISO 230-7), in m."""

    name = 'error_motion'
    meaning = ('radial and axial error motion of a rotary axis (ISO 230-7): the rotor '
               'shifting perpendicular to and along its axis, repeating every turn, with '
               'the angle right (a lobed bearing race, a bent spindle)')
    requires = ('angle', 'rotor_frame')
    max_orders = 3
    min_samples = 12

    def _prepare(self, context, channels, channel_residuals):
        angle, frame = context['angle'], context['rotor_frame']
        if len(angle) < self.min_samples:
            return f'{len(angle)} rows are too few (needs {self.min_samples})'
        groups, reasons, channel_trials = [], [], {}
        for i, channel in enumerate(channels):
            if np.all(np.isnan(angle[:, i])) or not np.any(frame[:, i]):
                continue
            top, need = resolvable_orders(angle[:, i])
            if top < FIRST_ORDER:
                reasons.append(f'{channel}: no order above the first is resolvable ({need})')
                continue
            # The rows' residuals as the rotor's displacement (least squares per row).
            displacement = np.einsum('nkc,nc->nk', np.linalg.pinv(frame[:, i]),
                                     channel_residuals)
            candidates = list(range(FIRST_ORDER, top + 1))
            channel_trials[channel] = float(len(candidates)) ** len(GROUPS)
            for group, components in GROUPS:
                orders, p = select_orders(angle[:, i], displacement[:, components], candidates,
                                          self.max_orders)
                groups.append((p, i, group, components, orders))
        # The group that stands out most passes the screen; every other one (another
        # axis, the axial beside the radial) must pass the loop's own level on its own.
        groups.sort(key=lambda g: g[0])
        layout = []
        for rank, (p, i, group, components, orders) in enumerate(groups):
            if orders and (rank == 0 or p < FURTHER):
                layout.append((i, components, orders))
            else:
                reasons.append(f'{channels[i]} {group}: no order of {FIRST_ORDER} to '
                               f'{max(FIRST_ORDER, resolvable_orders(angle[:, i])[0])} stands '
                               f'out (p = {p:.2g} over the orders scanned)')
        if not layout:
            return '; '.join(reasons) or 'no channel is a rotary axis with a housing frame'
        names, units = [], []
        for i, components, orders in layout:
            for m in components:
                for k in orders:
                    names += [f'{channels[i]}_{COMPONENTS[m]}_cos{k}',
                              f'{channels[i]}_{COMPONENTS[m]}_sin{k}']
                    units += ['m', 'm']
        width = len(channels)

        def term(params, ctx):
            out = np.zeros((len(ctx['angle']), width))
            start = 0
            for i, components, orders in layout:
                columns = harmonic_columns(ctx['angle'][:, i], orders)
                shift = np.zeros((len(out), 3))
                for m in components:
                    shift[:, m] = columns @ params[start:start + 2 * len(orders)]
                    start += 2 * len(orders)
                out += np.einsum('nck,nk->nc', ctx['rotor_frame'][:, i], shift)
            return out

        notes = {'orders': {f'{channels[i]} {"radial" if components[0] == 0 else "axial"}': orders
                            for i, components, orders in layout},
                 'components': 'radial_1, radial_2 perpendicular to the axis, axial along it '
                               '(the machine names the directions)'}
        if reasons:
            notes['channels_not_tested'] = reasons
        return Prepared(self, tuple(names), tuple(units), np.zeros(len(names)), term,
                        trials=float(np.prod(list(channel_trials.values()))), notes=notes,
                        channel_trials=channel_trials, separable=False)
