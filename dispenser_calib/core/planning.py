"""The five-axis calibration's stops chosen for what the user needs (issue 32), with the
shared planner (:mod:`calib_core.planning`), and what they are predicted to give before
anything moves.

Candidates: stops of the kinds the stepwise start needs (linear stops at a = c = 0 spread
over X, Y and Z; A turned alone; C turned alone) and stops with A and C both turned, each
aimed so the board's centre is on the optical axis at the working distance, inside the
strokes, keeping most of the board in view through the nominal model, and seen no more
steeply than the Mark detector can find its dots (:data:`MAX_VIEW_DEG`). Each
candidate's rows are the pixels of its visible dots, differentiated by the 31 parameters
at the nominal (or current) model and divided by the detection noise; they enter the
planner as the triangular factor of their information (31 rows), which is all a design
criterion sees of them.

What the user needs: where a point of the part lands in the camera's (the needle's)
frame at the poses the machine will dispense at, A within +-45 degrees and C anywhere.
Its sensitivity to the parameters is the working sensitivity of the test-pose (I)
criterion; the prediction is first order and from the detection noise alone.

The stepwise start needs 4 linear stops not in one plane and two angles of each rotary
axis turned alone: the plan reserves them first (greedy within their kind), then adds
the stops that most improve the criterion from every kind.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.checks import plan_rows, whole_number
from calib_core.errors import InvalidInputError
from calib_core.planning import CRITERIA, Adaptive, augment, information, predicted_errors
from dispenser_calib.core.calibration import calibrate
from dispenser_calib.core.data import SHIPPED_BOARD, Board, board_points, check_poses
from dispenser_calib.core.iso230 import iso230_7_report
from dispenser_calib.core.model import (
    NAMES, DispenserModel, camera_points, chain_rotation, place, project_rows)
from dispenser_calib.core.procedure import (
    NEEDLE_TIP, PART_PATH, SHIPPED_WORKSPACE, Workspace, evaluation_stops,
    plan_stops)

NOISE_PX = 0.1              # px, 1 sigma per coordinate of a detected dot
# Linear candidates about the aimed pose (m): X and Y keep the 20 x 16 mm board inside the
# 40 x 34 mm field at 120 mm; Z moves the camera, and so the board out of focus, within the
# depth of field (m either way; Z in five steps). The default is of today's plan's +-4 mm: a
# 25 mm lens at f/8 focused at 120 mm blurs a dot 40 mm nearer by about 120 px, more than
# the dot; the simulated camera images it sharp whatever Z is.
LINEAR_XY = {'x': (-6e-3, 0.0, 6e-3), 'y': (-5e-3, 0.0, 5e-3)}
DEPTH_OF_FIELD = 5e-3
A_ALONE_DEG = tuple(range(-80, 81, 10))
C_ALONE_DEG = tuple(range(15, 360, 15))
BOTH_A_DEG, BOTH_C_DEG = (-60, -30, 30, 60), tuple(range(0, 360, 30))
MIN_IN_VIEW = 0.8           # share of the board's dots a candidate must keep in view
# The steepest view of the board a candidate may have (angle between the board's normal and
# the line of sight to its centre): a dot seen at 60 degrees is an ellipse of aspect 2, under
# the Mark detector's limit of 2.5 (66 degrees, calib_core.marks.config.MAX_ELLIPSE_ASPECT)
# with room for perspective; steeper, the dots are not found on a real frame, and the
# board's far edge leaves the depth of field. The simulated camera images them anyway.
MAX_VIEW_DEG = 60.0
# The stepwise start's minimum per kind (dispenser_calib.core.calibration.stepwise).
RESERVED = (('linear', 4), ('a', 2), ('c', 2))
WORKING_POSES = 30
STEP = 1e-6                 # relative step of the central differences


@dataclass(frozen=True)
class FiveAxisPlan:
    """The chosen stops (n, 5) (x, y, z m; a, c rad), the kind of each, the candidates
    considered, and the prediction: every parameter's 1-sigma, every ISO 230-7 error's, and
    the part points' error at the working poses (m)."""

    stops: np.ndarray
    kinds: list
    candidates: int
    criterion: str
    noise_px: float
    parameter_sigmas: dict
    iso230_7_sigmas: dict
    working_error_m: dict

    def report(self) -> dict:
        return {'criterion': self.criterion, 'stops': len(self.stops),
                'kinds': {k: self.kinds.count(k) for k in ('linear', 'a', 'c', 'both')},
                'candidates': self.candidates, 'noise_px': self.noise_px,
                'predicted_parameter_sigmas': self.parameter_sigmas,
                'predicted_iso230_7_sigmas': self.iso230_7_sigmas,
                'predicted_working_error_m': self.working_error_m,
                'working': f'{WORKING_POSES} poses with A within +-45 deg and C anywhere, the '
                           f'{len(PART_PATH)} points of the part\'s path brought to the needle '
                           'tip; their place in the camera (needle) frame, less the offset '
                           'common to all (taken up by the tip measured through the camera)',
                'note': 'first order, from the detection noise alone; effects the model '
                        'lacks come on top'}


