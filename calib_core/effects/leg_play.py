"""A hexapod leg's joint play taken up by its static force, with the closing force
found from the data (down to zero: closed by the load's sign alone)."""
from __future__ import annotations

import numpy as np

from calib_core.effects.base import Effect, Prepared, both_signs


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
            # Imported here: scipy.stats costs every command 0.7 s; only a play fit votes.
            from scipy.stats import binomtest
            if (float(np.sum(cost)) < best_cost and
                    binomtest(votes, int(differ.sum()), alternative='greater').pvalue < 0.05):
                best, best_cost = threshold, float(np.sum(cost))
        return best

    def _prepare(self, context, channels, channel_residuals):
        index = np.flatnonzero(both_signs(context['load']))
        if 'direction' in context and len(index):
            threshold = self._choose_threshold(context, channel_residuals, index)
            index = np.flatnonzero(both_signs(self.side(context, threshold)))
        else:
            threshold = 0.0
        if not len(index):
            return ('no leg\'s static force changes sign often enough: play cannot be told '
                    'from an offset')
        thresholds = self.thresholds if 'direction' in context else (0.0,)
        width = len(channels)
        # Legs whose side changes at all but too rarely to fit their own play.
        rare = np.setdiff1d(np.flatnonzero(both_signs(self.side(context, threshold), 1)), index)

        def term(params, ctx):
            side = self.side(ctx, threshold)
            out = np.zeros((len(side), width))
            out[:, index] = -0.5 * side[:, index] * params
            out[:, rare] = -0.5 * side[:, rare] * np.mean(params)
            return out

        def determined(ctx):
            # A leg's play is told from its actuator offset only by rows on both sides.
            return both_signs(self.side(ctx, threshold)[:, index], 1)

        notes = {'force_to_close_play_N': threshold}
        if len(rare):
            notes['legs_with_mean_play'] = [channels[i] for i in rare]
        return Prepared(self, tuple(f'play_{channels[i]}' for i in index),
                        ('m',) * len(index), np.zeros(len(index)), term,
                        trials=float(len(thresholds)), notes=notes, determined=determined,
                        separable=not len(rare))
