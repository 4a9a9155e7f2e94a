"""Planning the XY-Theta stage's calibration run: which stops to measure beside the sweeps
so that the parametric calibration predicts the platform best where the stage will work,
and what it will reach, stated before the stage moves.

The stepwise start needs its three sweeps (each input up and back), so they stay, short
(``sweep_points`` per way) if asked; the planner replaces the workspace grid by stops
chosen from candidates inside the stroke (:func:`candidate_inputs`) with the shared
:func:`calib_core.planning.augment`, the sweeps' information being the prior.

Rows: per stop, the parametric model's Jacobian of the two calibration Marks' plate
positions (4 rows) by its free parameters (the gauge of
:data:`~printer_alignment.core.stage_calibration.parametric.PARAMETRIC_GAUGE` fixed, the
Marks' platform positions free), whitened by the stop's noise (the camera's on each
coordinate and each chain's landing through the kinematics) to choose; the prediction is
the covariance of the ordinary least squares the calibration runs (the sandwich with that
noise). The I criterion: the mean
squared error of the two Marks' predicted plate positions at working inputs approached
from below, as the aligner moves (default: random inputs within 80 % of the stroke, as the
paper's evaluation). Directions of approach follow from the order the stops are visited
in: the plan's stops are ordered first, their prediction made with the directions that
order gives.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import InvalidInputError
from calib_core.parameters import Parameter, ParameterSet
from calib_core.planning import (
    CRITERIA, augment, information, predicted_errors, sandwich_covariance, whiten)
from printer_alignment.core.geometry import rotate_points
from printer_alignment.core.stage import (
    CAMERA_NOISE, LANDING_SIGMA, NOMINAL_STAGE, STROKE, StageGeometry, check_stroke, landing_directions)
from printer_alignment.core.stage_calibration.data import StagePlan
from printer_alignment.core.stage_calibration.parametric import (
    PARAMETRIC_GAUGE, mark_names, predict_marks)

WORKING_REACH = 0.8        # of the stroke: where the aligner works
# The shipped stage's calibration Marks' plate positions with it at home (m: x1, y1, x2, y2),
# as the stage calibrator is taught them by default (its calibration_marks).
TAUGHT_HOME_MARKS = (0.0351, 0.0791, 0.1551, 0.0797)
STEP = 1e-8                # m or rad: central-difference step of the parameters


@dataclass(frozen=True)
class StageDesign:
    """A planned calibration run and what it is predicted to give.

    Attributes
    ----------
    targets : (n, 3) array
        Inputs in visiting order, m: home, the sweeps, then the planned stops.
    planned : int
        How many of them the planner chose (the rest are home and the sweeps).
    std_devs : dict
        Predicted 1-sigma of each free parameter (SI units).
    predicted_rms_m, predicted_max_m : float
        Predicted error of the Marks' plate positions at the working inputs, m (RMS over
        them, the largest 1-sigma).
    criterion : str
    candidates : int
    """

    targets: np.ndarray
    planned: int
    std_devs: dict
    predicted_rms_m: float
    predicted_max_m: float
    criterion: str
    candidates: int

    def report(self) -> dict:
        return {'stops': int(len(self.targets)), 'planned_stops': self.planned,
                'criterion': self.criterion, 'candidates': self.candidates,
                'predicted_rms_m': self.predicted_rms_m,
                'predicted_max_m': self.predicted_max_m,
                'predicted_std_devs': self.std_devs,
                'prediction': 'the Marks\' plate positions at the working inputs, from the '
                              'noise stated and the model at the nominal (or given) geometry'}


def free_parameters(geometry: StageGeometry, marks) -> ParameterSet:
    """The parametric fit's parameters at ``geometry`` and the Marks' platform positions
    ``marks`` (2, 2) m, the gauge fixed as the fit fixes it."""
    parameters = ParameterSet(geometry.as_parameters().parameters + [
        Parameter(n, float(v), 'm') for n, v in zip(mark_names(), np.ravel(marks))])
    for name in PARAMETRIC_GAUGE:
        parameters.set_free(name, False)
    return parameters


def platform_marks(home_marks, geometry: StageGeometry | None = None) -> np.ndarray:
    """The calibration Marks' platform positions (2, 2) m from their plate positions with
    the stage at home (as taught), through ``geometry`` (default the nominal stage)."""
    geometry = geometry or NOMINAL_STAGE
    pose = geometry.stage_to_plate(geometry.forward(np.zeros((1, 3))))[0]
    return rotate_points(-pose[2], np.asarray(home_marks, dtype=float) - pose[:2])


def _marks(parameters: ParameterSet, vector, q, directions) -> np.ndarray:
    values = parameters.with_free_vector(vector).as_dict()
    marks = np.array([values[n] for n in mark_names()]).reshape(2, 2)
    return predict_marks(StageGeometry.from_parameters(values), marks, q,
                         directions).reshape(len(q), 4)


def mark_jacobian(parameters: ParameterSet, q, directions) -> np.ndarray:
    """d(Marks' plate positions)/d(free parameters), (n, 4, p), at inputs ``q`` (n, 3) m
    approached from ``directions`` (n, 3); central differences."""
    x0 = parameters.free_vector()
    columns = []
    for j in range(len(x0)):
        step = np.zeros_like(x0)
        step[j] = STEP
        columns.append((_marks(parameters, x0 + step, q, directions)
                        - _marks(parameters, x0 - step, q, directions)) / (2 * STEP))
    return np.stack(columns, axis=-1)


def stop_noise(parameters: ParameterSet, q, directions, landing_sigma: float = LANDING_SIGMA,
               camera_noise: float = CAMERA_NOISE) -> np.ndarray:
    """Covariance (n, 4, 4) of each stop's measured Marks, m^2: every chain lands with
    ``landing_sigma`` and the camera adds ``camera_noise`` per coordinate."""
    x0 = parameters.free_vector()
    columns = []
    for k in range(3):
        step = np.zeros(3)
        step[k] = STEP
        columns.append((_marks(parameters, x0, q + step, directions)
                        - _marks(parameters, x0, q - step, directions)) / (2 * STEP))
    through = np.stack(columns, axis=-1)                                   # (n, 4, 3)
    return (landing_sigma ** 2 * through @ np.swapaxes(through, 1, 2)
            + camera_noise ** 2 * np.eye(4))


def whitened_rows(parameters: ParameterSet, q, directions, **noise) -> np.ndarray:
    """Each stop's Jacobian divided by its noise's Cholesky factor, (n, 4, p)."""
    return whiten(mark_jacobian(parameters, q, directions),
                  stop_noise(parameters, q, directions, **noise))


def candidate_inputs(per_axis: int = 9, span: float = StagePlan.span,
                     stroke: float = STROKE) -> np.ndarray:
    """Inputs (n, 3) m on a grid of q1, (q2 + q3) / 2 and q3 - q2 inside ``span`` of the
    ``stroke`` (m), where the mean and the difference of q2 and q3 share it as the plan's
    grid does (|mean| + |difference| / 2 <= reach)."""
    reach = span * stroke
    levels = np.linspace(-1, 1, per_axis)
    rows = [[q1 * reach, (m * (reach - abs(w) * reach / 2)) - w * reach / 2,
             (m * (reach - abs(w) * reach / 2)) + w * reach / 2]
            for w in levels for m in levels for q1 in levels]
    return np.unique(np.round(check_stroke(np.array(rows), stroke), 12), axis=0)


def default_working(count: int = 40, seed: int = 0, stroke: float = STROKE) -> np.ndarray:
    """Working inputs (count, 3) m: uniform within WORKING_REACH of the ``stroke`` (m), as
    the paper's evaluation draws its targets."""
    reach = WORKING_REACH * stroke
    return np.random.default_rng(seed).uniform(-reach, reach, (count, 3))


def visiting_directions(targets: np.ndarray) -> np.ndarray:
    """Each chain's direction of its last motion (n, 3) when ``targets`` (n, 3) m are
    visited in order from home, as :func:`landing_directions` lands them (the stage starts
    with +1)."""
    directions = np.ones_like(targets)
    previous, now = np.ones(3), np.zeros(3)
    for k, q in enumerate(targets):
        previous = directions[k] = landing_directions(now, q, previous)
        now = q
    return directions


def route(stops: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``stops`` (n, 3) in a short visiting order from ``start`` (3,): the nearest one not
    visited yet, each time."""
    left, order, now = list(range(len(stops))), [], np.asarray(start, float)
    while left:
        nearest = min(left, key=lambda k: float(np.abs(stops[k] - now).max()))
        order.append(nearest)
        left.remove(nearest)
        now = stops[nearest]
    return stops[order]


def _design(parameters: ParameterSet, q, directions, working, criterion: str,
            candidates: int, planned: int, **noise) -> StageDesign:
    # The covariance of the fit the suite runs: ordinary least squares on the Marks, whose
    # noise is correlated within a stop (the landing moves both Marks): the sandwich.
    covariance = sandwich_covariance(mark_jacobian(parameters, q, directions),
                                     stop_noise(parameters, q, directions, **noise))
    sensitivity = mark_jacobian(parameters, working, np.ones_like(working))
    errors = predicted_errors(covariance, sensitivity.reshape(-1, 2, covariance.shape[0]))
    per_mark = np.linalg.norm(errors.reshape(len(working), 2, 2), axis=2)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0, None))
    return StageDesign(np.asarray(q, dtype=float), planned,
                       dict(zip(parameters.free_names, map(float, sigma))),
                       float(np.sqrt(np.mean(per_mark ** 2))), float(per_mark.max()),
                       criterion, candidates)


def predict_stage_plan(geometry: StageGeometry, marks, targets, working=None,
                       criterion: str = 'I', candidates: int = 0, planned: int = 0,
                       stroke: float = STROKE, **noise) -> StageDesign:
    """What the calibration run ``targets`` (n, 3) m, visited in that order, is predicted to
    give: each free parameter's 1-sigma and the Marks' error at the ``working`` inputs
    (default: :func:`default_working` in the ``stroke``, m)."""
    targets = check_stroke(np.asarray(targets, dtype=float), stroke)
    working = (default_working(stroke=stroke) if working is None
               else np.asarray(working, dtype=float))
    return _design(free_parameters(geometry, marks), targets, visiting_directions(targets),
                   working, criterion, candidates, planned, **noise)


def predict_stage_run(geometry: StageGeometry, marks, q, directions, working=None,
                      stroke: float = STROKE, **noise) -> StageDesign:
    """The same for stops measured already, ``q`` (n, 3) m with the ``directions`` (n, 3)
    the stage reported, about ``geometry`` and ``marks`` (the ones identified so far)."""
    working = (default_working(stroke=stroke) if working is None
               else np.asarray(working, dtype=float))
    return _design(free_parameters(geometry, marks), q, directions, working, 'I', 0, 0,
                   **noise)


def identified(report: dict) -> tuple[StageGeometry, np.ndarray]:
    """The parametric calibration's geometry and the Marks' platform positions (2, 2) m
    from ``calibrate_stage``'s report."""
    values = report['parametric']['parameters']
    return (StageGeometry.from_parameters(values),
            np.array([values[n] for n in mark_names()]).reshape(2, 2))


def _choose(parameters: ParameterSet, q, directions, count: int, working, criterion: str,
            per_axis: int, stroke: float = STROKE, **noise) -> tuple[np.ndarray, int]:
    """The ``count`` candidates (count, 3) m inside the ``stroke`` (m) that, added one by
    one to the stops ``q`` (with their ``directions``), most lower the criterion (greedy:
    the first k are the best k), and how many candidates there were."""
    if criterion not in CRITERIA:
        raise InvalidInputError(f'criterion must be one of {", ".join(CRITERIA)}, not '
                                f'{criterion}')
    pool = candidate_inputs(per_axis, stroke=stroke)
    measured = whitened_rows(parameters, q, directions, **noise)
    # The candidates' directions are those of a stop reached from home, which the route
    # later replaces by its own: the backlash terms are small beside the geometry's.
    rows = whitened_rows(parameters, pool, np.sign(pool + 1e-15), **noise)
    sensitivity = mark_jacobian(parameters, working, np.ones_like(working))
    chosen = augment(rows, information(measured, np.arange(len(measured))),
                     min(count, len(pool)), criterion,
                     sensitivity if criterion == 'I' else None)
    return pool[chosen], len(pool)


def extend_stage(geometry: StageGeometry, marks, q, directions, count: int, working=None,
                 criterion: str = 'I', per_axis: int = 9, stroke: float = STROKE,
                 **noise) -> tuple[np.ndarray, StageDesign]:
    """The ``count`` candidate stops (count, 3) m inside the ``stroke`` (m) that, added one
    by one to the measured ones (``q``, ``directions``), most lower the criterion about
    ``geometry`` and ``marks`` (the ones identified so far; greedy: the first k are the
    best k), and the prediction with all of them, visited nearest first from home after
    the measured ones."""
    parameters = free_parameters(geometry, marks)
    working = (default_working(stroke=stroke) if working is None
               else np.asarray(working, dtype=float))
    chosen, candidates = _choose(parameters, q, directions, count, working, criterion,
                                 per_axis, stroke, **noise)
    added = np.vstack([np.zeros((1, 3)), route(chosen, np.zeros(3))])
    every = np.vstack([q, added[1:]])
    after = np.vstack([directions, visiting_directions(added)[1:]])
    return chosen, _design(parameters, every, after, working, criterion, candidates,
                           len(chosen), **noise)


def plan_stage(geometry: StageGeometry, marks, stops: int, sweep_points: int = 3,
               working=None, criterion: str = 'I', per_axis: int = 9,
               stroke: float = STROKE, **noise) -> StageDesign:
    """Home, the sweeps of ``sweep_points`` per way, and ``stops`` chosen stops.

    Parameters
    ----------
    geometry : StageGeometry
        The nominal (or a calibrated) stage.
    marks : (2, 2) array
        The calibration Marks' platform positions, m (as the stepwise start gives them).
    stops : int
        Stops to choose beside home and the sweeps.
    working : (W, 3) array, optional
        Inputs the stage will work at, m (default :func:`default_working`).
    criterion : 'I' or 'D'
    stroke : float
        Each input's limit either way, m (a machine description's).

    Raises
    ------
    InvalidInputError
        Fewer than one stop or an unknown criterion.
    """
    if not 1 <= stops:
        raise InvalidInputError(f'plan at least one stop beside the sweeps, not {stops}')
    sweeps = StagePlan(sweep_points=sweep_points, stroke=stroke).sweeps()
    working = (default_working(stroke=stroke) if working is None
               else np.asarray(working, dtype=float))
    chosen, candidates = _choose(free_parameters(geometry, marks), sweeps,
                                 visiting_directions(sweeps), stops, working, criterion,
                                 per_axis, stroke, **noise)
    targets = np.vstack([sweeps, route(chosen, sweeps[-1])])
    return predict_stage_plan(geometry, marks, targets, working, criterion, candidates,
                              len(chosen), stroke, **noise)
