"""Self-calibration of the XY-Theta stage with the machine's own camera.

Data: at each commanded input vector q the camera measures two calibration Marks on the
platform (plate frame, m). The plan moves the stage along the paper's trajectories: an X
sweep (q1 alone), a Y sweep (q2 = q3), an attitude sweep (q3 - q2 at q1 = 0, q2 = -q3)
and a grid over the workspace; sweeps go up and then down so both directions of approach
occur on every chain.

Two methods use the same measurements:

- :func:`stepwise_calibration`, the paper's: moving-platform frame (home pose, X direction,
  rotation centre of the attitude sweep), transmission ratios R1..R3 and the distance
  d3 - d2, axis skew alpha1, an attitude table over q3 - q2, and the measured workspace
  poses for interpolation of the remaining input error over triangles (tetrahedra in
  x, y, theta).
- :func:`parametric_calibration`: least squares on the whole error model of
  :class:`~printer_alignment.core.stage.StageGeometry` including backlash, started from
  the stepwise result.

Both return a model with ``forward(q)`` (plate-frame platform pose) and ``inverse(pose)``
(inputs for a plate-frame platform pose, approached from below on every chain).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator, PchipInterpolator

from calib_core.datasets import directions_from_order, read_columns, write_columns
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.least_squares import fit
from calib_core.parameters import Parameter, ParameterSet
from printer_alignment.core.geometry import rotate_points, rotation
from printer_alignment.core.stage import (
    NOMINAL_D, NOMINAL_LEAD, STROKE, StageGeometry, check_stroke, platform_points_in_plate)

STAGE_COLUMNS = ('q1', 'q2', 'q3', 'mark1_x', 'mark1_y', 'mark2_x', 'mark2_y')
STAGE_DIRECTIONS = ('direction1', 'direction2', 'direction3')
UNIDIRECTIONAL = np.ones(3)          # the aligner approaches every target from below
# Triangulation in (x, y, theta): theta scaled by this length so a radian weighs like
# the platform's half width.
ANGLE_SCALE = 0.2                    # m/rad


@dataclass(frozen=True)
class StageData:
    """Calibration Marks measured at commanded stage inputs.

    Attributes
    ----------
    q : ndarray (n, 3)
        Commanded chain inputs, m.
    directions : ndarray (n, 3)
        Direction of each chain's last motion (+1 / -1).
    marks : ndarray (n, 2, 2)
        The two calibration Marks measured in the plate frame, m.
    covariates : dict of str to ndarray (n,)
    """

    q: np.ndarray
    directions: np.ndarray
    marks: np.ndarray
    covariates: dict = field(default_factory=dict)

    def __post_init__(self):
        q = np.atleast_2d(np.asarray(self.q, dtype=float))
        directions = np.atleast_2d(np.asarray(self.directions, dtype=float))
        marks = np.asarray(self.marks, dtype=float).reshape(-1, 2, 2)
        if q.shape[1:] != (3,) or directions.shape != q.shape or len(marks) != len(q):
            raise InvalidInputError(f'q {q.shape}, directions {directions.shape} and marks '
                                    f'{marks.shape} must be (n, 3), (n, 3), (n, 2, 2)')
        for name, value in (('q', q), ('marks', marks)):
            if not np.all(np.isfinite(value)):
                raise InvalidInputError(f'{name} contains NaN or infinite values')
        if not np.all(np.isin(directions, (-1.0, 1.0))):
            raise InvalidInputError('directions must be +1 or -1')
        object.__setattr__(self, 'q', q)
        object.__setattr__(self, 'directions', directions)
        object.__setattr__(self, 'marks', marks)

    def __len__(self) -> int:
        return len(self.q)

    def select(self, rows) -> 'StageData':
        return StageData(self.q[rows], self.directions[rows], self.marks[rows],
                         {k: v[rows] for k, v in self.covariates.items()})

    @classmethod
    def from_csv(cls, path, dropped: dict | None = None) -> 'StageData':
        """Columns q1..q3 (m), mark1_x, mark1_y, mark2_x, mark2_y (m, plate frame);
        optional direction1..3 (+1 / -1; without them, from the order of the rows) and
        covariates such as time (s) or temperature (K)."""
        columns = read_columns(path, list(STAGE_COLUMNS), dropped)
        q = np.column_stack([columns[c] for c in ('q1', 'q2', 'q3')])
        present = [c for c in STAGE_DIRECTIONS if c in columns]
        if present and len(present) != 3:
            raise InvalidInputError(f'{path} has {", ".join(present)} but not all three '
                                    'direction columns')
        directions = (np.column_stack([columns[c] for c in STAGE_DIRECTIONS]) if present
                      else directions_from_order(np.vstack([np.zeros(3), q]))[1:])
        marks = np.column_stack([columns[c] for c in STAGE_COLUMNS[3:]]).reshape(-1, 2, 2)
        used = set(STAGE_COLUMNS) | set(STAGE_DIRECTIONS)
        return cls(q, directions, marks, {k: v for k, v in columns.items() if k not in used})

    def to_csv(self, path) -> None:
        names = list(STAGE_COLUMNS[:3]) + list(STAGE_DIRECTIONS) + list(STAGE_COLUMNS[3:]) \
            + list(self.covariates)
        write_columns(path, names, [self.q, self.directions, self.marks.reshape(-1, 4)]
                      + [self.covariates[k] for k in self.covariates])


@dataclass(frozen=True)
class StagePlan:
    """Which inputs the calibration visits (m). ``span`` is the fraction of the stroke
    used; sweeps have ``sweep_points`` each way, the workspace grid ``grid`` points per
    input (q1, (q2 + q3) / 2, q3 - q2)."""

    sweep_points: int = 9
    grid: tuple = (5, 5, 3)
    span: float = 0.95

    def __post_init__(self):
        if self.sweep_points < 3 or len(self.grid) != 3 or min(self.grid) < 2:
            raise InvalidInputError('sweep_points must be >= 3 and grid three counts >= 2')
        if not 0 < self.span <= 1:
            raise InvalidInputError('span must be in (0, 1]')

    def targets(self) -> np.ndarray:
        """Inputs in visiting order, m, (n, 3). Starts at home; sweeps go up and back."""
        reach = self.span * STROKE
        ramp = np.linspace(-reach, reach, self.sweep_points)
        both_ways = np.concatenate([ramp, ramp[::-1]])
        zero = np.zeros_like(both_ways)
        x_sweep = np.column_stack([both_ways, zero, zero])
        y_sweep = np.column_stack([zero, both_ways, both_ways])
        attitude = np.column_stack([zero, -both_ways, both_ways])
        n1, nm, nw = self.grid
        rows = []
        # Mean of q2, q3 and their difference share the stroke: |qm| + |w| / 2 <= reach.
        for k, w in enumerate(np.linspace(-reach, reach, nw)):
            qm_reach = reach - abs(w) / 2
            for j, qm in enumerate(np.linspace(-qm_reach, qm_reach, nm)):
                q1s = np.linspace(-reach, reach, n1)
                for q1 in (q1s if (j + k) % 2 == 0 else q1s[::-1]):
                    rows.append([q1, qm - w / 2, qm + w / 2])
        return check_stroke(np.vstack([np.zeros((1, 3)), x_sweep, y_sweep, attitude,
                                       np.array(rows)]))


def _rows(q: np.ndarray, condition) -> np.ndarray:
    return np.flatnonzero(condition(q))


def relative_motions(marks: np.ndarray, home: np.ndarray):
    """Rigid plate-frame motions (angle rad (n,), translation m (n, 2)) that carry the two
    ``home`` Marks ((2, 2)) to each measured pair ((n, 2, 2)): ``M = R(angle) M0 + C``."""
    from printer_alignment.core.alignment import rigid_fit
    out = [rigid_fit(home, pair) for pair in marks]
    return np.array([a for a, _ in out]), np.array([c for _, c in out])


def _unique_mean(keys: np.ndarray, values: np.ndarray):
    """Mean of ``values`` over rows with the same ``keys`` (rounded to 1 nm)."""
    rounded = np.round(keys / 1e-9).astype(np.int64)
    unique, inverse = np.unique(rounded, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    sums = np.zeros((len(unique),) + values.shape[1:])
    np.add.at(sums, inverse, values)
    counts = np.bincount(inverse, minlength=len(unique)).reshape((-1,) + (1,) * (values.ndim - 1))
    first = np.array([np.flatnonzero(inverse == i)[0] for i in range(len(unique))])
    return keys[first], sums / counts


class StageModel:
    """Common inverse/forward interface of a calibrated (or nominal) stage."""

    method = 'model'

    def inverse(self, plate_pose) -> np.ndarray:
        raise NotImplementedError

    def forward(self, q, iterations: int = 6) -> np.ndarray:
        """Plate-frame platform poses (n, 3) for inputs q (m, (n, 3)), by Newton on
        :meth:`inverse` with the geometric Jacobian."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pose = self.geometry.stage_to_plate(self.geometry.forward(q, UNIDIRECTIONAL))
        for _ in range(iterations):
            stage_pose = self.geometry.plate_to_stage(pose)
            jac = self.geometry.jacobian(stage_pose)
            step_stage = np.linalg.solve(jac, (q - self.inverse(pose))[..., None])[..., 0]
            a0 = self.geometry.stage2plate[2]
            step = np.column_stack([rotate_points(a0, step_stage[:, :2]), step_stage[:, 2]])
            pose = pose + step
            if np.max(np.abs(step)) < 1e-13:
                break
        return pose


