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

from scipy import stats

from calib_core.effects.base import Effect, Prepared
from calib_core.effects.rotary import resolvable_orders

COMPONENTS = ('radial_1', 'radial_2', 'axial')
GROUPS = (('radial', (0, 1)), ('axial', (2,)))
FIRST_ORDER = 2


def _harmonics(angle: np.ndarray, orders) -> np.ndarray:
    """(n, 2 len(orders)): cos(k angle), sin(k angle) per order."""
    return np.column_stack([f(k * angle) for k in orders for f in (np.cos, np.sin)])


def _rss(angle: np.ndarray, targets: np.ndarray, orders) -> float:
    """Residual sum of squares of ``targets`` (n, q) on a constant and the harmonics of
    ``orders``."""
    design = np.column_stack([np.ones_like(angle)]
                             + ([_harmonics(angle, orders)] if orders else []))
    fitted = design @ np.linalg.lstsq(design, targets, rcond=None)[0]
    return float(np.sum((targets - fitted) ** 2))


def _choose_orders(angle: np.ndarray, targets: np.ndarray, top: int, most: int,
                   screen: float):
    """The orders of one component group, from FIRST_ORDER to ``top``: the order that
    explains most, kept if its F-test (corrected for the orders scanned) passes
    ``screen``, then more while they lower the information criterion. A screen, not the
    decision: the loop's own test of the joint fit decides. Returns (orders, scanned)."""
    n, q = targets.shape
    candidates = list(range(FIRST_ORDER, top + 1))
    scanned = len(candidates)
    if not candidates or n <= 2 * q + 1:
        return [], max(scanned, 1)
    rss0 = _rss(angle, targets, [])
    best = min(candidates, key=lambda k: _rss(angle, targets, [k]))
    rss1 = _rss(angle, targets, [best])
    dof = q * (n - 3)
    f_stat = (rss0 - rss1) / (2 * q) / max(rss1 / dof, 1e-300)
    if stats.f.sf(f_stat, 2 * q, dof) * scanned >= screen:
        return [], scanned
    chosen = [best]
    candidates.remove(best)

    def criterion(orders):
        return n * q * np.log(max(_rss(angle, targets, orders), 1e-300) / (n * q)) \
            + q * (1 + 2 * len(orders)) * np.log(n)
    while candidates and len(chosen) < most:
        score = {k: criterion(chosen + [k]) for k in candidates}
        k = min(score, key=score.get)
        if score[k] >= criterion(chosen):
            break
        chosen.append(k)
        candidates.remove(k)
    return sorted(chosen), scanned


class ErrorMotion(Effect):
    """Radial and axial error motion of each rotary channel (ISO 230-7), in m."""

    name = 'error_motion'
    meaning = ('radial and axial error motion of a rotary axis (ISO 230-7): the rotor '
               'shifting perpendicular to and along its axis, repeating every turn, with '
               'the angle right (a lobed bearing race, a bent spindle)')
    requires = ('angle', 'rotor_frame')
    max_orders = 3
    min_samples = 12
    screen = 0.05     # a component group worth handing to the loop's test

    def _prepare(self, context, channels, channel_residuals):
        angle, frame = context['angle'], context['rotor_frame']
        if len(angle) < self.min_samples:
            return f'{len(angle)} rows are too few (needs {self.min_samples})'
        layout, reasons, channel_trials = [], [], {}
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
            trials = 1.0
            for group, components in GROUPS:
                orders, scanned = _choose_orders(angle[:, i], displacement[:, components],
                                                 top, self.max_orders, self.screen)
                if orders:
                    layout.append((i, components, orders))
                    trials *= scanned
                else:
                    reasons.append(f'{channel} {group}: no order of {FIRST_ORDER} to {top} '
                                   f'stands out (screen p >= {self.screen})')
            channel_trials[channel] = trials
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
                columns = _harmonics(ctx['angle'][:, i], orders)
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
