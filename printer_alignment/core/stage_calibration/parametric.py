"""The parametric calibration: least squares on the whole error model of
:class:`~printer_alignment.core.stage.StageGeometry`, backlash included, started from
the stepwise result; the gauge fixed with reasons, weakly determined parameters named."""
from __future__ import annotations

import numpy as np

from calib_core.least_squares import fit
from calib_core.parameters import Parameter, ParameterSet
from printer_alignment.core.geometry import rotate_points
from printer_alignment.core.stage import StageGeometry, platform_points_in_plate
from printer_alignment.core.stage_calibration.data import StageData
from printer_alignment.core.stage_calibration.models import ParametricModel


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