class ParametricModel(StageModel):
    """The error model with identified parameters (inputs approached from below)."""

    method = 'parametric'

    def __init__(self, geometry: StageGeometry):
        self.geometry = geometry

    def inverse(self, plate_pose) -> np.ndarray:
        stage_pose = self.geometry.plate_to_stage(plate_pose)
        return self.geometry.inverse(stage_pose, UNIDIRECTIONAL)

    def forward(self, q, iterations: int = 6) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return self.geometry.stage_to_plate(self.geometry.forward(q, UNIDIRECTIONAL))



class StepwiseModel(StageModel):
    """The paper's stepwise model: identified kinematics, attitude table over q3 - q2 and
    interpolation of the remaining input error over the measured workspace."""

    method = 'stepwise'

    def __init__(self, geometry: StageGeometry, attitude_w, attitude_theta,
                 poses, corrections):
        self.geometry = geometry
        self.attitude_w = np.asarray(attitude_w, dtype=float)
        self.attitude_theta = np.asarray(attitude_theta, dtype=float)
        self.poses = np.asarray(poses, dtype=float)
        self.corrections = np.asarray(corrections, dtype=float)
        self._table = PchipInterpolator(self.attitude_theta, self.attitude_w, extrapolate=True)
        scaled = self._scaled(self.poses)
        self._linear = LinearNDInterpolator(scaled, self.corrections) if len(scaled) > 4 else None
        self._nearest = NearestNDInterpolator(scaled, self.corrections)

    def _scaled(self, plate_pose):
        plate_pose = np.atleast_2d(plate_pose)
        return np.column_stack([plate_pose[:, :2], plate_pose[:, 2] * ANGLE_SCALE])

    def _tabled(self, plate_pose) -> np.ndarray:
        """Inputs from the identified kinematics with q3 - q2 from the attitude table."""
        plate_pose = np.atleast_2d(plate_pose)
        q = self.geometry.inverse(self.geometry.plate_to_stage(plate_pose))
        mean = 0.5 * (q[:, 1] + q[:, 2])
        w = self._table(plate_pose[:, 2] - self.geometry.stage2plate[2])
        return np.column_stack([q[:, 0], mean - w / 2, mean + w / 2])

    def inverse(self, plate_pose) -> np.ndarray:
        plate_pose = np.atleast_2d(np.asarray(plate_pose, dtype=float))
        q = self._tabled(plate_pose)
        scaled = self._scaled(plate_pose)
        correction = self._linear(scaled) if self._linear is not None else np.full(q.shape, np.nan)
        outside = ~np.isfinite(correction).all(axis=1)
        correction[outside] = self._nearest(scaled[outside])
        return q + correction


