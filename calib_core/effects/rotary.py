"""The angular positioning error of a rotary axis that repeats every revolution: a worm
gear's error, an encoder's eccentricity (order 1) or its ellipticity (order 2), as
harmonics of one turn, with the orders the sampled angles can and cannot resolve."""
from __future__ import annotations

import numpy as np

from scipy import special

from calib_core.effects.base import Effect, Prepared

TURN = 2 * np.pi
SCREEN = 0.05      # an order worth handing to the loop's test of the joint fit
FURTHER = 1e-3     # a further order of an effect: the loop's own significance level
SAME_PLACE = 1e-3   # rad: readings of one commanded angle (encoder jitter) are one place


def _places(angle: np.ndarray) -> np.ndarray:
    """The distinct places (rad, in [0, 2 pi)) of an axis: readings closer than
    :data:`SAME_PLACE` round the turn merged, each place their mean."""
    ordered = np.sort(np.mod(angle, TURN))
    groups = np.split(ordered, np.flatnonzero(np.diff(ordered) > SAME_PLACE) + 1)
    if len(groups) > 1 and groups[0][0] + TURN - groups[-1][-1] <= SAME_PLACE:
        groups = [np.r_[groups[-1] - TURN, groups[0]]] + groups[1:-1]
    return np.sort(np.mod([g.mean() for g in groups], TURN))


def commanded_places(angle: np.ndarray) -> np.ndarray:
    """Each reading (n,) rad replaced by the mean of the readings within
    :data:`SAME_PLACE` of their neighbours: the place it was commanded to, for tests that
    count distinct places."""
    order = np.argsort(angle)
    groups = np.split(order, np.flatnonzero(np.diff(angle[order]) > SAME_PLACE) + 1)
    out = np.empty(len(angle))
    for group in groups:
        out[group] = angle[group].mean()
    return out


def resolvable_orders(angle: np.ndarray) -> tuple[int, str]:
    """The highest harmonic of one revolution that the distinct angles (rad) of one axis
    resolve, with what the data would need for more.

    Readings within :data:`SAME_PLACE` are one place. The places must go round: no gap
    between neighbouring places (modulo one turn) wider than twice their median spacing,
    else a harmonic of the turn is a smooth function over the arc seen, which the axis's
    scale and line already describe. With m distinct places, orders up to (m - 1) // 2 are
    resolved (their Nyquist limit); a higher order (a worm gear with z teeth is order z)
    aliases onto a lower one.

    Returns
    -------
    top : int
        0 when no order is resolvable.
    need : str
        For the report.
    """
    distinct = _places(angle)
    if len(distinct) < 3:
        return 0, 'angles at three or more places round the turn'
    gaps = np.diff(np.r_[distinct, distinct[0] + TURN])
    step = float(np.median(gaps))
    need = (f'{len(distinct)} angles {np.degrees(step):.3g} deg apart resolve orders up to '
            f'{(len(distinct) - 1) // 2} per turn; order z (a worm gear with z teeth) needs '
            f'more than 2 z angles round the turn')
    if gaps.max() > 2 * step + 1e-9:
        return 0, (f'the angles leave a gap of {np.degrees(gaps.max()):.3g} deg: a harmonic '
                   f'of the turn needs angles all round it')
    return (len(distinct) - 1) // 2, need


def harmonic_columns(angle: np.ndarray, orders) -> np.ndarray:
    """(n, 2 len(orders)): cos(k angle), sin(k angle) per order k."""
    return np.column_stack([f(k * angle) for k in orders for f in (np.cos, np.sin)]
                           + [np.empty((len(angle), 0))])


def _rss(angle: np.ndarray, targets: np.ndarray, orders) -> float:
    design = np.column_stack([np.ones_like(angle), harmonic_columns(angle, orders)])
    fitted = design @ np.linalg.lstsq(design, targets, rcond=None)[0]
    return float(np.sum((targets - fitted) ** 2))