def candidate_stops(model: DispenserModel, image_size, depth_of_field: float = DEPTH_OF_FIELD,
                    workspace: Workspace = SHIPPED_WORKSPACE) -> tuple[np.ndarray, list]:
    """Stops (M, 5) inside the ``workspace``'s strokes, aimed at its working distance, with
    at least :data:`MIN_IN_VIEW` of the board in view through ``model``, seen at
    :data:`MAX_VIEW_DEG` or less, the linear ones within ``depth_of_field`` (m) of focus;
    and the kind of each ('linear', 'a', 'c', 'both')."""
    centre = np.array([0.0, 0.0, workspace.working_distance])
    aimed = place(model, np.zeros(3), 0.0, 0.0, centre)
    stops, kinds = [], []
    for dx in LINEAR_XY['x']:
        for dy in LINEAR_XY['y']:
            for dz in np.unique(np.linspace(-depth_of_field, depth_of_field, 5)):
                stops.append(aimed + np.array([dx, dy, dz, 0.0, 0.0]))
                kinds.append('linear')
    angles = ([(a, 0.0, 'a') for a in A_ALONE_DEG if a]
              + [(0.0, c, 'c') for c in C_ALONE_DEG]
              + [(a, c, 'both') for a in BOTH_A_DEG for c in BOTH_C_DEG if c])
    for a, c, kind in angles:
        stops.append(place(model, np.zeros(3), np.deg2rad(a), np.deg2rad(c), centre))
        kinds.append(kind)
    stops = np.array(stops)
    keep = (np.array([workspace.inside(s) for s in stops])
            & (_in_view(model, stops, image_size, workspace.board).mean(axis=1) >= MIN_IN_VIEW)
            & (view_angle(model, stops) <= np.deg2rad(MAX_VIEW_DEG)))
    return stops[keep], [k for k, kept in zip(kinds, keep) if kept]


def view_angle(model: DispenserModel, stops: np.ndarray) -> np.ndarray:
    """Angle (rad) between the board's normal and the line of sight to its centre at each
    stop (M,), through ``model``."""
    normal = chain_rotation(model, stops[:, 3], stops[:, 4])[:, :, 2]          # (M, 3)
    centre = camera_points(model, np.zeros(3), stops)[:, 0]                     # (M, 3)
    cosine = np.abs(np.einsum('mi,mi->m', normal, centre)) / np.linalg.norm(centre, axis=1)
    return np.arccos(np.clip(cosine, 0.0, 1.0))


def _in_view(model: DispenserModel, stops: np.ndarray, image_size,
             board: Board = SHIPPED_BOARD) -> np.ndarray:
    """Which of the ``board``'s dots each stop images through ``model``, (M, k) bool."""
    points, _ = board_points(board)
    pixels = _pixels(model, points, stops, board.radius).reshape(len(stops), len(points), 2)
    width, height = image_size
    return (np.all(np.isfinite(pixels), axis=2) & (pixels[..., 0] >= 0)
            & (pixels[..., 0] <= width - 1) & (pixels[..., 1] >= 0)
            & (pixels[..., 1] <= height - 1))


