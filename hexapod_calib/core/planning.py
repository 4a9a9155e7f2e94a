"""What a hexapod calibration plan will give, predicted before anything moves, with the
shared planner's tools (``calib_core.planning``).

The identification's rows are the leg lengths the geometry predicts at the measured poses
against the commanded ones (m). Their noise is the pose sensor's (position and angle per
axis) carried through the leg-length Jacobian, so the six rows of one pose are
correlated. The prediction uses the covariance of the fit the suite runs (ordinary least
squares: the sandwich). At a working pose the legs come from the identified geometry's
inverse kinematics and the platform sits where the true legs put it: to first order the
pose error is ``J^-1 dL/de (e_hat - e)`` with J the leg-length Jacobian.
"""
from __future__ import annotations

import numpy as np

from calib_core.planning import (
    augment, design_bound, exchange, information, predicted_errors, sandwich_covariance, whiten)
from hexapod_calib.core.calibration import PoseData, identification_jacobian
from hexapod_calib.core.geometry import HexapodGeometry
from hexapod_calib.core.kinematics import inverse_kinematics, jacobian

# The simulated pose sensor's and actuators' 1-sigma (hexapod_calib.sim.hexapod).
POSITION_NOISE = 0.6e-6     # m per axis
ANGLE_NOISE = 6e-6          # rad per axis
ACTUATOR_NOISE = 0.5e-6     # m per leg: where a leg stops against where it was sent
# The I criterion weighs a rotation error as the displacement it makes this far from the
# platform's centre (m), so that one number scores both.
LEVER = 0.1


def _rows(geometry: HexapodGeometry, poses) -> np.ndarray:
    """d(modelled leg length)/d(parameter) at ``poses``, (n, 6, 42)."""
    poses = np.atleast_2d(poses)
    data = PoseData(poses, poses, inverse_kinematics(geometry, poses))
    return -identification_jacobian(geometry, data).reshape(len(poses), 6, -1)


def _leg_noise(geometry: HexapodGeometry, poses, position_noise: float, angle_noise: float,
               actuator_noise: float) -> np.ndarray:
    """Covariance (n, 6, 6) of the six leg-length rows of each pose: the pose sensor's noise
    through the leg-length Jacobian and the actuators' repeatability."""
    legs_by_pose = jacobian(geometry, poses)                                   # (n, 6, 6)
    pose_noise = np.diag([position_noise ** 2] * 3 + [angle_noise ** 2] * 3)
    return legs_by_pose @ pose_noise @ np.swapaxes(legs_by_pose, 1, 2) \
        + actuator_noise ** 2 * np.eye(6)


def _whitened(geometry: HexapodGeometry, poses, position_noise: float, angle_noise: float,
              actuator_noise: float) -> np.ndarray:
    """Each pose's six rows whitened by their correlated noise (:func:`_leg_noise`)."""
    return whiten(_rows(geometry, poses),
                  _leg_noise(geometry, poses, position_noise, angle_noise, actuator_noise))


def _working_sensitivity(geometry: HexapodGeometry, working) -> np.ndarray:
    """The pose error at the ``working`` poses by parameter, a rotation weighed at
    :data:`LEVER` (W, 6, 42)."""
    sensitivity = np.linalg.solve(jacobian(geometry, working), _rows(geometry, working))
    return sensitivity * np.array([1.0] * 3 + [LEVER] * 3)[None, :, None]


def exchange_poses(geometry: HexapodGeometry, candidates, count: int, criterion: str,
                   working, position_noise: float = POSITION_NOISE,
                   angle_noise: float = ANGLE_NOISE,
                   actuator_noise: float = ACTUATOR_NOISE) -> np.ndarray:
    """Indices of ``count`` of the ``candidates`` (M, 6) chosen by the shared exchange on
    their whitened rows; for ``criterion`` 'I' the least mean squared pose error at the
    ``working`` poses (W, 6), a rotation weighed at :data:`LEVER`; 'D' the largest
    information determinant."""
    whitened = _whitened(geometry, candidates, position_noise, angle_noise, actuator_noise)
    sensitivity = _working_sensitivity(geometry, working) if criterion == 'I' else None
    return exchange(whitened, count, criterion, sensitivity).chosen


