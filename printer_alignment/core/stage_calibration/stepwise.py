"""The paper's stepwise calibration: moving-platform frame, transmission ratios R1..R3,
d3 - d2, axis skew alpha1, an attitude table over q3 - q2 and the measured workspace
poses for interpolation of the remaining input error."""
from __future__ import annotations

import numpy as np

from calib_core.errors import CalibrationError
from printer_alignment.core.geometry import rotate_points, rotation
from printer_alignment.core.stage import NOMINAL_D, NOMINAL_LEAD, StageGeometry
from printer_alignment.core.stage_calibration.data import StageData, relative_motions
from printer_alignment.core.stage_calibration.models import StepwiseModel


def _rows(q: np.ndarray, condition) -> np.ndarray:
    return np.flatnonzero(condition(q))


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


def _fit_line(t: np.ndarray, points: np.ndarray):
    """Least-squares line through points ((n, 2)) against t ((n,)): slope vector (2,)."""
    design = np.column_stack([t, np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(design, points, rcond=None)
    return coef[0]


def _sweeps(q: np.ndarray) -> tuple:
    """The rows of the home pose and of the X, Y and attitude sweeps in the inputs ``q``
    (n, 3) m; a sweep the method needs missing is named."""
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
    return home_rows, x_rows, y_rows, w_rows


def _attitude_table(w: np.ndarray, angle: np.ndarray) -> tuple:
    """The attitude table over q3 - q2 (``w``, m; ``angle``, rad, of the attitude sweep):
    one entry per commanded difference, through (0, 0), sorted; refused if not monotonic."""
    table_w, table_theta = _unique_mean(np.append(w, 0.0)[:, None],
                                        np.append(angle, 0.0)[:, None])
    order = np.argsort(table_theta[:, 0])
    table_w, table_theta = table_w[order, 0], table_theta[order, 0]
    if np.any(np.diff(table_theta) <= 0):
        raise CalibrationError('the attitude table is not monotonic in q3 - q2: the '
                               'attitude sweep measurements are inconsistent')
    return table_w, table_theta


def stepwise_calibration(data: StageData, nominal_d=NOMINAL_D):
    """The paper's stepwise self-calibration; d1 and the middle of d2 and d3, which the
    sweeps do not show, are taken from ``nominal_d`` (m, the stage's nominal guides, a
    machine description's).

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
    home_rows, x_rows, y_rows, w_rows = _sweeps(q)
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
    d1, d2, d3 = nominal_d
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

    table_w, table_theta = _attitude_table(w, angle[w_rows])

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
