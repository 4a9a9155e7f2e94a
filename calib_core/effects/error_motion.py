"""Error motion of a rotary axis (ISO 230-7): the rotor's translation, perpendicular to the
axis (radial) and along it (axial), and its tilt about the two radial directions,
repeating every turn, when the angle itself is right. A two-lobed bearing race or a lobed
spindle moves the table twice per turn, a race whose two rows are lobed out of phase tilts
it; a camera or a tracker sees the target shift and turn with no angle error.

The machine supplies, per row, each rotary axis's housing frame: ``rotor_frame`` (n, C, C,
5), whose ``[:, i]`` maps a displacement of rotary channel i's rotor, written as (radial_1,
radial_2, axial) in m, and its tilt (about radial_1, radial_2) in rad, to the terms of the
machine's channels (a target's shift and turn in a camera frame, say); zero for a channel
that is not a rotary axis. Where a machine's channel residuals see a term other than it
is (more channels than a row has residuals), ``rotor_view`` (same shape) says how each
component looks in them, and the screen reads the motion through it. The effect is

    motion_i(theta) = sum over the chosen orders k of a_k cos(k theta) + b_k sin(k theta)

per component, the radial pair sharing its orders and the tilt pair theirs. Order 1 is
left out: a radial motion once per turn is the target's distance from the axis (its
centring), an axial one and a tilt the axis line's tilt, all in every rotary model's base
parameters (ISO 230-7 removes them as well). Where along the axis the rotor tilts is the
machine's gauge (a tilt about another point adds radial motion of the same orders): the
machine states it with its frame.
"""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import Effect, Prepared
from calib_core.effects.rotary import (
    FURTHER, harmonic_columns, resolvable_orders, select_orders)

COMPONENTS = ('radial_1', 'radial_2', 'axial', 'tilt_1', 'tilt_2')
COMPONENT_UNITS = ('m', 'm', 'm', 'rad', 'rad')
GROUPS = (('radial', (0, 1)), ('axial', (2,)), ('tilt', (3, 4)))
FIRST_ORDER = 2


class ErrorMotion(Effect):
    """Radial, axial (m) and tilt (rad) error motion of each rotary channel (ISO 230-7)."""

    name = 'error_motion'
    meaning = ('radial, axial and tilt error motion of a rotary axis (ISO 230-7): the '
               'rotor shifting perpendicular to and along its axis and tilting about it, '
               'repeating every turn, with the angle right (a lobed bearing race, a bent '
               'spindle)')
    requires = ('angle', 'rotor_frame')
    max_orders = 3
    min_samples = 12

    def _prepare(self, context, channels, channel_residuals):
        angle, frame = context['angle'], context['rotor_frame']
        view = context.get('rotor_view', frame)
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
            displacement = np.einsum('nkc,nc->nk', np.linalg.pinv(view[:, i]),
                                     channel_residuals)
            candidates = list(range(FIRST_ORDER, top + 1))
            carried = [(group, components) for group, components in GROUPS
                       if np.any(frame[:, i][:, :, components])]   # what the machine sees
            channel_trials[channel] = float(len(candidates)) ** len(carried)
            for group, components in carried:
                orders, p = select_orders(angle[:, i], displacement[:, components], candidates,
                                          self.max_orders)
                groups.append((p, i, group, components, orders))
        # The group that stands out most passes the screen; every other one (another
        # axis, the axial or the tilt beside the radial) must pass the loop's own level.
        groups.sort(key=lambda g: g[0])
        layout = []
        for rank, (p, i, group, components, orders) in enumerate(groups):
            if orders and (rank == 0 or p < FURTHER):
                layout.append((i, group, components, orders))
            else:
                reasons.append(f'{channels[i]} {group}: no order of {FIRST_ORDER} to '
                               f'{max(FIRST_ORDER, resolvable_orders(angle[:, i])[0])} stands '
                               f'out (p = {p:.2g} over the orders scanned)')
        if not layout:
            return '; '.join(reasons) or 'no channel is a rotary axis with a housing frame'
        names, units = [], []
        for i, _, components, orders in layout:
            for m in components:
                for k in orders:
                    names += [f'{channels[i]}_{COMPONENTS[m]}_cos{k}',
                              f'{channels[i]}_{COMPONENTS[m]}_sin{k}']
                    units += [COMPONENT_UNITS[m]] * 2
        width = len(channels)

        def term(params, ctx):
            out = np.zeros((len(ctx['angle']), width))
            start = 0
            for i, _, components, orders in layout:
                columns = harmonic_columns(ctx['angle'][:, i], orders)
                motion = np.zeros((len(out), len(COMPONENTS)))
                for m in components:
                    motion[:, m] = columns @ params[start:start + 2 * len(orders)]
                    start += 2 * len(orders)
                out += np.einsum('nck,nk->nc', ctx['rotor_frame'][:, i], motion)
            return out

        notes = {'orders': {f'{channels[i]} {group}': orders
                            for i, group, components, orders in layout},
                 'components': 'radial_1, radial_2 perpendicular to the axis, axial along it '
                               '(m); tilt_1, tilt_2 about radial_1, radial_2 (rad); the '
                               'machine names the directions'}
        if reasons:
            notes['channels_not_tested'] = reasons
        return Prepared(self, tuple(names), tuple(units), np.zeros(len(names)), term,
                        trials=float(np.prod(list(channel_trials.values()))), notes=notes,
                        channel_trials=channel_trials, separable=False)