def _pixels(model: DispenserModel, points: np.ndarray, stops: np.ndarray,
            dot_radius: float) -> np.ndarray:
    """Every point at every stop, (stops x points, 2) px, dots (of ``dot_radius``, m) as
    their images' centres."""
    rows = np.tile(points, (len(stops), 1))
    poses = np.repeat(stops, len(points), axis=0)
    return project_rows(model, rows, poses, dot_radius)


def _derivatives(function, model: DispenserModel) -> np.ndarray:
    """Central differences of ``function(model)`` (n,) by every parameter, (n, p)."""
    columns = []
    for j, value in enumerate(model.values):
        step = STEP * max(1.0, abs(value))
        up, down = model.values.copy(), model.values.copy()
        up[j] += step
        down[j] -= step
        columns.append((function(DispenserModel(up)) - function(DispenserModel(down)))
                       / (2 * step))
    return np.column_stack(columns)


def stop_rows(model: DispenserModel, stops: np.ndarray, image_size,
              noise_px: float = NOISE_PX, board: Board = SHIPPED_BOARD) -> np.ndarray:
    """Each stop's identification rows of the ``board``'s dots whitened by the detection
    noise, as the triangular factor R (p, p) of its information (R^T R = J^T J /
    noise^2), (M, p, p)."""
    points, _ = board_points(board)
    jacobian = _derivatives(lambda m: _pixels(m, points, stops, board.radius).ravel(),
                            model) / noise_px
    jacobian = jacobian.reshape(len(stops), 2 * len(points), -1)
    # Rows of dots out of view carry nothing.
    seen = np.repeat(_in_view(model, stops, image_size, board), 2, axis=1)
    jacobian = np.where(seen[..., None], jacobian, 0.0)
    return np.linalg.qr(jacobian, mode='r')


def _working_poses(model: DispenserModel, seed: int) -> np.ndarray:
    """(W, k, 5): at each of the working table angles, the pose that brings each of the
    part path's k points to the needle's tip through ``model``."""
    angles = evaluation_stops(model, WORKING_POSES, seed + 1)[:, 3:]
    return np.array([[place(model, point, a, c, NEEDLE_TIP) for point in PART_PATH]
                     for a, c in angles])


def _landed(model: DispenserModel, poses: np.ndarray) -> np.ndarray:
    """Where the part path's points are in the camera frame at ``poses`` (W, k, 5), per
    ``model``: (W, k, 3) m."""
    return np.stack([camera_points(model, point, poses[:, k])[:, 0]
                     for k, point in enumerate(PART_PATH)], axis=1)


def working_sensitivity(model: DispenserModel, seed: int = 0) -> np.ndarray:
    """d(part point in the camera frame)/d(parameters) at the working poses, (W, 3 k, p) m
    per parameter unit: :data:`WORKING_POSES` table angles with A within +-45 degrees and
    C anywhere (:func:`evaluation_stops`), each of the part path's k points brought to the
    needle's tip there by the linear axes (:func:`place`), as a dispensing path is. The
    displacement common to every point and pose is taken out: the tip is measured through
    the same camera and model (:func:`procedure.tip_from_dots`), which takes it up; what
    is left is what the user sees on the part."""
    poses = _working_poses(model, seed)
    derivative = _derivatives(lambda m: _landed(m, poses).ravel(), model)
    derivative = derivative.reshape(len(poses), len(PART_PATH), 3, -1)
    derivative -= derivative.mean(axis=(0, 1))
    return derivative.reshape(len(poses), 3 * len(PART_PATH), -1)


def placement_error(model: DispenserModel, reference: DispenserModel, seed: int = 0) -> float:
    """RMS (m) of where the part path's points land against the needle's tip at the
    working poses (:func:`working_sensitivity`'s) when placed with ``model`` on the machine
    ``reference`` describes (a simulation's truth, a better calibration), the offset common
    to every point and pose taken out: what the predicted working error is the 1-sigma of."""
    landed = _landed(reference, _working_poses(model, seed)).reshape(-1, 3)
    landed -= landed.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum(landed ** 2, axis=1))))