def select_orders(angle: np.ndarray, targets: np.ndarray, candidates, most: int,
                  screen: float = SCREEN, further: float = FURTHER) -> tuple[list, float]:
    """The harmonic orders of ``angle`` (n,) rad that ``targets`` (n, q) show, chosen term
    by term: the order that explains most, kept if its F-test against a constant, times
    the orders scanned, is below ``screen``; then each further order that explains most of
    what is left while its nested F-test, times the orders left, is below ``further``
    (at most ``most`` orders). The first is a screen (the loop's own test of the joint fit
    decides the effect); the further ones are that decision, made per term, so an order
    that fits noise is not reported as part of a real effect. Returns the orders and the
    first order's corrected p-value (1 when none could be tested)."""
    n, q = targets.shape
    chosen, left, first = [], list(candidates), 1.0
    rss = _rss(angle, targets, [])
    while left and len(chosen) < most:
        trial = {k: _rss(angle, targets, chosen + [k]) for k in left}
        best = min(trial, key=trial.get)
        dof = q * (n - 1 - 2 * (len(chosen) + 1))
        if dof <= 0:
            break
        f_stat = (rss - trial[best]) / (2 * q) / max(trial[best] / dof, 1e-300)
        p = min(1.0, float(special.fdtrc(2 * q, dof, f_stat)) * len(left))
        if not chosen:
            first = p
        if p >= (further if chosen else screen):
            break
        chosen.append(best)
        left.remove(best)
        rss = trial[best]
    return sorted(chosen), first


class RotaryHarmonics(Effect):
    """Angular error of each rotary channel as harmonics of its angle,
    term = sum over the chosen orders k of a_k cos(k theta) + b_k sin(k theta) (rad).

    Orders are chosen per channel from 1 to the resolvable limit term by term
    (:func:`select_orders`, at most ``max_orders``); the orders scanned count as trials in
    the significance test. Channels whose ``angle`` is NaN are not rotary.
    """

    name = 'angular_harmonics'
    meaning = ('angular positioning error of a rotary axis repeating every turn (worm gear, '
               'encoder eccentricity or ellipticity), harmonics of one revolution')
    requires = ('angle',)
    max_orders = 7
    min_samples = 12

    def _orders(self, angle: np.ndarray, residual: np.ndarray):
        """The chosen orders (:func:`select_orders`) and the number scanned, or why none."""
        top, need = resolvable_orders(angle)
        if top < 1:
            return f'no harmonic is resolvable: {need}'
        chosen, _ = select_orders(angle, residual[:, None], range(1, top + 1), self.max_orders)
        if not chosen:
            return f'no harmonic stands out ({need})'
        return chosen, top

    def _prepare(self, context, channels, channel_residuals):
        angle = context['angle']
        if len(angle) < self.min_samples:
            return f'{len(angle)} rows are too few (needs {self.min_samples})'
        layout, reasons, trials, searched_by_channel = [], [], 1.0, {}
        for c in range(angle.shape[1]):
            if np.all(np.isnan(angle[:, c])):
                continue
            result = self._orders(angle[:, c], channel_residuals[:, c])
            if isinstance(result, str):
                reasons.append(f'{channels[c]}: {result}')
                continue
            orders, scanned = result
            layout.append((c, orders))
            trials *= scanned
            searched_by_channel[channels[c]] = scanned
        if not layout:
            return '; '.join(reasons) or 'no channel is a rotary axis'
        names, initial = [], []
        for c, orders in layout:
            x, r = angle[:, c], channel_residuals[:, c]
            design = np.column_stack([np.ones_like(x), harmonic_columns(x, orders)])
            initial += list(np.linalg.lstsq(design, r, rcond=None)[0][1:])
            for k in orders:
                names += [f'cos{k}_{channels[c]}', f'sin{k}_{channels[c]}']
        width = len(channels)

        def term(params, ctx):
            out = np.zeros((len(ctx['angle']), width))
            start = 0
            for c, orders in layout:
                columns = harmonic_columns(ctx['angle'][:, c], orders)
                out[:, c] = columns @ params[start:start + 2 * len(orders)]
                start += 2 * len(orders)
            return out

        notes = {'orders': {channels[c]: orders for c, orders in layout},
                 'resolvable_orders': {channels[c]: resolvable_orders(angle[:, c])[0]
                                       for c, _ in layout}}
        if reasons:
            notes['channels_not_tested'] = reasons
        return Prepared(self, tuple(names), ('rad',) * len(names), np.array(initial, float),
                        term, trials=trials, notes=notes, channel_trials=searched_by_channel)
