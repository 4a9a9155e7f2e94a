"""Planning the platform's identification: which poses to measure with the laser tracker so
that the marks land where they should at the poses the platform will work at, and what that
plan will give, before anything moves.

The identification's rows are the loop closures ``|C_i - B_i| - L_i`` (one per chain and
pose, m). Their noise comes from the tracker's pose (x, y, theta) and the feed sensors,
projected on each chain: the three rows of one pose are correlated through the shared
pose. The planner chooses with those rows whitened (the information a weighted fit would
have), and predicts with the covariance of the fit the suite runs (ordinary least squares,
chain by chain: the sandwich covariance).

The working error: the feeds for a target come from the identified model's inverse; the
platform then sits where the true closures put it. To first order the pose error is
``g_P^-1 g_e (e_hat - e)`` (g the squared closures, P the pose, e the 18 parameters), and
each mark moves with the pose.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import InvalidInputError
from calib_core.planning import (
    augment, exchange, information, predicted_errors, sandwich_covariance, whiten)
from platform_calib.core.compensation import SCREEN
from platform_calib.core.geometry import PlatformGeometry, parameter_names
from platform_calib.core.kinematics import inverse, pose_jacobians, rotation

# The simulated tracker and feed sensors' 1-sigma (platform_calib.sim.platform), the
# default noise the plan is predicted with: x m, y m, theta rad; feed m.
TRACKER_NOISE = (10e-6, 10e-6, 20e-6)
FEED_NOISE = 1e-6
# The registration's working area: the screen placed within a few mm and degrees.
WORKING_SPAN = (5e-3, 5e-3, np.deg2rad(5.0))
HOME = (0.0, 0.0, 0.0)          # the pose the working box is centred on (x m, y m, theta rad)
# Feeds kept this far inside the stroke: the true platform is not the nominal one (links
# and joints off by up to a mm move a feed by about as much).
STROKE_MARGIN = 2e-3


@dataclass(frozen=True)
class PoseDesign:
    """The chosen poses (n, 3) (x m, y m, theta rad) and what they are predicted to give:
    each parameter's 1-sigma (18,) and, at each working pose, each mark's 1-sigma position
    error (W, 2) m."""

    poses: np.ndarray
    criterion: str
    parameter_sigmas: np.ndarray
    working_errors: np.ndarray
    candidates: int

    def report(self) -> dict:
        errors = self.working_errors
        return {'criterion': self.criterion, 'poses': len(self.poses),
                'candidates': self.candidates,
                'predicted_parameter_sigmas': dict(zip(parameter_names(),
                                                       map(float, self.parameter_sigmas))),
                'predicted_mark_error_m': {'rms': float(np.sqrt(np.mean(errors ** 2))),
                                           'median': float(np.median(errors)),
                                           'max': float(errors.max())},
                'note': '1-sigma position error of a mark at the working poses after '
                        'registering with the identified model, first order, from the '
                        'tracker and feed noise alone (effects the 18 parameters lack '
                        'come on top)'}


def candidate_poses(nominal: PlatformGeometry, count: int, span=WORKING_SPAN,
                    margin: float = STROKE_MARGIN, seed: int = 0, home=HOME) -> np.ndarray:
    """Up to ``count`` random poses within +-``span`` of ``home`` (x m, y m, theta rad)
    whose nominal feeds stay ``margin`` (m) inside the stroke (those outside are dropped,
    so fewer may come back)."""
    rng = np.random.default_rng(seed + 91)
    poses = np.asarray(home, float) + rng.uniform(-1, 1, (count, 3)) * np.asarray(span, float)
    feeds = inverse(nominal, poses, check=False)
    low, high = nominal.stroke
    inside = np.all(np.isfinite(feeds) & (feeds >= low + margin) & (feeds <= high - margin), 1)
    return poses[inside]


def _closure_derivatives(geometry: PlatformGeometry, poses):
    feeds = inverse(geometry, poses)
    g_pose, g_feed, g_par = pose_jacobians(geometry, poses, feeds)
    distance = np.sqrt(np.sum(g_pose[..., :2] ** 2, -1)) / 2          # |d| per chain
    return g_pose, g_feed, g_par, distance


def identification_rows(geometry: PlatformGeometry, poses, tracker_noise=TRACKER_NOISE,
                        feed_noise: float = FEED_NOISE):
    """The closure rows per pose (n, 3, 18) (d r / d e, r = |C - B| - L in m) and their
    noise covariance per pose (n, 3, 3) (m^2)."""
    g_pose, g_feed, g_par, distance = _closure_derivatives(geometry, poses)
    rows = g_par / (2 * distance[..., None])
    for i in range(3):
        rows[:, i, 6 * i + 3] = -1.0                   # d(|d| - L)/dL
    by_pose = g_pose / (2 * distance[..., None])
    by_feed = g_feed / (2 * distance)
    noise = np.einsum('nia,a,nja->nij', by_pose, np.square(tracker_noise), by_pose)
    noise += np.einsum('ni,ij->nij', by_feed ** 2 * feed_noise ** 2, np.eye(3))
    return rows, noise


def working_sensitivity(geometry: PlatformGeometry, targets, screen=SCREEN) -> np.ndarray:
    """d(mark position)/d(parameter error) at each target, (W, 4, 18): marks A then B, x
    then y (m per unit of each parameter)."""
    targets = np.atleast_2d(np.asarray(targets, float))
    g_pose, _, g_par, _ = _closure_derivatives(geometry, targets)
    pose = np.linalg.solve(g_pose, g_par)                                 # (W, 3, 18)
    b, c = screen
    marks = np.array([[b / 2, c / 2], [-b / 2, -c / 2]])
    turned = np.einsum('wab,kb->wka', rotation(targets[:, 2]), marks)    # R m_k
    by_angle = np.stack([-turned[..., 1], turned[..., 0]], -1)            # dR/dtheta m_k
    out = pose[:, None, :2, :] + by_angle[..., None] * pose[:, None, 2:3, :]
    return out.reshape(len(targets), 4, 18)


def plan_platform(nominal: PlatformGeometry, count: int, working=None,
                  criterion: str = 'I', candidates: int = 3000, span=WORKING_SPAN,
                  margin: float = STROKE_MARGIN, seed: int = 0,
                  tracker_noise=TRACKER_NOISE, feed_noise: float = FEED_NOISE,
                  home=HOME) -> PoseDesign:
    """The ``count`` poses to measure, chosen from ``candidates`` random ones inside the
    stroke within ``span`` of ``home``, and their predicted result. ``working`` (W, 3):
    the poses the platform will work at (default: 200 random ones in the same box).

    Raises
    ------
    InvalidInputError
        Fewer than 6 poses, too few reachable candidates, a working pose out of reach."""
    if count < 6:
        raise InvalidInputError(f'the 18 parameters need at least 6 poses; asked for {count}')
    pool = candidate_poses(nominal, candidates, span, margin, seed, home)
    if len(pool) < count:
        raise InvalidInputError(f'only {len(pool)} of {candidates} candidate poses keep the '
                                f'feeds {margin * 1e3:g} mm inside the stroke: widen the '
                                'candidates or ask for fewer poses')
    working = default_working(span, seed, home) if working is None else working
    sensitivity = working_sensitivity(nominal, working)
    rows, noise = identification_rows(nominal, pool, tracker_noise, feed_noise)
    design = exchange(whiten(rows, noise), count, criterion, sensitivity)
    return _predicted(pool[design.chosen], rows[design.chosen], noise[design.chosen],
                      sensitivity, criterion, len(pool))


def default_working(span=WORKING_SPAN, seed: int = 0, home=HOME) -> np.ndarray:
    """200 random working poses within +-``span`` of ``home`` (x m, y m, theta rad)."""
    return np.asarray(home, float) + (np.random.default_rng(seed + 92).uniform(-1, 1, (200, 3))
                                      * np.asarray(span))


def _predicted(poses, rows, noise, sensitivity, criterion: str, candidates: int) -> PoseDesign:
    """The prediction for identifying from ``poses`` (their rows (n, 3, 18) and noise
    (n, 3, 3)) with the fit the suite runs."""
    covariance = sandwich_covariance(rows, noise)
    per_row = predicted_errors(covariance, sensitivity).reshape(len(sensitivity), 2, 2)
    return PoseDesign(np.asarray(poses), criterion, np.sqrt(np.diag(covariance)),
                      np.sqrt(np.sum(per_row ** 2, -1)), candidates)


def predict_platform(geometry: PlatformGeometry, poses, working=None, span=WORKING_SPAN,
                     seed: int = 0, tracker_noise=TRACKER_NOISE,
                     feed_noise: float = FEED_NOISE) -> PoseDesign:
    """What identifying from ``poses`` (n, 3) gives, predicted about ``geometry`` (the
    nominal, or the one identified so far)."""
    working = default_working(span, seed) if working is None else working
    rows, noise = identification_rows(geometry, np.asarray(poses, float), tracker_noise,
                                      feed_noise)
    return _predicted(poses, rows, noise, working_sensitivity(geometry, working), 'given',
                      len(poses))


def extend_platform(geometry: PlatformGeometry, nominal: PlatformGeometry, measured,
                    count: int, working=None,
                    criterion: str = 'I', candidates: int = 3000, span=WORKING_SPAN,
                    margin: float = STROKE_MARGIN, seed: int = 0,
                    tracker_noise=TRACKER_NOISE, feed_noise: float = FEED_NOISE,
                    home=HOME) -> PoseDesign:
    """``count`` more poses to measure after ``measured`` (n, 3), chosen about
    ``geometry`` (the one identified so far) to lower the criterion most, and the
    prediction for all of them together; candidates within ``span`` of ``home`` whose
    ``nominal`` feeds (what is commanded) keep ``margin`` inside the stroke."""
    measured = np.asarray(measured, float)
    working = default_working(span, seed, home) if working is None else working
    pool = candidate_poses(nominal, candidates, span, margin, seed + 1000 + len(measured),
                           home)
    sensitivity = working_sensitivity(geometry, working)
    rows, noise = identification_rows(geometry, np.vstack([measured, pool]), tracker_noise,
                                      feed_noise)
    whitened = whiten(rows, noise)
    prior = information(whitened, np.arange(len(measured)))
    added = augment(whitened[len(measured):], prior, count, criterion, sensitivity)
    keep = np.r_[np.arange(len(measured)), len(measured) + added]
    return _predicted(np.vstack([measured, pool[added]]), rows[keep], noise[keep],
                      sensitivity, criterion, len(pool))