def _scales(model: DispenserModel) -> np.ndarray:
    """Column scales that bring the parameters to one order of size (as the refinement
    scales them): px, m and rad differ by 10 orders, and a factor or inverse of the
    unscaled information loses the weak directions (the principal point against the
    board's lateral place). The criteria do not depend on them."""
    return np.maximum(np.abs(model.values), 1e-3)


def predict(model: DispenserModel, stops: np.ndarray, image_size, noise_px: float = NOISE_PX,
            seed: int = 0, rows: np.ndarray | None = None,
            board: Board = SHIPPED_BOARD) -> dict:
    """What the identification from ``stops`` (n, 5) of ``board`` will give, first order:
    the parameters' covariance, their and the ISO 230-7 errors' 1-sigma and the working
    error (m: RMS, median and max over the working poses and points of the 3-D error)."""
    scale = _scales(model)
    rows = (stop_rows(model, stops, image_size, noise_px, board) if rows is None
            else rows) * scale
    covariance = np.linalg.inv(information(rows, np.arange(len(rows)))) * np.outer(scale, scale)
    working = working_sensitivity(model, seed)
    per_row = predicted_errors(covariance, working)                 # (W, 3 k)
    per_point = np.sqrt(np.sum(per_row.reshape(len(working), -1, 3) ** 2, axis=2))
    return {'covariance': covariance,
            'parameter_sigmas': dict(zip(NAMES, map(float, np.sqrt(np.diag(covariance))))),
            'iso230_7_sigmas': iso230_7_report(model, covariance)['std_devs'],
            'working_error_m': {'rms': float(np.sqrt(np.mean(per_point ** 2))),
                                'median': float(np.median(per_point)),
                                'max': float(per_point.max())}}


@dataclass(frozen=True)
class _Candidates:
    """The candidate stops (M, 5), their kinds, the parameter scales (p,), each stop's
    scaled rows (M, p, p), the scaled working sensitivity (None for 'D') and a prior of a
    millionth of a mean stop's information per parameter (the start from nothing, where
    the criterion is not yet defined)."""

    stops: np.ndarray
    kinds: list
    scale: np.ndarray
    rows: np.ndarray
    working: np.ndarray | None
    prior: np.ndarray


def _candidates(model: DispenserModel, image_size, criterion: str, noise_px: float, seed: int,
                depth_of_field: float, needed: int,
                workspace: Workspace = SHIPPED_WORKSPACE) -> _Candidates:
    """The candidates of :func:`candidate_stops` and their rows; at least ``needed`` of them.

    Raises
    ------
    InvalidInputError
        Fewer candidates than ``needed``."""
    stops, kinds = candidate_stops(model, image_size, depth_of_field, workspace)
    if needed > len(stops):
        raise InvalidInputError(f'{needed} stops asked from {len(stops)} candidates (inside '
                                f'the strokes and with {MIN_IN_VIEW:.0%} of the board in a '
                                f'{image_size[0]}x{image_size[1]} px image through the model)')
    scale = _scales(model)
    rows = stop_rows(model, stops, image_size, noise_px, workspace.board) * scale
    working = working_sensitivity(model, seed) * scale if criterion == 'I' else None
    prior = np.diag(1e-6 * np.einsum('mrp,mrp->p', rows, rows) / len(rows))
    return _Candidates(stops, kinds, scale, rows, working, prior)