def _fit_line(t: np.ndarray, points: np.ndarray):
    """Least-squares line through points ((n, 2)) against t ((n,)): slope vector (2,)."""
    design = np.column_stack([t, np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(design, points, rcond=None)
    return coef[0]


def stepwise_calibration(data: StageData):
    """The paper's stepwise self-calibration.

    Returns
    -------
    model : StepwiseModel
    report : dict
        Identified quantities in SI units (leads m/rev, angles rad, lengths m).

    Raises
    ------
    CalibrationError
        If a sweep the method needs is missing from the data (names it).
    """
    q = data.q
    tol = 1e-9
    home_rows = _rows(q, lambda q: np.all(np.abs(q) < tol, axis=1))
    x_rows = _rows(q, lambda q: (np.abs(q[:, 1]) < tol) & (np.abs(q[:, 2]) < tol)
                   & (np.abs(q[:, 0]) > tol))
    y_rows = _rows(q, lambda q: (np.abs(q[:, 0]) < tol) & (np.abs(q[:, 1] - q[:, 2]) < tol)
                   & (np.abs(q[:, 1]) > tol))
    w_rows = _rows(q, lambda q: (np.abs(q[:, 0]) < tol) & (np.abs(q[:, 1] + q[:, 2]) < tol)
                   & (np.abs(q[:, 1]) > tol))
    for name, rows in (('home pose (q = 0)', home_rows), ('X sweep (q1 alone)', x_rows),
                       ('Y sweep (q2 = q3)', y_rows), ('attitude sweep (q2 = -q3)', w_rows)):
        need = 1 if name.startswith('home') else 3
        if len(rows) < need:
            raise CalibrationError(f'the stepwise calibration needs the {name}: '
                                   f'{len(rows)} rows found, at least {need} needed')
    home = data.marks[home_rows].mean(axis=0)
    angle, shift = relative_motions(data.marks, home)

    # Rotation centre of the attitude sweep, (d2 + d3) / 2, d1 in the stage frame:
    # (I - R) c = C for every row.
    big = w_rows[np.abs(angle[w_rows]) > 1e-4]
    if len(big) < 2:
        raise CalibrationError('the attitude sweep does not rotate the platform: cannot '
                               'find its rotation centre')
    design = np.vstack([np.eye(2) - rotation(a) for a in angle[big]])
    centre, *_ = np.linalg.lstsq(design, shift[big].ravel(), rcond=None)

    # Moving-platform frame: the X direction is the path of the platform point over chain
    # 2's guide; points elsewhere also swing with the small turn an X move makes when the
    # slots of chains 2 and 3 are not parallel.
    d1, d2, d3 = NOMINAL_D
    d_mid = 0.5 * (d2 + d3)
    first = _fit_line(q[x_rows, 0], (rotate_points(angle, home.mean(axis=0)) + shift)[x_rows])
    over_chain2 = centre - 0.5 * (d3 - d2) * first / np.linalg.norm(first)
    slope_x = _fit_line(q[x_rows, 0], (rotate_points(angle, over_chain2) + shift)[x_rows])
    k1 = float(np.linalg.norm(slope_x))
    frame_angle = float(np.arctan2(slope_x[1], slope_x[0]))

    # Y sweep: direction (axis skew), rotation per input, displacement of the centre.
    moved_centre = rotate_points(angle, centre) + shift
    slope_y = _fit_line(q[y_rows, 1], moved_centre[y_rows])
    alpha1 = float(np.arctan2(slope_y[1], slope_y[0]) - frame_angle)
    k_mean = float(np.linalg.norm(slope_y) * np.sin(alpha1))
    rho_y = float(np.polyfit(q[y_rows, 1], angle[y_rows], 1)[0])
    w = q[w_rows, 2] - q[w_rows, 1]
    rho_w = float(np.polyfit(w, np.tan(angle[w_rows]), 1)[0])
    distance = k_mean / rho_w                                        # d3 - d2
    k2, k3 = k_mean - rho_y * distance / 2, k_mean + rho_y * distance / 2

    # The centre of the attitude sweep is at (d_mid, d1) in the stage frame; the stage's
    # own middle is not visible, so d1 and (d2 + d3) / 2 stay nominal.
    origin = centre - rotate_points(frame_angle, np.array([d_mid, d1]))
    home_angle = frame_angle
    geometry = StageGeometry(
        lead=(k1 * NOMINAL_LEAD, k2 * NOMINAL_LEAD, k3 * NOMINAL_LEAD),
        d=(d1, d_mid - distance / 2, d_mid + distance / 2), alpha1=alpha1,
        stage2plate=(float(origin[0]), float(origin[1]), home_angle))

    # Attitude table over q3 - q2, one entry per commanded difference, through (0, 0).
    table_w, table_theta = _unique_mean(np.append(w, 0.0)[:, None],
                                        np.append(angle[w_rows], 0.0)[:, None])
    order = np.argsort(table_theta[:, 0])
    table_w, table_theta = table_w[order, 0], table_theta[order, 0]
    if np.any(np.diff(table_theta) <= 0):
        raise CalibrationError('the attitude table is not monotonic in q3 - q2: the '
                               'attitude sweep measurements are inconsistent')

    home_pose = np.array([origin[0], origin[1], home_angle])
    poses = np.column_stack([rotate_points(angle, home_pose[:2]) + shift, home_angle + angle])
    provisional = StepwiseModel(geometry, table_w, table_theta, poses[:1], np.zeros((1, 3)))
    keys, mean_poses = _unique_mean(q, poses)
    corrections = keys - provisional._tabled(mean_poses)
    model = StepwiseModel(geometry, table_w, table_theta, mean_poses, corrections)
    report = {
        'R1': geometry.lead[0], 'R2': geometry.lead[1], 'R3': geometry.lead[2],
        'alpha1': float(alpha1), 'd3_minus_d2': float(distance),
        'rotation_centre': centre.tolist(), 'platform_origin': origin.tolist(),
        'platform_angle': home_angle, 'attitude_table_points': int(len(table_w)),
        'interpolation_points': int(len(mean_poses)),
        'units': {'R1': 'm/rev', 'R2': 'm/rev', 'R3': 'm/rev', 'alpha1': 'rad',
                  'd3_minus_d2': 'm', 'rotation_centre': 'm', 'platform_origin': 'm',
                  'platform_angle': 'rad'}}
    return model, report


# Fixed in the parametric fit, with the reason (the report repeats it):
PARAMETRIC_GAUGE = {
    'q_offset1': 'encoder zero: same effect as the platform origin along X',
    'q_offset2': 'encoder zero: same effect as the platform origin along Y',
    'q_offset3': 'encoder zero: same effect as the platform angle at home',
    'beta2': 'defines the stage frame\'s Y axis: a common turn of all guides is the stage angle',
    'd1': 'only in second-order terms: inseparable from the mark positions at this stroke',
    'd2': 'defines the stage frame\'s x origin: a common shift of the guides is stage_x',
    'link_difference': 'turns the platform at home like stage_angle and q_offset3 do',
}


def mark_names(count: int = 2) -> list[str]:
    return [f'mark{i + 1}_{axis}' for i in range(count) for axis in ('x', 'y')]


def _split(parameters: ParameterSet):
    values = parameters.as_dict()
    geometry = StageGeometry.from_parameters(values)
    marks = np.array([values[n] for n in mark_names()]).reshape(2, 2)
    return geometry, marks


def predict_marks(geometry: StageGeometry, marks_platform, q, directions) -> np.ndarray:
    """Plate positions (m, (n, 2, 2)) of the platform Marks for inputs q and directions."""
    plate = geometry.stage_to_plate(geometry.forward(q, directions))
    return platform_points_in_plate(plate, marks_platform)


def parametric_calibration(data: StageData, initial: StageGeometry,
                           fixed: dict | None = None, backlash: bool | None = None):
    """Identify the error model from the calibration measurements.

    Parameters
    ----------
    data : StageData
    initial : StageGeometry
        Start (e.g. the stepwise result); its fixed parameters keep their values.
    fixed : dict, optional
        Parameter name -> reason; default :data:`PARAMETRIC_GAUGE`.
    backlash : bool, optional
        Estimate backlash per chain; default: when every chain was approached from both
        directions (otherwise it cannot be seen, and is fixed at 0 with that reason).

    Returns
    -------
    model : ParametricModel
    report : dict
    fit_result : FitResult
    """
    fixed = dict(PARAMETRIC_GAUGE if fixed is None else fixed)
    both = [bool(np.any(data.directions[:, i] > 0) and np.any(data.directions[:, i] < 0))
            for i in range(3)]
    if backlash is None:
        backlash = all(both)
    if not backlash:
        for i in range(3):
            fixed[f'backlash{i + 1}'] = ('not estimated' if both[i] else
                                         'every move of this chain went the same way')
        initial = initial.with_changes(backlash=(0.0, 0.0, 0.0))
    home = data.marks[np.argmin(np.abs(data.q).sum(axis=1))]
    pose0 = initial.stage_to_plate(initial.forward(np.zeros((1, 3))))[0]
    marks0 = rotate_points(-pose0[2], home - pose0[:2])
    start = ParameterSet(initial.as_parameters().parameters + [
        Parameter(n, float(v), 'm') for n, v in zip(mark_names(), marks0.ravel())])
    for name in fixed:
        start.set_free(name, False)

    def residuals(parameters):
        geometry, marks = _split(parameters)
        return (predict_marks(geometry, marks, data.q, data.directions) - data.marks).ravel()

    result = fit(residuals, start)
    geometry, marks = _split(result.parameters)
    weak = _weakly_determined(result)
    residual = result.residuals.reshape(-1, 2, 2)
    report = {
        'parameters': result.parameters.as_dict(), 'units': result.parameters.units(),
        'std_devs': result.std_devs, 'fixed': fixed,
        'residual_rms_m': float(np.sqrt(np.mean(np.sum(residual ** 2, axis=2)))),
        'residual_max_m': float(np.max(np.linalg.norm(residual, axis=2))),
        'condition_number': result.condition_number, 'num_poses': len(data),
        'weakly_determined': weak}
    return ParametricModel(geometry), report, result


# A parameter whose 1-sigma exceeds this (per unit) is reported as weakly determined.
WEAK_LIMITS = {'m': 50e-6, 'rad': 0.5e-3, 'm/rev': 1e-6}


def _weakly_determined(result) -> dict:
    """Parameter -> why the data hardly determine it (its sigma and its strongest
    partner in the correlation matrix). Its effect on predicted poses is small at this
    stroke; the prediction stays good, the value itself means little."""
    names = result.parameters.free_names
    units = result.parameters.units()
    std = np.sqrt(np.clip(np.diag(result.covariance), 1e-300, None))
    correlation = result.covariance / np.outer(std, std)
    out = {}
    for i, name in enumerate(names):
        if std[i] > WEAK_LIMITS.get(units[name], np.inf):
            others = np.abs(correlation[i]).copy()
            others[i] = 0
            j = int(np.argmax(others))
            out[name] = (f'sigma {std[i]:.3g} {units[name]}; correlated {correlation[i, j]:+.3f} '
                         f'with {names[j]}: they move the Marks almost alike within the stroke')
    return out


def _fit_error(model: StageModel, data: StageData, home) -> dict:
    """How far each model puts the platform from the measured pose on the calibration
    data (m, rad): Mark centroid distance and angle, max and RMS."""
    angle, shift = relative_motions(data.marks, home)
    centroid = home.mean(axis=0)
    measured = rotate_points(angle, centroid) + shift
    home_pose = model.forward(np.zeros((1, 3)))[0]
    predicted = model.forward(data.q)
    moved = [rotate_points(p[2] - home_pose[2], centroid - home_pose[:2]) + p[:2] for p in predicted]
    distance = np.linalg.norm(np.array(moved) - measured, axis=1)
    turn = np.abs(predicted[:, 2] - home_pose[2] - angle)
    return {'position_max_m': float(distance.max()),
            'position_rms_m': float(np.sqrt(np.mean(distance ** 2))),
            'orientation_max_rad': float(turn.max()),
            'orientation_rms_rad': float(np.sqrt(np.mean(turn ** 2)))}


def calibrate_stage(data: StageData) -> tuple[dict, dict]:
    """Both calibrations from one run: ``({'stepwise': ..., 'parametric': ...}, report)``.
    The report holds each method's identified values and its fit to the data (the
    comparison on unseen poses is the alignment evaluation)."""
    stepwise, stepwise_report = stepwise_calibration(data)
    parametric, parametric_report, _ = parametric_calibration(data, stepwise.geometry)
    home = data.marks[np.all(np.abs(data.q) < 1e-9, axis=1)].mean(axis=0)
    report = {'num_poses': len(data), 'stepwise': stepwise_report,
              'parametric': parametric_report,
              'fit_to_calibration_data': {'stepwise': _fit_error(stepwise, data, home),
                                          'parametric': _fit_error(parametric, data, home)},
              'note': 'fit_to_calibration_data: each model as the aligner uses it (every '
                      'chain approached from below) against the measured poses of the run, '
                      'whose downward sweeps carry backlash; accuracy on unseen poses is '
                      'the alignment evaluation'}
    return {'stepwise': stepwise, 'parametric': parametric}, report


def models_as_dict(models: dict) -> dict:
    """The calibrated models in plain YAML/JSON types (SI units), for files and messages."""
    out = {}
    for name, model in models.items():
        entry = {'method': model.method, 'geometry': model.geometry.as_dict()}
        if isinstance(model, StepwiseModel):
            entry.update(attitude_w=model.attitude_w.tolist(),
                         attitude_theta=model.attitude_theta.tolist(),
                         poses=model.poses.tolist(), corrections=model.corrections.tolist())
        out[name] = entry
    return out


def models_from_dict(content: dict) -> dict:
    """Inverse of :func:`models_as_dict`.

    Raises
    ------
    InvalidInputError
        A model entry is incomplete (names what is missing)."""
    models = {}
    for name, entry in content.items():
        try:
            geometry = StageGeometry.from_parameters(entry['geometry'])
            if entry['method'] == 'stepwise':
                models[name] = StepwiseModel(geometry, entry['attitude_w'],
                                             entry['attitude_theta'], entry['poses'],
                                             entry['corrections'])
            else:
                models[name] = ParametricModel(geometry)
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(f'stage model {name!r} is incomplete or malformed: '
                                    f'{exc!r}') from None
    return models
