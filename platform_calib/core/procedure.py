"""The platform's calibration run: plan poses, command each through the nominal inverse
kinematics, read the feeds and the tracker, identify, then evaluate on separate poses with
the nominal and the calibrated commands. Hardware is passed in as callables, so the node,
the tests and the offline replay run the same code."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from calib_core.checks import MAX_SEED, whole_number
from calib_core.errors import InvalidInputError
from calib_core.planning import Adaptive
from platform_calib.core.compensation import composite_error
from platform_calib.core.geometry import PlatformGeometry
from platform_calib.core.identification import (
    MIN_POSES, POSE_SCHEMA, Identification, PoseData, identify)
from platform_calib.core.kinematics import inverse
from platform_calib.core.planning import (
    default_working, extend_platform, plan_platform, predict_platform)


DESIGNS = ('random', 'I', 'D')


@dataclass(frozen=True)
class PlatformPlan:
    """The poses to identify from and ``evaluation_poses`` others to evaluate on (random
    within +-``span`` of ``home``, x m, y m, theta rad, drawn with ``seed``). The identification poses:
    ``targets`` when given (a planned set, e.g. from ``machine-align plan platform``), else
    ``poses`` of them, random (``design`` 'random') or planned here for the least error at
    the evaluation span ('I') or the largest information ('D').

    Adaptive with ``target_error`` > 0 (m, the predicted 1-sigma mark error at the working
    poses, RMS): after identifying, predict about the identified geometry; while above the
    target, add the ``step`` poses that lower it most (D or I as ``design``, I for a random
    start), measure and identify again, up to ``max_poses``. It stops early, saying so,
    when even ``max_poses`` poses are predicted to miss the target."""

    poses: int = 20
    evaluation_poses: int = 10
    span: tuple = (5e-3, 5e-3, np.deg2rad(5.0))
    seed: int = 0
    design: str = 'random'
    targets: tuple = ()
    target_error: float = 0.0
    max_poses: int = 60
    step: int = 4
    home: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, 'poses', whole_number(self.poses, 'poses', MIN_POSES))
        object.__setattr__(self, 'evaluation_poses',
                           whole_number(self.evaluation_poses, 'evaluation_poses', 1))
        object.__setattr__(self, 'seed', whole_number(self.seed, 'seed', 0, MAX_SEED))
        span = np.asarray(self.span, dtype=float)
        if span.shape != (3,) or not np.all(np.isfinite(span)) or np.any(span <= 0) \
                or np.any(span[:2] > 0.1) or span[2] > np.pi / 4:
            raise InvalidInputError(f'span must be three positive values (x m, y m, theta '
                                    f'rad; up to 0.1 m and pi/4), not {self.span!r}')
        object.__setattr__(self, 'span', tuple(float(v) for v in span))
        home = np.asarray(self.home, dtype=float)
        if home.shape != (3,) or not np.all(np.isfinite(home)) or np.any(np.abs(home[:2]) > 0.5) \
                or abs(home[2]) > np.pi / 4:
            raise InvalidInputError(f'home must be three values (x m, y m, theta rad; within '
                                    f'0.5 m and pi/4), not {self.home!r}')
        object.__setattr__(self, 'home', tuple(float(v) for v in home))
        object.__setattr__(self, 'max_poses', whole_number(self.max_poses, 'max_poses', MIN_POSES))
        object.__setattr__(self, 'step', whole_number(self.step, 'step', 1))
        if not (isinstance(self.target_error, (int, float)) and np.isfinite(self.target_error)
                and 0 <= self.target_error < 1e-3):
            raise InvalidInputError(f'target_error must be a mark error in m (0 for none, '
                                    f'below 1 mm), not {self.target_error!r}')
        if self.design not in DESIGNS:
            raise InvalidInputError(f'design must be one of {", ".join(DESIGNS)}, not '
                                    f'{self.design!r}')
        if len(self.targets):
            try:
                targets = np.array(self.targets, dtype=float).reshape(-1, 3)
            except (TypeError, ValueError):
                raise InvalidInputError('targets must be rows of x (m), y (m), theta (rad)') \
                    from None
            POSE_SCHEMA.check({'x': targets[:, 0], 'y': targets[:, 1],
                               'theta': targets[:, 2]}, 'the plan\'s targets')
            if len(targets) < MIN_POSES:
                raise InvalidInputError(f'{len(targets)} targets for 18 parameters: at least '
                                        f'{MIN_POSES}')
            object.__setattr__(self, 'targets', tuple(map(tuple, targets.tolist())))
            object.__setattr__(self, 'poses', len(targets))

    def targets_for(self, nominal: PlatformGeometry) -> tuple[np.ndarray, np.ndarray, dict]:
        """The identification poses (n, 3), the evaluation poses (m, 3) and, for a design
        planned here, its prediction (else an empty dict)."""
        rng = np.random.default_rng(self.seed)
        draw = np.asarray(self.home) + rng.uniform(
            -1, 1, (self.poses + self.evaluation_poses, 3)) * np.asarray(self.span)
        identify_at, evaluate_at = draw[:self.poses], draw[self.poses:]
        if len(self.targets):
            return np.array(self.targets), evaluate_at, {}
        if self.design == 'random':
            return identify_at, evaluate_at, {}
        design = plan_platform(nominal, self.poses, criterion=self.design, span=self.span,
                               seed=self.seed, home=self.home)
        return design.poses, evaluate_at, design.report()


@dataclass(frozen=True)
class Stop:
    """One stop: the phase, the pose aimed at, the feeds read there (m), each feed's
    direction of approach, the pose the tracker measured."""

    phase: str
    target: np.ndarray
    feeds: np.ndarray
    direction: np.ndarray
    measured: np.ndarray


def data_of(stops: list) -> PoseData:
    return PoseData(np.array([s.measured for s in stops]), np.array([s.feeds for s in stops]),
                    {'direction': np.array([s.direction for s in stops])})


def evaluate(stops: list) -> dict:
    """Composite mark error (m) measured by the tracker against the target, per phase."""
    out = {}
    for phase in sorted({s.phase for s in stops}):
        rows = [s for s in stops if s.phase == phase]
        errors = composite_error(np.array([s.measured for s in rows]),
                                 np.array([s.target for s in rows]))
        out[phase] = {'median_m': float(np.median(errors)), 'max_m': float(errors.max()),
                      'poses': len(rows)}
    return out


def run_platform_calibration(plan: PlatformPlan, nominal: PlatformGeometry,
                             move: Callable[[np.ndarray], tuple],
                             measure: Callable[[], np.ndarray],
                             record: Callable[[Stop], None] = lambda stop: None,
                             progress: Callable[[int, int, str], None] = lambda *a: None
                             ) -> tuple[Identification, dict, list, dict]:
    """Identify and evaluate: (identification, evaluation per phase, stops, the plan's
    prediction when it was planned here, else empty). ``move(feeds)`` returns (feeds read,
    directions); ``measure()`` the tracker's pose (3,).

    Raises
    ------
    WorkspaceError
        A planned pose the nominal platform cannot reach (refused before anything moves).
    CalibrationError
        Poses that do not determine the parameters."""
    identify_at, evaluate_at, prediction = plan.targets_for(nominal)
    nominal_feeds = inverse(nominal, np.vstack([identify_at, evaluate_at]))   # checked first
    total = len(identify_at) + 2 * len(evaluate_at)
    stops = []
    if prediction:
        errors = prediction['predicted_mark_error_m']
        progress(0, total, f'{plan.design}-optimal plan of {len(identify_at)} poses: mark '
                           f'error predicted {errors["rms"] * 1e6:.2f} um RMS, '
                           f'{errors["max"] * 1e6:.2f} um max (1 sigma) before anything moves')

    def stop(phase, target, feeds):
        reading, direction = move(feeds)
        stops.append(Stop(phase, target, np.asarray(reading, float),
                          np.asarray(direction, float), np.asarray(measure(), float)))
        record(stops[-1])
        # An adaptive plan adds poses: the count grows past the first plan's total.
        progress(len(stops), max(total, len(stops)),
                 f'{phase} {len(stops)}/{max(total, len(stops))}')

    for target, feeds in zip(identify_at, nominal_feeds):
        stop('identify', target, feeds)
    result = identify(data_of([s for s in stops if s.phase == 'identify']), nominal)
    if plan.target_error > 0:
        result, prediction['adaptive'] = _adapt(plan, nominal, result, stop, stops, progress)
    calibrated = inverse(result.geometry, evaluate_at)
    for target, feeds in zip(evaluate_at, nominal_feeds[len(identify_at):]):
        stop('evaluate_nominal', target, feeds)
    for target, feeds in zip(evaluate_at, calibrated):
        stop('evaluate_calibrated', target, feeds)
    return result, evaluate(stops), stops, prediction


def _adapt(plan: PlatformPlan, nominal: PlatformGeometry, result: Identification, stop,
           stops: list, progress) -> tuple[Identification, dict]:
    """The adaptive rounds of :class:`PlatformPlan` (decided by
    :class:`calib_core.planning.Adaptive`): (the last identification, the rounds with their
    predictions and why it stopped)."""
    criterion = 'I' if plan.design == 'random' else plan.design
    rounds = Adaptive(plan.target_error, plan.max_poses, plan.step, 'poses',
                      ' (the tracker and feed noise and the span decide it)')
    while True:
        poses = np.array([s.measured for s in stops if s.phase == 'identify'])
        now = predict_platform(result.geometry, poses,
                               default_working(plan.span, plan.seed, plan.home))
        rms = now.report()['predicted_mark_error_m']['rms']
        progress(len(stops), len(stops), f'adaptive: {len(poses)} poses, mark error predicted '
                 f'{rms * 1e6:.2f} um RMS (target {plan.target_error * 1e6:.2f} um)')

        def extend(room, poses=poses):
            best = extend_platform(result.geometry, nominal, poses, room, criterion=criterion,
                                   span=plan.span, seed=plan.seed, home=plan.home)
            return best.poses[len(poses):], best.report()['predicted_mark_error_m']['rms']
        added = rounds.more(rms, len(poses), extend)
        if added is None:
            return result, rounds.report()
        for target_pose, feeds in zip(added, inverse(nominal, added)):
            stop('identify', target_pose, feeds)
        result = identify(data_of([s for s in stops if s.phase == 'identify']), nominal)