def plan_five_axis(model: DispenserModel, count: int, image_size, criterion: str = 'I',
                   noise_px: float = NOISE_PX, seed: int = 0,
                   depth_of_field: float = DEPTH_OF_FIELD,
                   workspace: Workspace = SHIPPED_WORKSPACE) -> FiveAxisPlan:
    """``count`` stops chosen from :func:`candidate_stops` in ``workspace`` by
    ``criterion`` ('I': the part points' error at the working poses; 'D': the
    information's determinant), the stepwise start's minimum reserved first; and their
    prediction.

    Raises
    ------
    InvalidInputError
        Fewer stops than the stepwise start needs, more than the candidates, an unknown
        criterion."""
    if criterion not in CRITERIA:
        raise InvalidInputError(f'criterion must be one of {", ".join(CRITERIA)}, not '
                                f'{criterion}')
    least = sum(n for _, n in RESERVED)
    if count < least:
        raise InvalidInputError(f'{count} stops: the stepwise start needs at least {least} '
                                '(4 linear, A and C each alone at two angles)')
    c = _candidates(model, image_size, criterion, noise_px, seed, depth_of_field, count,
                    workspace)
    chosen: list[int] = []
    kinds = np.array(c.kinds)
    for kind, needed in RESERVED:
        others = np.flatnonzero(kinds != kind).tolist()
        picked = augment(c.rows, c.prior + information(c.rows, chosen), needed, criterion,
                         c.working, exclude=set(chosen) | set(others))
        chosen += picked.tolist()
    chosen += augment(c.rows, c.prior + information(c.rows, chosen), count - len(chosen),
                      criterion, c.working, exclude=chosen).tolist()
    chosen_stops = c.stops[chosen]
    linear = chosen_stops[kinds[chosen] == 'linear', :3]
    if np.linalg.matrix_rank(np.column_stack([linear, np.ones(len(linear))]), tol=1e-6) < 4:
        raise InvalidInputError('the planned linear stops lie in one plane: the stepwise start '
                                'cannot use them; plan more stops')
    predicted = predict(model, chosen_stops, image_size, noise_px, seed,
                        c.rows[chosen] / c.scale)
    return FiveAxisPlan(chosen_stops, [c.kinds[k] for k in chosen], len(c.stops), criterion,
                        noise_px, predicted['parameter_sigmas'], predicted['iso230_7_sigmas'],
                        predicted['working_error_m'])


def todays_prediction(model: DispenserModel, image_size, noise_px: float = NOISE_PX,
                      seed: int = 0, workspace: Workspace = SHIPPED_WORKSPACE) -> dict:
    """The prediction for today's stepwise plan (:func:`plan_stops`) in ``workspace``, to
    compare, with its stops (n, 5) m, rad."""
    stops = plan_stops(model, seed, workspace)
    return {**predict(model, stops, image_size, noise_px, seed, board=workspace.board),
            'stops': len(stops),
            'stops_m_rad': stops.tolist()}


def stops_from_plan_keys(options: dict, model: DispenserModel, image_size,
                         seed: int = 0, noise_px: float = NOISE_PX,
                         workspace: Workspace = SHIPPED_WORKSPACE
                         ) -> tuple[np.ndarray | None, dict | None, 'AdaptivePlan | None']:
    """The calibrator's plan keys: ``targets`` (a list of [x, y, z m, a, c rad] stops, as
    given), or ``design`` ('I' or 'D') with ``stops`` (how many, default 27) planned about
    ``model`` in ``workspace``, predicted at ``noise_px``; neither: (None, None), the
    stepwise plan. With ``target_error`` (m) the run is adaptive (:class:`AdaptivePlan`,
    ``max_stops`` and ``step`` with it). Returns the stops (n, 5), when planned the plan's
    report (its prediction), and the adaptive plan or None.

    Raises
    ------
    InvalidInputError
        Both keys, malformed targets, mm or degrees (beyond what a dispenser's axes read),
        ``max_stops`` or ``step`` without ``target_error``.
    StrokeError
        A target outside a stroke (before anything moves)."""
    if 'targets' in options and 'design' in options:
        raise InvalidInputError('give targets (the stops as given) or design (stops planned '
                                'here), not both')
    if 'stops' in options and 'design' not in options:
        raise InvalidInputError('stops is the number of stops a design plans: give design '
                                '(I or D) with it')
    adaptive = None
    if 'target_error' in options:
        adaptive = AdaptivePlan(tuple(image_size), options['target_error'],
                                options.get('max_stops', 60), options.get('step', 4),
                                str(options.get('design', 'I')), noise_px, seed, workspace)
    elif {'max_stops', 'step'} & set(options):
        raise InvalidInputError('max_stops and step belong to the adaptive mode: give '
                                'target_error (m) with them')
    if 'targets' in options:
        targets = plan_rows(options['targets'], 'x, y, z, a, c (m, rad)', 'targets')
        check_poses(targets, 'targets')
        for pose in targets:
            workspace.check(pose)
        return targets, None, adaptive
    if 'design' in options:
        count = whole_number(options.get('stops', 27), 'stops', sum(n for _, n in RESERVED))
        plan = plan_five_axis(model, count, image_size, str(options['design']), noise_px, seed,
                              workspace=workspace)
        return plan.stops, plan.report(), adaptive
    return None, None, adaptive


