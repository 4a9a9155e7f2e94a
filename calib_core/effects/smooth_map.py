"""A smooth 2-D error map over an XY machine's travel: what straightness and flatness of the
guides, a bent bridge or a thermal bow leave after a rigid-body model, and what a
controller takes as a 2-D compensation grid."""
from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre

from calib_core.effects.base import Effect, Prepared, bic


def _scaled(x: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Positions (n, 2) mapped onto [-1, 1] over the travel [low, high]."""
    return 2 * (x - low) / np.where(high > low, high - low, 1.0) - 1


def map_terms(degree: int) -> list:
    """The (i, j) of the 2-D Legendre products P_i(u) P_j(v) of total degree 2 to
    ``degree``: those of degree 0 and 1 are the rigid-body model's (offset, scale,
    rotation, squareness)."""
    return [(i, total - i) for total in range(2, degree + 1) for i in range(total + 1)]


def map_columns(x: np.ndarray, low, high, degree: int) -> np.ndarray:
    """The map's basis at positions ``x`` (n, 2) m, shape (n, len(map_terms(degree)))."""
    u = _scaled(np.asarray(x, float), np.asarray(low), np.asarray(high))
    pu = legendre.legvander(u[:, 0], degree)
    pv = legendre.legvander(u[:, 1], degree)
    return np.column_stack([pu[:, i] * pv[:, j] for i, j in map_terms(degree)])


class SmoothMap(Effect):
    """Per axis a 2-D polynomial in both positions (Legendre products of total degree 2 to
    d over the travel measured), d chosen from 2 to 4 by the Bayesian information criterion
    on the residuals, at most one term per four distinct positions. Evaluated outside the
    travel measured it extrapolates; the compensation grid stays inside it."""

    name = 'smooth_map'
    meaning = ('a smooth 2-D error map over the travel (guide straightness, a bent bridge, '
               'a thermal bow): 2-D polynomials of degree 2 and up per axis')
    requires = ('position',)
    degrees = (2, 3, 4)

    def _prepare(self, context, channels, channel_residuals):
        x = np.asarray(context['position'], float)
        if x.shape[1] != 2:
            return f'needs exactly two axes, the model has {x.shape[1]} channel(s)'
        distinct = len(np.unique(np.round(x, 9), axis=0))
        low, high = x.min(axis=0), x.max(axis=0)
        if not np.all(high > low):
            return 'both axes must move for a 2-D map'
        usable = [d for d in self.degrees if 4 * len(map_terms(d)) <= distinct]
        if not usable:
            return (f'{distinct} distinct positions are too few for a 2-D map (needs '
                    f'{4 * len(map_terms(self.degrees[0]))})')
        criterion = []
        for degree in usable:
            design = np.column_stack([np.ones(len(x)), map_columns(x, low, high, degree)])
            criterion.append(sum(bic(design, channel_residuals[:, c]) for c in range(2)))
        degree = usable[int(np.argmin(criterion))]
        terms = map_terms(degree)
        count = len(terms)

        def term(params, ctx):
            columns = map_columns(ctx['position'], low, high, degree)
            return np.column_stack([columns @ params[:count], columns @ params[count:]])

        names = tuple(f'map{i}{j}_{c}' for c in channels for i, j in terms)
        notes = {'map_degree': degree, 'map_travel_m': [low.tolist(), high.tolist()]}
        return Prepared(self, names, ('m',) * len(names), np.zeros(len(names)), term,
                        trials=float(len(usable)), notes=notes)


def compensation_grid(prepared_term, values, low, high, step: float) -> np.ndarray:
    """The map's correction on a regular grid over [low, high] (m, 2 each), ``step`` m apart:
    rows of x, y, correction_x, correction_y (m), the correction being minus the error."""
    xs = np.arange(low[0], high[0] + step / 2, step)
    ys = np.arange(low[1], high[1] + step / 2, step)
    grid = np.array([(x, y) for y in ys for x in xs])
    error = prepared_term(np.asarray(values, float), {'position': grid})
    return np.column_stack([grid, -error])
