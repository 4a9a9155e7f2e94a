"""Planning a measurement, shared by every machine: from candidate measurements inside the
machine's limits, choose the few that determine what the user needs, and state before
anything moves what they will give.

A machine supplies, per candidate, its rows of the identification Jacobian whitened by the
measurement noise (``(M, r, p)``: r rows per candidate, p parameters), and optionally the
sensitivity of the error at the poses it will work at to the parameters (``(W, q, p)``).
The design criteria, on the information matrix ``A = sum J_k^T J_k`` of the chosen set:

- ``I`` (test-pose or I-optimal, Klimchik and Pashkevich's approach): minimise the mean
  predicted squared error at the working poses, ``trace(K A^-1)`` with ``K`` the mean of
  the working sensitivities' ``G^T G``; what an engineer at the machine cares about.
- ``D`` (D-optimal, Borm and Menq's observability product): maximise ``log det A``.

The search is Fedorov's exchange: a greedy start, then sweeps that swap a chosen
candidate for the one that most improves the criterion, until no swap helps. Every step
scores all candidates at once by rank-r updates (Woodbury), never refitting anything.
:func:`augment` adds measurements to what was measured already (the adaptive mode: measure,
re-identify, add the stops that most reduce the predicted error), and :class:`Adaptive`
decides the rounds of that mode for every machine.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from calib_core.errors import InvalidInputError

CRITERIA = ('I', 'D')
# A relative ridge keeps a design with fewer rows than parameters invertible while the
# greedy start builds it up (per parameter, relative to the mean candidate's information).
RIDGE = 1e-9


@dataclass(frozen=True)
class Design:
    """The chosen candidates and the criterion's value (for ``I`` the mean predicted
    squared error at the working poses, in the working error's unit squared; for ``D``
    ``-log det A``, smaller is better for both)."""

    chosen: np.ndarray
    criterion: str
    value: float
    sweeps: int


def information(jacobians: np.ndarray, chosen) -> np.ndarray:
    """``A = sum_k J_k^T J_k`` over the chosen candidates, (p, p)."""
    rows = np.asarray(jacobians)[np.asarray(chosen, int)]
    return np.einsum('krp,krq->pq', rows, rows)


def _scores(jacobians: np.ndarray, inverse: np.ndarray, criterion: str,
            weight: np.ndarray | None) -> np.ndarray:
    """Per candidate, how much adding it improves the criterion given ``inverse`` = A^-1:
    for D the gain in log det A, for I the fall in trace(K A^-1)."""
    b = jacobians @ inverse                                           # (M, r, p)
    s = np.eye(jacobians.shape[1]) + b @ np.swapaxes(jacobians, 1, 2)  # (M, r, r)
    if criterion == 'D':
        return np.linalg.slogdet(s)[1]
    q = b @ weight @ np.swapaxes(b, 1, 2)                             # J A^-1 K A^-1 J^T
    return np.einsum('mii->m', np.linalg.solve(s, q))


def _value(a: np.ndarray, criterion: str, weight: np.ndarray | None) -> float:
    if criterion == 'D':
        sign, logdet = np.linalg.slogdet(a)
        return -logdet if sign > 0 else np.inf
    return float(np.trace(weight @ np.linalg.inv(a)))


def _working_weight(criterion: str, working) -> np.ndarray | None:
    """The criterion checked, and for ``I`` the mean of the working sensitivities' G^T G
    (p, p); None for ``D``."""
    if criterion not in CRITERIA:
        raise InvalidInputError(f'criterion must be one of {", ".join(CRITERIA)}, not '
                                f'{criterion}')
    if criterion == 'D':
        return None
    if working is None:
        raise InvalidInputError('the I criterion needs the working poses')
    working = np.asarray(working, dtype=float)
    return np.einsum('wqp,wqs->ps', working, working) / len(working)


RANDOM_STARTS = 7
"""Exchanges started from random subsets besides the greedy start: single swaps stop at a
local optimum (on 9 candidates one start in six ended 8 % above the best subset); the
best of the starts is kept."""


def exchange(jacobians, count: int, criterion: str = 'I', working=None,
             max_sweeps: int = 20, random_starts: int = RANDOM_STARTS) -> Design:
    """Choose ``count`` distinct candidates by the criterion: the best of an exchange from
    the greedy start and from ``random_starts`` random subsets (seeded, so a plan is
    reproducible).

    Parameters
    ----------
    jacobians : (M, r, p) array
        Each candidate's identification rows, whitened (divided by the noise's 1-sigma).
    count : int
        Measurements to choose (at least enough rows for p parameters).
    criterion : 'I' or 'D'
    working : (W, q, p) array, optional
        The working poses' error sensitivities (needed for ``I``).

    Raises
    ------
    InvalidInputError
        An unknown criterion, too few candidates or rows, ``I`` without working poses."""
    jacobians = np.asarray(jacobians, dtype=float)
    weight = _working_weight(criterion, working)
    m, r, p = jacobians.shape
    if not count * r >= p:
        raise InvalidInputError(f'{count} measurements give {count * r} equations for {p} '
                                'parameters: plan more')
    if count > m:
        raise InvalidInputError(f'{count} measurements asked from {m} candidates')
    if not np.all(np.isfinite(jacobians)):
        raise InvalidInputError('the candidates\' Jacobians are not finite')
    ridge = np.diag(RIDGE * np.maximum(np.einsum('mrp,mrp->p', jacobians, jacobians) / m,
                                       1e-300))
    chosen: list[int] = []
    a = ridge.copy()
    for _ in range(count):                                # greedy start
        scores = _scores(jacobians, np.linalg.inv(a), criterion, weight)
        scores[chosen] = -np.inf
        best = int(np.argmax(scores))
        chosen.append(best)
        a += jacobians[best].T @ jacobians[best]
    starts = [chosen]
    rng = np.random.default_rng(0)
    for _ in range(random_starts if count < m else 0):
        starts.append([int(k) for k in rng.choice(m, count, replace=False)])
    designs = []
    for start in starts:
        a = ridge + information(jacobians, start)
        if _value(a, criterion, weight) < np.inf:
            designs.append(_swaps(jacobians, list(start), a, criterion, weight, max_sweeps))
    return min(designs, key=lambda design: design.value)


def _swaps(jacobians, chosen: list, a: np.ndarray, criterion: str, weight,
           max_sweeps: int) -> Design:
    """Fedorov's exchange from ``chosen`` (information ``a``): sweeps swapping each chosen
    candidate for the one that most improves the criterion, until no swap helps."""
    count = len(chosen)
    value = _value(a, criterion, weight)
    sweeps = 0
    for sweeps in range(1, max_sweeps + 1):
        swapped = False
        for slot in range(count):
            out = chosen[slot]
            without = a - jacobians[out].T @ jacobians[out]
            scores = _scores(jacobians, np.linalg.inv(without), criterion, weight)
            scores[[c for c in chosen if c != out]] = -np.inf
            best = int(np.argmax(scores))
            if best == out:
                continue
            trial = without + jacobians[best].T @ jacobians[best]
            trial_value = _value(trial, criterion, weight)
            if trial_value < value - 1e-9 * abs(value):
                chosen[slot], a, value, swapped = best, trial, trial_value, True
        if not swapped:
            break
    return Design(np.array(chosen), criterion, float(value), sweeps)


def augment(jacobians, prior: np.ndarray, count: int, criterion: str = 'I', working=None,
            exclude=()) -> np.ndarray:
    """The ``count`` candidates (indices) that, added one by one (greedy) to the
    information ``prior`` (p, p) of what was measured already, most improve the criterion;
    ``exclude`` candidates are not chosen. Arguments as :func:`exchange`."""
    jacobians = np.asarray(jacobians, dtype=float)
    weight = _working_weight(criterion, working)
    left = len(jacobians) - len({int(k) for k in exclude})
    if count > left:
        raise InvalidInputError(f'{count} measurements asked from {left} candidates left')
    a = np.asarray(prior, dtype=float).copy()
    excluded = sorted({int(k) for k in exclude})
    chosen: list[int] = []
    for _ in range(count):
        scores = _scores(jacobians, np.linalg.pinv(a), criterion, weight)
        scores[excluded + chosen] = -np.inf
        best = int(np.argmax(scores))
        chosen.append(best)
        a += jacobians[best].T @ jacobians[best]
    return np.array(chosen, dtype=int)


def design_bound(jacobians, working, iterations: int = 3000) -> dict:
    """How well any plan of the candidates (M, r, p; whitened rows, as :func:`exchange`
    takes them) can do by the I criterion (the mean squared error at the ``working``
    sensitivities (W, q, p)): the optimal approximate design, weights w over the candidates
    summing to 1, by the multiplicative algorithm (w_k <- w_k sqrt(d_k / sum_j w_j d_j),
    d_k = trace(M^-1 K M^-1 J_k^T J_k) the criterion's gradient). For a convex criterion
    the equivalence theorem bounds its optimum from below by any w: phi* >= 2 phi(w) -
    max_k d_k. A plan of N measurements has at least phi* / N: no exchange, candidate
    order or search of these candidates does better.

    Returns
    -------
    dict
        ``per_measurement``: phi(w), the criterion of the design found, for one
        measurement; ``lower_bound``: the certified phi* bound, for one measurement;
        ``weights`` (M,); ``support``: candidates with weight over 1e-3 / M."""
    jacobians = np.asarray(jacobians, dtype=float)
    weight = _working_weight('I', working)
    fisher = np.einsum('krp,krq->kpq', jacobians, jacobians)             # (M, p, p)
    w = np.full(len(jacobians), 1.0 / len(jacobians))

    def gradient(w):
        """phi(w) and d (M,): trace(A F_k) with A = M^-1 K M^-1, both symmetric."""
        inverse = np.linalg.pinv(np.einsum('k,kpq->pq', w, fisher))
        return (float(np.trace(weight @ inverse)),
                np.einsum('pq,kpq->k', inverse @ weight @ inverse, fisher))
    for _ in range(iterations):
        _, d = gradient(w)
        w = w * np.sqrt(np.maximum(d, 0.0) / max(float(w @ d), 1e-300))
        w /= w.sum()
    phi, d = gradient(w)
    return {'per_measurement': phi, 'lower_bound': max(2 * phi - float(d.max()), 0.0),
            'weights': w, 'support': int(np.sum(w > 1e-3 / len(w)))}


def whiten(rows: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """Each measurement's rows (M, r, p) divided by the Cholesky factor of its noise
    covariance (M, r, r): the rows a fit weighted by the noise would see, as the design
    criteria take them."""
    return np.linalg.solve(np.linalg.cholesky(noise), rows)


def sandwich_covariance(rows: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """Covariance (p, p) of the ordinary least-squares estimate from unweighted rows
    (M, r, p), r per measurement, whose noise has covariance ``noise`` (M, r, r) within
    a measurement and none between them: ``(J^T J)^-1 J^T N J (J^T J)^-1``. What the
    identification actually does when the noise of its rows is correlated or unequal."""
    inverse = np.linalg.pinv(information(rows, np.arange(len(rows))))
    return inverse @ np.einsum('kip,kij,kjq->pq', rows, noise, rows) @ inverse


def predicted_errors(covariance: np.ndarray, working: np.ndarray) -> np.ndarray:
    """1-sigma error per working pose and output row (W, q) from the parameter
    ``covariance`` (p, p) and the working sensitivities (W, q, p)."""
    return np.sqrt(np.einsum('wqp,ps,wqs->wq', working, covariance, working))


@dataclass
class Adaptive:
    """The adaptive mode's rounds, the same for every machine: after each identification
    the machine predicts its error at the working poses (RMS, m) about what it identified;
    while that is above ``target_error``, it adds the ``step`` measurements that lower it
    most, up to ``max_count`` in all. It stops, saying so, when even ``max_count``
    measurements are predicted to miss the target (before measuring more in vain).

    ``what`` names the measurements in the report (stops, poses); ``limited_by`` says what
    sets the floor when the target cannot be met (the noise, the strokes)."""

    target_error: float
    max_count: int
    step: int
    what: str = 'stops'
    limited_by: str = ''
    rounds: list = field(default_factory=list)
    stopped: str = ''

    def __post_init__(self):
        if not (isinstance(self.target_error, (int, float)) and np.isfinite(self.target_error)
                and 0 < self.target_error < 1e-3):
            raise InvalidInputError(f'target_error must be an error in m, above 0 and below '
                                    f'1 mm, not {self.target_error!r}')

    def more(self, predicted: float, count: int, extend: Callable):
        """The measurements to add after a round that gave ``predicted`` (m) from ``count``
        measurements, or None when the rounds are over (:attr:`stopped` says why).
        ``extend(room)`` returns the ``room`` best further measurements, best first (a
        greedy choice: its first ``step`` are the best ``step``), and the RMS predicted with
        all of them."""
        self.rounds.append({self.what: int(count), 'predicted_rms_m': float(predicted)})
        limit = f'max_{self.what} = {self.max_count}'
        if predicted <= self.target_error:
            return self._stop('target met')
        room = self.max_count - count
        if room <= 0:
            return self._stop(f'target not met within {limit}')
        added, floor = extend(room)
        if floor > self.target_error:
            self.rounds[-1][f'best_at_max_{self.what}_m'] = float(floor)
            return self._stop(f'target cannot be met within {limit}: {floor * 1e6:.2f} um '
                              f'predicted with all of them{self.limited_by}')
        return added[:self.step]

    def _stop(self, why: str):
        self.stopped = why
        return None

    def report(self) -> dict:
        return {'target_m': self.target_error, f'max_{self.what}': self.max_count,
                'step': self.step, 'rounds': self.rounds, 'stopped': self.stopped}