def extend_five_axis(model: DispenserModel, measured: np.ndarray, count: int, image_size,
                     criterion: str = 'I', noise_px: float = NOISE_PX, seed: int = 0,
                     depth_of_field: float = DEPTH_OF_FIELD,
                     workspace: Workspace = SHIPPED_WORKSPACE) -> tuple[np.ndarray, dict]:
    """The ``count`` candidate stops (count, 5) in ``workspace`` that, added one by one to
    the ``measured`` ones (n, 5), most improve the criterion about ``model`` (greedy, so
    the first k of them are the best k), and the prediction for all of them together."""
    c = _candidates(model, image_size, criterion, noise_px, seed, depth_of_field, 1,
                    workspace)
    measured_rows = stop_rows(model, measured, image_size, noise_px, workspace.board) * c.scale
    prior = c.prior + information(measured_rows, np.arange(len(measured)))
    taken = [k for k, stop in enumerate(c.stops)
             if np.any(np.all(np.abs(measured - stop) < 1e-9, axis=1))]
    count = min(count, len(c.stops) - len(taken))
    chosen = augment(c.rows, prior, count, criterion, c.working, exclude=taken)
    every = np.concatenate([measured_rows, c.rows[chosen]]) / c.scale
    return c.stops[chosen], predict(model, np.vstack([measured, c.stops[chosen]]), image_size,
                                    noise_px, seed, every)


@dataclass
class AdaptivePlan:
    """The adaptive mode (the calibrator's plan keys ``target_error``, ``max_stops``,
    ``step``; its rounds decided by :class:`calib_core.planning.Adaptive`): after the
    planned stops are imaged, calibrate and predict the part's placement error about the
    calibration so far; while it is above ``target_error`` (m, RMS at the working poses),
    add the ``step`` stops that lower it most (inside ``workspace``), image them and
    calibrate again, up to ``max_stops``. Called with the images so far, it returns the
    stops to image next (none when done); :meth:`report` says what happened."""

    image_size: tuple
    target_error: float
    max_stops: int = 60
    step: int = 4
    criterion: str = 'I'
    noise_px: float = NOISE_PX
    seed: int = 0
    workspace: Workspace = SHIPPED_WORKSPACE

    def __post_init__(self):
        self.max_stops = whole_number(self.max_stops, 'max_stops', sum(n for _, n in RESERVED))
        self.step = whole_number(self.step, 'step', 1)
        self._adaptive = Adaptive(self.target_error, self.max_stops, self.step, 'stops',
                               ' (the detection noise and the strokes decide it)')

    def __call__(self, images: list) -> np.ndarray:
        # The calibration (not only its prediction) comes first: the Jacobian is taken
        # about the machine as measured so far, not about the nominal one.
        _, result = calibrate(images, self.image_size)
        measured = np.array([im.pose for im in images])
        now = predict(result.model, measured, self.image_size, self.noise_px, self.seed,
                      board=self.workspace.board)

        def extend(room):
            more, best = extend_five_axis(result.model, measured, room, self.image_size,
                                          self.criterion, self.noise_px, self.seed,
                                          workspace=self.workspace)
            return more, best['working_error_m']['rms']
        more = self._adaptive.more(now['working_error_m']['rms'], len(measured), extend)
        return np.zeros((0, 5)) if more is None else more

    def report(self) -> dict:
        return self._adaptive.report()
