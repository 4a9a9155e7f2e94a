"""Alignment of a substrate to a stencil with the XY-Theta stage.

Substrate Marks M0 (on the platform) and stencil Marks M1 (fixed) are measured in the plate
frame; the rigid motion ``M1 = R(theta) M0 + C`` that carries one onto the other is found by
least squares over at least two Mark pairs, applied to the platform's current pose, and
turned into chain inputs by a calibrated stage model.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import InvalidInputError, OutOfTravelError
from printer_alignment.core.stage import STROKE


def rigid_fit(source, target):
    """Least-squares rotation and translation with ``target = R(angle) source + C``.

    Parameters
    ----------
    source, target : array_like (k, 2)
        Corresponding points, m; k >= 2 and not all coincident.

    Returns
    -------
    angle : float (rad)
    translation : ndarray (2,) (m)
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 2:
        raise InvalidInputError(f'Mark pairs must be two (k, 2) arrays, got {source.shape} '
                                f'and {target.shape}')
    if len(source) < 2:
        raise InvalidInputError(f'{len(source)} Mark pair(s): at least 2 are needed to '
                                'determine the rotation')
    if not (np.all(np.isfinite(source)) and np.all(np.isfinite(target))):
        raise InvalidInputError('Mark positions contain NaN or infinite values')
    a = source - source.mean(axis=0)
    b = target - target.mean(axis=0)
    if np.min([np.abs(a).max(), np.abs(b).max()]) < 1e-9:
        raise InvalidInputError('the Marks coincide: their rotation is undetermined')
    angle = float(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]),
                             np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
    c, s = np.cos(angle), np.sin(angle)
    translation = target.mean(axis=0) - source.mean(axis=0) @ np.array([[c, s], [-s, c]])
    return angle, translation


@dataclass(frozen=True)
class AlignmentPlan:
    """The motion and the inputs to perform it.

    Attributes
    ----------
    angle, translation : float (rad), ndarray (2,) (m)
        Plate-frame motion the substrate needs.
    fit_rms : float
        RMS distance of the Mark pairs after the motion, m: the substrate's and stencil's
        Mark layouts disagree by this much (scale, print distortion), not the stage.
    current_pose, target_pose : ndarray (3,)
        Platform poses in the plate frame (m, m, rad) by the model.
    q : ndarray (3,)
        Chain inputs for the target, m.
    """

    angle: float
    translation: np.ndarray
    fit_rms: float
    current_pose: np.ndarray
    target_pose: np.ndarray
    q: np.ndarray


def plan_alignment(model, q_now, substrate, stencil, stroke: float = STROKE) -> AlignmentPlan:
    """Inputs that carry the measured substrate Marks onto the stencil Marks.

    Raises
    ------
    OutOfTravelError
        The target pose is outside the workspace (an input beyond the stroke); the stage
        must not be moved.
    """
    substrate = np.asarray(substrate, dtype=float)
    stencil = np.asarray(stencil, dtype=float)
    angle, translation = rigid_fit(substrate, stencil)
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.array([[c, -s], [s, c]])
    fit_rms = float(np.sqrt(np.mean(np.sum((substrate @ rotation.T + translation - stencil) ** 2,
                                           axis=1))))
    current = model.forward(np.asarray(q_now, dtype=float).reshape(1, 3))[0]
    target = np.concatenate([rotation @ current[:2] + translation, [current[2] + angle]])
    q = model.inverse(target[None])[0]
    if np.any(np.abs(q) > stroke):
        chain = int(np.argmax(np.abs(q) > stroke))
        raise OutOfTravelError(
            f'the target pose (shift {translation[0] * 1e6:.1f}, {translation[1] * 1e6:.1f} '
            f'um about the plate origin, rotation {np.rad2deg(angle) * 3600:.1f} arcsec) is '
            f'outside the workspace: chain {chain + 1} would need {q[chain] * 1e3:.4f} mm '
            f'(stroke +-{stroke * 1e3:.1f} mm); not moved')
    return AlignmentPlan(angle, translation, fit_rms, current, target, q)


REPORT_KEYS = ('model', 'q_before_m', 'substrate_before_m', 'stencil_m', 'q_planned_m')


def replay_alignment(report: dict, model) -> dict:
    """Plan a recorded alignment again from its recorded Mark measurements.

    Parameters
    ----------
    report : dict
        An aligner report: ``q_before_m`` (3,), ``substrate_before_m`` and ``stencil_m``
        (k, 2) and ``q_planned_m`` (3,), all m.
    model
        The stage model the alignment used (``forward``/``inverse`` in m, rad).

    Returns
    -------
    dict
        ``q_recorded_m`` and ``q_replayed_m`` (3,), ``max_difference_m``, and the
        camera-verified ``verification`` of the recorded run (m, rad).
    """
    missing = [k for k in REPORT_KEYS if k not in report]
    if missing:
        raise InvalidInputError(f'the alignment report lacks {", ".join(missing)} '
                                '(recorded by an older aligner?)')
    # The stroke the aligner planned within (a described stage's; older reports: the
    # shipped stage's).
    plan = plan_alignment(model, report['q_before_m'], report['substrate_before_m'],
                          report['stencil_m'], float(report.get('stroke_m', STROKE)))
    recorded = np.asarray(report['q_planned_m'], dtype=float)
    return {'model': report['model'], 'q_recorded_m': recorded.tolist(),
            'q_replayed_m': plan.q.tolist(),
            'max_difference_m': float(np.abs(plan.q - recorded).max()),
            'verification': report.get('verification')}
