"""Both calibrations from one run, with each model's fit to the calibration data."""
from __future__ import annotations

import numpy as np

from printer_alignment.core.geometry import rotate_points
from printer_alignment.core.stage_calibration.data import StageData, relative_motions
from printer_alignment.core.stage_calibration.models import StageModel
from printer_alignment.core.stage_calibration.parametric import parametric_calibration
from printer_alignment.core.stage_calibration.stepwise import stepwise_calibration


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