def criterion_rms(geometry: HexapodGeometry, poses, working,
                  position_noise: float = POSITION_NOISE, angle_noise: float = ANGLE_NOISE,
                  actuator_noise: float = ACTUATOR_NOISE) -> float:
    """The I criterion of identifying from ``poses`` (n, 6) as RMS (m): the pose error at
    the ``working`` poses (W, 6), a rotation weighed at :data:`LEVER`, of the fit weighted
    by the noise (the actuators' repeatability at the working poses not counted)."""
    rows = _whitened(geometry, poses, position_noise, angle_noise, actuator_noise)
    sensitivity = _working_sensitivity(geometry, working)
    weight = np.einsum('wqp,wqs->ps', sensitivity, sensitivity) / len(sensitivity)
    return float(np.sqrt(np.trace(weight @ np.linalg.pinv(
        information(rows, np.arange(len(rows)))))))


def planning_floor(geometry: HexapodGeometry, candidates, working, counts,
                   position_noise: float = POSITION_NOISE, angle_noise: float = ANGLE_NOISE,
                   actuator_noise: float = ACTUATOR_NOISE) -> dict:
    """What no plan of N of the ``candidates`` (M, 6) can undercut by :func:`criterion_rms`,
    for each N of ``counts``: the optimal approximate design's certified bound
    (:func:`calib_core.planning.design_bound`), as RMS (m) by N."""
    found = design_bound(_whitened(geometry, candidates, position_noise, angle_noise,
                                   actuator_noise), _working_sensitivity(geometry, working))
    return {'rms_m': {int(n): float(np.sqrt(found['lower_bound'] / n)) for n in counts},
            'support': found['support'], 'per_measurement': found['per_measurement'],
            'lower_bound_per_measurement': found['lower_bound']}


def extend_poses(geometry: HexapodGeometry, measured, candidates, count: int, working,
                 criterion: str = 'I', position_noise: float = POSITION_NOISE,
                 angle_noise: float = ANGLE_NOISE,
                 actuator_noise: float = ACTUATOR_NOISE) -> tuple[np.ndarray, dict]:
    """The ``count`` of the ``candidates`` (M, 6) that, added one by one to the poses
    ``measured`` (n, 6; repeats counted), most lower the criterion about ``geometry`` (the
    one identified so far; greedy: the first k are the best k), and :func:`predict` for
    all of them at the ``working`` poses."""
    noise = (position_noise, angle_noise, actuator_noise)
    prior_rows = _whitened(geometry, measured, *noise)
    chosen = augment(_whitened(geometry, candidates, *noise),
                     information(prior_rows, np.arange(len(prior_rows))),
                     min(count, len(candidates)), criterion,
                     _working_sensitivity(geometry, working) if criterion == 'I' else None)
    added = np.asarray(candidates)[chosen]
    return added, predict(geometry, np.vstack([measured, added]), working, *noise)


def predict(geometry: HexapodGeometry, poses, working, position_noise: float = POSITION_NOISE,
            angle_noise: float = ANGLE_NOISE, actuator_noise: float = ACTUATOR_NOISE) -> dict:
    """Predicted 1-sigma result of identifying from ``poses`` (n, 6) measured by a pose
    sensor of the given noise, with legs that stop within ``actuator_noise`` of where they
    are sent: each parameter's sigma (m) and, at the ``working`` poses (W, 6), the
    platform's displacement (m) and rotation (rad) error, RMS and max (the calibration's
    share and the actuators' repeatability together)."""
    rows = _rows(geometry, poses)
    noise = _leg_noise(geometry, poses, position_noise, angle_noise, actuator_noise)
    covariance = sandwich_covariance(rows, noise)
    at_work = jacobian(geometry, working)
    sensitivity = np.linalg.solve(at_work, _rows(geometry, working))
    # The actuators' repeatability moves the platform at a working pose too.
    repeat = np.linalg.inv(at_work)
    per_axis = np.sqrt(predicted_errors(covariance, sensitivity) ** 2
                       + actuator_noise ** 2 * np.sum(repeat ** 2, axis=2))   # (W, 6)
    displacement = np.sqrt(np.sum(per_axis[:, :3] ** 2, 1))
    rotation = np.sqrt(np.sum(per_axis[:, 3:] ** 2, 1))
    names = geometry.parameters().names
    return {'poses': len(rows), 'working_poses': len(sensitivity),
            'position_noise_m': position_noise, 'angle_noise_rad': angle_noise,
            'actuator_noise_m': actuator_noise,
            'predicted_parameter_sigmas_m': dict(zip(names, map(float, np.sqrt(np.diag(
                covariance))))),
            'predicted_displacement_m': {'rms': float(np.sqrt(np.mean(displacement ** 2))),
                                         'max': float(displacement.max())},
            'predicted_rotation_rad': {'rms': float(np.sqrt(np.mean(rotation ** 2))),
                                       'max': float(rotation.max())},
            'note': '1-sigma, first order, from the pose sensor noise and the actuators\' '
                    'repeatability (effects the 42 parameters lack come on top)'}
