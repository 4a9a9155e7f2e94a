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
    """The machine's XY error as a 2-D polynomial per axis of its XY position (Legendre
    products of total degree 2 to d over the travel measured), d chosen from 2 to 4 by the
    Bayesian information criterion on the residuals, at most one term per four distinct
    positions.

    On an XY machine whose channels are its two axes (the gantry), the XY position is the
    context's ``position`` and the map's axes are its channels. A machine whose channels
    are other actuators (the stage's three chains) gives its place in its own XY frame as
    ``map_position`` ((n, 2) m, the platform in the plate frame) and, as ``map_to_channels``
    ((n, C, 2)), how much each channel must change to move it by a unit in x and in y: the
    map is then the platform's error in that frame, passed to the chains. Evaluated outside
    the travel measured it extrapolates; the compensation grid stays inside it."""

    name = 'smooth_map'
    meaning = ('a smooth 2-D error map over the travel (guide straightness, a bent bridge, '
               'a thermal bow): 2-D polynomials of degree 2 and up per axis')
    requires = ('position',)
    degrees = (2, 3, 4)

    def _prepare(self, context, channels, channel_residuals):
        framed = 'map_position' in context and 'map_to_channels' in context
        x = np.asarray(context['map_position' if framed else 'position'], float)
        if not framed and (x.ndim != 2 or x.shape[1] != 2):
            return (f'needs the machine\'s XY position: {len(channels)} channel(s) and no '
                    f'XY frame given')
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
            criterion.append(sum(bic(design, channel_residuals[:, c])
                                 for c in range(channel_residuals.shape[1])))
        degree = usable[int(np.argmin(criterion))]

        def term(params, ctx):
            xy = ctx['map_position'] if framed else ctx['position']
            error = map_error(params, degree, low, high, xy)                # (n, 2)
            if not framed:
                return error
            return np.einsum('nca,na->nc', ctx['map_to_channels'], error)

        axes = ('x', 'y') if framed else channels
        names = tuple(f'map{i}{j}_{a}' for a in axes for i, j in map_terms(degree))
        notes = {'map_degree': degree, 'map_travel_m': [low.tolist(), high.tolist()],
                 'map_frame': 'the machine\'s XY frame' if framed else 'the axes'}
        return Prepared(self, names, ('m',) * len(names), np.zeros(len(names)), term,
                        trials=float(len(usable)), notes=notes)


def map_error(values, degree: int, low, high, xy) -> np.ndarray:
    """The map's error (m, (n, 2): x then y) at XY positions ``xy`` ((n, 2) m), its
    parameters ``values`` the x axis's terms then the y axis's (:func:`map_terms`) over the
    travel [``low``, ``high``]."""
    count = len(map_terms(degree))
    return map_columns(xy, low, high, degree) @ np.asarray(values, float).reshape(2, count).T


def compensation_grid(values, degree: int, low, high, step: float) -> np.ndarray:
    """The map's correction on a regular grid over [low, high] (m, 2 each), ``step`` m apart:
    rows of x, y, correction_x, correction_y (m), the correction being minus the error."""
    xs = np.arange(low[0], high[0] + step / 2, step)
    ys = np.arange(low[1], high[1] + step / 2, step)
    grid = np.array([(x, y) for y in ys for x in xs])
    return np.column_stack([grid, -map_error(values, degree, low, high, grid)])
