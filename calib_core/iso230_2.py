"""ISO 230-2 figures of a linear axis and the compensation table a controller loads.

Definitions (ISO 230-2:2014, section 2), per target i and direction (up = approached from
below, +1; down = from above, -1), with x_ij = measured - target of cycle j:

- mean unidirectional deviation x_i (per direction), estimator s_i (ddof 1);
- reversal B_i = x_i(up) - x_i(down); B = max |B_i|; mean reversal B_mean = mean B_i;
- unidirectional repeatability R_i = 4 s_i, bidirectional
  R_i = max(2 s_i(up) + 2 s_i(down) + |B_i|, R_i(up), R_i(down)); R = max over i;
- systematic positioning error E (per direction: range of x_i; bidirectional: range of
  both directions' x_i together); mean bidirectional positioning error M = range of
  (x_i(up) + x_i(down)) / 2;
- accuracy A (per direction: max(x_i + 2 s_i) - min(x_i - 2 s_i); bidirectional: the same
  over both directions).
"""
from __future__ import annotations

import numpy as np

from calib_core.errors import InvalidInputError


def _cells(target, deviation, direction):
    """Per target: mean and s per direction (NaN where a direction has < 2 values)."""
    targets = np.unique(target)
    mean = np.full((len(targets), 2), np.nan)
    spread = np.full((len(targets), 2), np.nan)
    for i, t in enumerate(targets):
        for k, sign in enumerate((1.0, -1.0)):
            values = deviation[(target == t) & (direction == sign)]
            if len(values):
                mean[i, k] = values.mean()
            if len(values) >= 2:
                spread[i, k] = values.std(ddof=1)
    return targets, mean, spread


def _range(values) -> float:
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(np.ptp(values)) if values.size else float('nan')


def figures(target: np.ndarray, deviation: np.ndarray, direction: np.ndarray) -> dict:
    """ISO 230-2 figures (m) of positioning ``deviation`` (measured - target, m) at
    ``target`` (m) approached from ``direction`` (+1 / -1).

    Returns
    -------
    dict
        ``up``, ``down`` (unidirectional A, E, R) and ``bidirectional`` (A, B, B_mean,
        E, M, R), and ``per_target``: target, mean deviation and s per direction, B_i and
        R_i. Figures a direction's data cannot give (one direction only, one cycle) are
        None, with the reason under ``notes``.
    """
    target, deviation, direction = (np.asarray(a, float).ravel()
                                    for a in (target, deviation, direction))
    if not (len(target) == len(deviation) == len(direction)) or len(target) == 0:
        raise InvalidInputError('target, deviation and direction must be equal-length, non-empty')
    targets, mean, spread = _cells(target, deviation, direction)
    notes = []
    out = {}
    for k, name in enumerate(('up', 'down')):
        if np.all(np.isnan(mean[:, k])):
            out[name] = None
            notes.append(f'no target approached {name}')
            continue
        s = spread[:, k]
        entry = {'E': _range(mean[:, k])}
        if np.all(np.isnan(s)):
            entry.update(R=None, A=None)
            notes.append(f'{name}: one cycle only, no repeatability')
        else:
            entry['R'] = float(np.nanmax(4 * s))
            entry['A'] = float(np.nanmax(mean[:, k] + 2 * s) - np.nanmin(mean[:, k] - 2 * s))
        out[name] = entry
    reversal = mean[:, 0] - mean[:, 1]
    both = np.isfinite(reversal)
    bidirectional = {'E': _range(mean), 'B': None, 'B_mean': None, 'M': None, 'R': None,
                     'A': None}
    r_i = np.full(len(targets), np.nan)
    if both.any():
        bidirectional['B'] = float(np.max(np.abs(reversal[both])))
        bidirectional['B_mean'] = float(np.mean(reversal[both]))
        bidirectional['M'] = _range(mean[both].mean(axis=1))
        repeat = np.isfinite(spread).all(axis=1) & both
        if repeat.any():
            r_i[repeat] = np.maximum.reduce([2 * spread[repeat, 0] + 2 * spread[repeat, 1]
                                             + np.abs(reversal[repeat]),
                                             4 * spread[repeat, 0], 4 * spread[repeat, 1]])
            bidirectional['R'] = float(np.nanmax(r_i))
            bidirectional['A'] = float(np.nanmax(mean + 2 * spread) - np.nanmin(mean - 2 * spread))
    else:
        notes.append('no target approached from both directions: B, M, bidirectional R '
                     'and A need both')
    out['bidirectional'] = bidirectional
    out['per_target'] = {'target': targets.tolist(),
                         'mean_up': _listed(mean[:, 0]), 'mean_down': _listed(mean[:, 1]),
                         's_up': _listed(spread[:, 0]), 's_down': _listed(spread[:, 1]),
                         'B': _listed(reversal), 'R': _listed(r_i)}
    out['notes'] = notes
    return out


def _listed(values: np.ndarray) -> list:
    return [None if not np.isfinite(v) else float(v) for v in values]


def format_figures(label: str, result: dict) -> list:
    """Report lines: the figures in um."""
    def um(value):
        return '   n/a' if value is None else f'{value * 1e6:6.2f}'

    lines = [f'  ISO 230-2, {label} (um):      A      B      E      M      R']
    bi = result['bidirectional']
    lines.append(f'    bidirectional         {um(bi["A"])} {um(bi["B"])} {um(bi["E"])} '
                 f'{um(bi["M"])} {um(bi["R"])}')
    for name in ('up', 'down'):
        entry = result[name]
        if entry is not None:
            lines.append(f'    {name:<21} {um(entry["A"])}    --- {um(entry["E"])}    --- '
                         f'{um(entry["R"])}')
    return lines


def compensation_table(positions: np.ndarray, error_up: np.ndarray,
                       error_down: np.ndarray) -> list:
    """Rows (position, correction up, correction down), m: the correction to add to a
    command approached from below / above is minus the predicted error there."""
    return [(float(p), float(-u), float(-d)) for p, u, d in zip(positions, error_up, error_down)]
