"""Both calibrations from one run, with each model's fit to the calibration data."""
from __future__ import annotations

import numpy as np

from calib_core.sanity import SanityGate
from printer_alignment.core.geometry import rotate_points
from printer_alignment.core.stage import NOMINAL_D, NOMINAL_LEAD
from printer_alignment.core.stage_calibration.data import StageData, relative_motions
from printer_alignment.core.stage_calibration.models import StageModel
from printer_alignment.core.stage_calibration.parametric import parametric_calibration
from printer_alignment.core.stage_calibration.stepwise import stepwise_calibration

# The sanity gate's bounds: a camera measures the Marks to a few um; ball screws are within
# a fraction of a percent of their lead; the X-Y skew of a built stage is a fraction of a
# degree.
MAX_MARK_RESIDUAL_RMS_M = 50e-6
MAX_LEAD_CHANGE = 0.10
MAX_SKEW_RAD = 0.1


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


def calibrate_stage(data: StageData, nominal_d=NOMINAL_D) -> tuple[dict, dict]:
    """Both calibrations from one run: ``({'stepwise': ..., 'parametric': ...}, report)``;
    ``nominal_d`` (m) the guides' nominal places (:func:`stepwise_calibration`).
    The report holds each method's identified values and its fit to the data (the
    comparison on unseen poses is the alignment evaluation)."""
    stepwise, stepwise_report = stepwise_calibration(data, nominal_d)
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


def check_stage_calibration(report: dict, description=None, causes: str | None = None) -> None:
    """Refuse a stage calibration (``calibrate_stage``'s report) that cannot be the stage:
    Mark residual RMS over :data:`MAX_MARK_RESIDUAL_RMS_M` (with a ``description``,
    :class:`printer_alignment.core.stage_description.StageDescription`, over its limit from
    the declared noise; ``causes`` the likely causes, most likely first, said with either
    failure), a lead more than :data:`MAX_LEAD_CHANGE` from the nominal 2 mm/rev, chain 1 more than
    :data:`MAX_SKEW_RAD` from square, or a free parameter without a finite std dev.

    Raises
    ------
    CalibrationError
        Every failure named; nothing may be written or put in force."""
    gate = SanityGate('the stage calibration')
    stepwise, parametric = report['stepwise'], report['parametric']
    limit, expected = ((MAX_MARK_RESIDUAL_RMS_M, 'the camera measures the Marks to a few um')
                       if description is None else
                       (description.residual_limit(), description.expected_text()))
    gate.residual(parametric['residual_rms_m'] * 1e6, limit * 1e6, 'um', expected,
                  *(() if causes is None else (causes,)))
    low, high = NOMINAL_LEAD * (1 - MAX_LEAD_CHANGE), NOMINAL_LEAD * (1 + MAX_LEAD_CHANGE)
    leads_off = not all(low <= stepwise[n] <= high for n in ('R1', 'R2', 'R3'))
    for name in ('R1', 'R2', 'R3'):
        gate.within(f'stepwise {name}', stepwise[name], low, high, 'm/rev',
                    f'within {MAX_LEAD_CHANGE:.0%} of the nominal lead'
                    + (f'; likely causes: {causes}' if causes and leads_off and name == 'R1'
                       else ''))
    gate.within('stepwise alpha1', stepwise['alpha1'], np.pi / 2 - MAX_SKEW_RAD,
                np.pi / 2 + MAX_SKEW_RAD, 'rad', f'within {MAX_SKEW_RAD:g} rad of square')
    gate.finite_std_devs({name: sigma for name, sigma in parametric['std_devs'].items()
                          if name not in parametric['fixed']})
    gate.enforce()
