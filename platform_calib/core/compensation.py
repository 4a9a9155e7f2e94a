"""Feed compensation: the feeds that put the screen's two marks on target, by the model's
exact inverse kinematics, by Levenberg-Marquardt on the full model, or by the source's
particle swarm (pymoo's PSO with fixed coefficients: the source's global-best update
(23)-(24); a particle leaving the bounds draws its velocity again, up to 20 times, then
restarts at random inside them; seeded).

The composite error is the source's eq. (18), lost and rebuilt: the displacement of the
two marks A = (b/2, c/2) and B = (-b/2, -c/2) (screen frame = platform frame) between the
pose reached and the target, |AA'| + |BB'| (m); ``max`` takes the larger one instead."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from calib_core.errors import InvalidInputError
from platform_calib.core.geometry import PlatformGeometry
from platform_calib.core.kinematics import check_stroke, forward, inverse, rotation
from platform_calib.errors import WorkspaceError

SCREEN = (0.500, 0.400)        # b, c: the marks' diagonal extents, m
METHODS = ('exact', 'lm', 'pso')


def mark_positions(poses, screen=SCREEN) -> np.ndarray:
    """The two marks in the base frame for each pose, (n, 2, 2) m."""
    poses = np.atleast_2d(poses)
    b, c = screen
    marks = np.array([[b / 2, c / 2], [-b / 2, -c / 2]])
    return poses[:, None, :2] + np.einsum('nab,kb->nka', rotation(poses[:, 2]), marks)


def mark_errors(reached, target, screen=SCREEN) -> np.ndarray:
    """|AA'| and |BB'| (n, 2) m."""
    return np.linalg.norm(mark_positions(reached, screen) - mark_positions(target, screen),
                          axis=-1)


def composite_error(reached, target, screen=SCREEN, combine: str = 'sum') -> np.ndarray:
    """|AA'| + |BB'| (or the larger, ``combine='max'``), (n,) m."""
    errors = mark_errors(reached, target, screen)
    if combine == 'sum':
        return errors.sum(axis=1)
    if combine == 'max':
        return errors.max(axis=1)
    raise InvalidInputError(f'combine must be sum or max, not {combine!r}')


@dataclass(frozen=True)
class PSOSettings:
    """The swarm: the source's are 40 particles, c1 = c2 = 2, inertia 0.8, 4 iterations,
    which lie outside the region where standard PSO converges (c1 + c2 < 24 (1 - w^2) /
    (7 - 5 w) = 2.88 at w = 0.8: Poli 2009's order-2 condition as SEEDS_CDE.md quotes it,
    not checked against the paper; the bench agrees: 31 % of the source's swarms settle in
    50 iterations, all of Clerc's). ``stable`` is Clerc's constriction values."""

    particles: int = 40
    c1: float = 2.0
    c2: float = 2.0
    inertia: float = 0.8
    iterations: int = 4
    bound: float = 6e-3             # correction range +-, m (the source's Fig. 5: +-6 mm)
    seed: int = 0
    # Converged: over the last quarter of the iterations (at least 10 of them) the best
    # composite error changed by less than this (m): 0.1 um, far below what a registration
    # can use (the identification's floor is about 10 um).
    cost_tolerance: float = 1e-7

    @classmethod
    def source(cls, seed: int = 0) -> 'PSOSettings':
        return cls(seed=seed)

    @classmethod
    def stable(cls, seed: int = 0, iterations: int = 200) -> 'PSOSettings':
        return cls(c1=1.49618, c2=1.49618, inertia=0.7298, iterations=iterations, seed=seed)

    def order2_stable(self) -> bool:
        """Poli's order-2 stability condition on (c1 + c2, w)."""
        w = self.inertia
        return abs(w) < 1 and 0 < self.c1 + self.c2 < 24 * (1 - w * w) / (7 - 5 * w)


@dataclass
class Compensation:
    """Feeds (3,) m for one target, the model's predicted composite error there (m), and
    for the swarm its best cost per iteration and whether it converged."""

    method: str
    feeds: np.ndarray
    predicted_error: float
    seconds: float
    history: list = field(default_factory=list)
    converged: bool = True
    message: str = ''


def _predicted(model: PlatformGeometry, feeds, target, screen, start) -> float:
    try:
        reached = forward(model, np.atleast_2d(feeds), start)
    except WorkspaceError:
        return np.inf
    return float(composite_error(reached, target[None], screen)[0])


def compensate(model: PlatformGeometry, nominal: PlatformGeometry, target, method: str,
               screen=SCREEN, pso: PSOSettings = PSOSettings()) -> Compensation:
    """Feeds for ``target`` (3,) with the identified ``model``, starting from the nominal
    command (the nominal inverse kinematics).

    Raises
    ------
    WorkspaceError
        The target is outside the workspace or the stroke, or on another branch.
    InvalidInputError
        An unknown method."""
    target = np.asarray(target, dtype=float)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise InvalidInputError(f'target must be finite (x m, y m, theta rad), not {target!r}')
    nominal_feeds = inverse(nominal, target[None])[0]
    start = time.perf_counter()
    if method == 'exact':
        feeds = inverse(model, target[None])[0]
        result = Compensation('exact', feeds, 0.0, 0.0)
    elif method == 'lm':
        result = _levenberg_marquardt(model, target, nominal_feeds, screen)
    elif method == 'pso':
        result = _swarm(model, target, nominal_feeds, screen, pso)
    else:
        raise InvalidInputError(f'unknown compensation method {method!r}; use {METHODS}')
    check_stroke(model, result.feeds[None])
    result.predicted_error = _predicted(model, result.feeds, target, screen, target[None])
    result.seconds = time.perf_counter() - start
    return result


def _levenberg_marquardt(model, target, nominal_feeds, screen) -> Compensation:
    goal = mark_positions(target[None], screen)[0].ravel()

    def residual(feeds):
        reached = forward(model, feeds[None], target[None])
        return mark_positions(reached, screen)[0].ravel() - goal

    from scipy.optimize import least_squares   # here: only this method needs it
    solution = least_squares(residual, nominal_feeds, method='lm', xtol=1e-15, ftol=1e-15)
    return Compensation('lm', solution.x, 0.0, 0.0, converged=bool(solution.success),
                        message=solution.message)


def _swarm(model, target, nominal_feeds, screen, settings: PSOSettings) -> Compensation:
    """The source's route: corrections to the nominal feeds within +-``bound`` (and the
    stroke), the cost the model's composite error."""

    def cost(corrections):
        # All particles in one batched Newton; a candidate no pose closes costs infinity.
        reached = forward(model, nominal_feeds + corrections, target[None], strict=False)
        errors = composite_error(reached, np.repeat(target[None], len(reached), 0), screen)
        return np.where(np.isfinite(errors), errors, np.inf)

    # The corrections within +-bound and the feeds within their stroke.
    low, high = model.stroke
    lower = np.maximum(-settings.bound, low - nominal_feeds)
    upper = np.minimum(settings.bound, high - nominal_feeds)
    # Imported here: pymoo loads scipy's optimisers, which the other methods and the
    # CLI's parsers do not need.
    from platform_calib.core.swarm import minimise_swarm
    best, correction, history = minimise_swarm(cost, lower, upper, settings)
    window = max(len(history) // 4, 10)
    if len(history) <= window:
        converged = False
        message = (f'not converged: {len(history)} iterations cannot show a settled best '
                   f'(needs over {window}); best composite error {best * 1e6:.3g} um')
    else:
        change = history[-window - 1] - history[-1]
        converged = change < settings.cost_tolerance
        message = (f'best composite error {best * 1e6:.3g} um, changed by {change * 1e9:.3g} nm '
                   f'over the last {window} of {len(history)} iterations'
                   + ('' if converged else ': not converged'))
    return Compensation('pso', nominal_feeds + correction, float(best), 0.0, history,
                        converged, message)
