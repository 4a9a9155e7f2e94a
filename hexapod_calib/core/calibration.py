"""Hexapod identification: the 42-parameter error model fitted to measured platform poses.

Model: commanded actuator length l_i = |p + R a_i - b_i| - o_i for every leg i, with the
pose (p, R) measured by an external instrument (CMM, laser tracker) in the base frame. Each
leg contributes one equation per pose in its own seven parameters (offset o_i, base joint
b_i, platform joint a_i), so with full-pose measurements all 42 are identifiable from
poses that both translate and rotate the platform.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.checks import MAX_POSITION_M
from calib_core.datasets import read_columns, write_columns
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.least_squares import FitResult, check_identifiability, fit
from calib_core.parameters import ParameterSet
from calib_core.sanity import SanityGate
from calib_core.schema import Column, Schema
from hexapod_calib.core.geometry import (
    LEGS, POSE_NAMES, HexapodGeometry, as_poses, rotation_matrices)
from hexapod_calib.core.kinematics import inverse_kinematics, leg_vectors

MEASURED_NAMES = tuple(f'meas_{n}' for n in POSE_NAMES)
LEG_NAMES = tuple(f'l{i + 1}' for i in range(LEGS))
PARAMETERS_PER_LEG = 7
# The pose CSV (DESIGN.md section 6), declared: positions and leg lengths of any hexapod.
POSE_SCHEMA = Schema((
    *(Column(n, 'm', -MAX_POSITION_M, MAX_POSITION_M, f'{kind} {n[-1]}')
      for kind, names in (('commanded', POSE_NAMES[:3]), ('measured', MEASURED_NAMES[:3]))
      for n in names),
    *(Column(n, 'm', 0.0, MAX_POSITION_M, f'leg {n[1]} length') for n in LEG_NAMES)))
# The sanity gate's bounds: a pose sensor (CMM, laser tracker) closes the legs to a few um,
# and no built hexapod has a joint centre or an actuator zero 10 mm from its drawing.
MAX_LEG_RESIDUAL_RMS_M = 100e-6
MAX_PARAMETER_CHANGE_M = 10e-3


@dataclass(frozen=True)
class PoseData:
    """Calibration measurements.

    Attributes
    ----------
    commanded : ndarray, shape (n, 6)
        Poses aimed at (m, rad).
    measured : ndarray, shape (n, 6)
        Poses the instrument measured (m, rad).
    leg_lengths : ndarray, shape (n, 6)
        Actuator lengths the controller commanded, m.
    covariates : dict of str to ndarray (n,)
        Extra columns (time, temperature, ...) kept for the closed loop.
    """

    commanded: np.ndarray
    measured: np.ndarray
    leg_lengths: np.ndarray
    covariates: dict = field(default_factory=dict)

    def __post_init__(self):
        commanded = as_poses(self.commanded, 'commanded poses')
        measured = as_poses(self.measured, 'measured poses')
        legs = np.atleast_2d(np.asarray(self.leg_lengths, dtype=float))
        if measured.shape != commanded.shape or legs.shape != commanded.shape:
            raise InvalidInputError('commanded poses, measured poses and leg lengths must all '
                                    f'have shape (n, 6); got {commanded.shape}, '
                                    f'{measured.shape}, {legs.shape}')
        if not np.all(np.isfinite(legs)):
            raise InvalidInputError('leg lengths contain NaN or infinite values')
        object.__setattr__(self, 'commanded', commanded)
        object.__setattr__(self, 'measured', measured)
        object.__setattr__(self, 'leg_lengths', legs)

    def __len__(self) -> int:
        return len(self.commanded)

    def subset(self, index) -> 'PoseData':
        return PoseData(self.commanded[index], self.measured[index], self.leg_lengths[index],
                        {k: v[index] for k, v in self.covariates.items()})

    @staticmethod
    def concatenate(parts: list['PoseData']) -> 'PoseData':
        keys = set.intersection(*(set(p.covariates) for p in parts)) if parts else set()
        return PoseData(np.vstack([p.commanded for p in parts]),
                        np.vstack([p.measured for p in parts]),
                        np.vstack([p.leg_lengths for p in parts]),
                        {k: np.concatenate([p.covariates[k] for p in parts]) for k in keys})

    @classmethod
    def from_csv(cls, path, nominal: HexapodGeometry, dropped: dict | None = None,
                 leg_m_per_unit: float = 1.0) -> 'PoseData':
        """Read the pose CSV of DESIGN.md section 6. Without ``l1..l6`` columns the
        commanded leg lengths are those of the nominal geometry at the commanded pose (what
        an uncalibrated controller sends); with them, readings in the actuators' unit
        times ``leg_m_per_unit`` (a machine description's: a lead for revolutions)."""
        columns = read_columns(path, list(POSE_NAMES) + list(MEASURED_NAMES), dropped)
        commanded = np.column_stack([columns[n] for n in POSE_NAMES])
        measured = np.column_stack([columns[n] for n in MEASURED_NAMES])
        POSE_SCHEMA.check({**{n: commanded[:, k] for k, n in enumerate(POSE_NAMES[:3])},
                           **{n: measured[:, k] for k, n in enumerate(MEASURED_NAMES[:3])}},
                          path)
        present = [n for n in LEG_NAMES if n in columns]
        if present and len(present) != LEGS:
            raise InvalidInputError(f'{path} has leg length columns {", ".join(present)} but '
                                    'needs all of l1..l6 (or none)')
        legs = (np.column_stack([columns[n] for n in LEG_NAMES]) * leg_m_per_unit if present
                else inverse_kinematics(nominal, commanded))
        POSE_SCHEMA.check({n: legs[:, k] for k, n in enumerate(LEG_NAMES)}, path)
        used = set(POSE_NAMES) | set(MEASURED_NAMES) | set(LEG_NAMES)
        return cls(commanded, measured, legs, {k: v for k, v in columns.items() if k not in used})

    def to_csv(self, path) -> None:
        names = list(POSE_NAMES) + list(MEASURED_NAMES) + list(LEG_NAMES) + list(self.covariates)
        write_columns(path, names, [self.commanded, self.measured, self.leg_lengths]
                      + [self.covariates[k] for k in self.covariates])


def identification_residuals(geometry: HexapodGeometry, data: PoseData) -> np.ndarray:
    """Commanded minus modelled actuator length at the measured poses, m, shape (n, 6)."""
    return data.leg_lengths - inverse_kinematics(geometry, data.measured)


def identification_jacobian(geometry: HexapodGeometry, data: PoseData) -> np.ndarray:
    """Derivative of :func:`identification_residuals` (flattened, (6n,)) with respect to
    the 42 parameters in the order of :meth:`HexapodGeometry.parameters`, shape (6n, 42)."""
    vectors = leg_vectors(geometry, data.measured)
    units = vectors / np.linalg.norm(vectors, axis=2, keepdims=True)
    rotations = rotation_matrices(data.measured[:, 3:])
    n = len(data)
    jac = np.zeros((n, LEGS, LEGS * PARAMETERS_PER_LEG))
    for i in range(LEGS):
        k = i * PARAMETERS_PER_LEG
        jac[:, i, k] = 1.0                                   # offset
        jac[:, i, k + 1:k + 4] = units[:, i]                 # base joint
        jac[:, i, k + 4:k + 7] = -np.einsum('nji,nj->ni', rotations, units[:, i])  # platform
    return jac.reshape(n * LEGS, LEGS * PARAMETERS_PER_LEG)


@dataclass(frozen=True)
class Identification:
    """An identified geometry with its statistics (SI units)."""

    geometry: HexapodGeometry
    initial: HexapodGeometry
    fit: FitResult
    num_poses: int

    def report(self) -> dict:
        params = self.geometry.parameters()
        initial = self.initial.parameters().as_dict()
        residuals = self.fit.residuals
        return {
            'model': '6-SPS, 42 parameters: per leg the actuator offset and the base and '
                     'platform joint centres',
            'num_poses': self.num_poses,
            'parameters': params.as_dict(),
            'std_devs': dict(self.fit.std_devs),
            'change_from_initial': {k: v - initial[k] for k, v in params.as_dict().items()},
            'units': params.units(),
            'residual_rms_m': float(np.sqrt(np.mean(residuals ** 2))),
            'residual_max_m': float(np.max(np.abs(residuals))),
            'condition_number': self.fit.condition_number,
        }


def _free_columns(parameters: ParameterSet) -> np.ndarray:
    free = set(parameters.free_names)
    return np.array([n in free for n in parameters.names])


def identify(data: PoseData, initial: HexapodGeometry, fixed=(),
             max_condition: float = 1e6) -> Identification:
    """Fit the 42-parameter model (minus ``fixed`` names) to measured poses.

    Raises
    ------
    CalibrationError
        Fewer equations than free parameters, or poses that cannot separate some
        parameters (named in the message).
    """
    parameters = initial.parameters()
    for name in fixed:
        if name not in parameters:
            raise InvalidInputError(f'unknown parameter {name!r}')
        parameters.set_free(name, False)
    free_count = len(parameters.free_names)
    if len(data) * LEGS < free_count:
        raise CalibrationError(f'{len(data)} poses give {len(data) * LEGS} equations for '
                               f'{free_count} parameters; measure at least '
                               f'{int(np.ceil(free_count / LEGS))} poses (better 2-3 times '
                               'as many)')
    columns = _free_columns(parameters)
    result = fit(lambda p: identification_residuals(HexapodGeometry.from_parameters(p), data).ravel(),
                 parameters, max_condition=max_condition,
                 jacobian_fn=lambda p: identification_jacobian(
                     HexapodGeometry.from_parameters(p), data)[:, columns])
    return Identification(HexapodGeometry.from_parameters(result.parameters), initial, result,
                          len(data))


def identifiability(geometry: HexapodGeometry, poses, max_condition: float = 1e6) -> float:
    """Condition number of the identification at ``poses`` (shape (n, 6)) before measuring.

    Raises
    ------
    CalibrationError
        Naming the parameters these poses cannot separate.
    """
    poses = as_poses(poses)
    data = PoseData(poses, poses, inverse_kinematics(geometry, poses))
    if len(data) * LEGS < LEGS * PARAMETERS_PER_LEG:
        raise CalibrationError(f'{len(data)} poses cannot determine 42 parameters')
    return check_identifiability(identification_jacobian(geometry, data),
                                 geometry.parameters().names, max_condition)


def select_poses(geometry: HexapodGeometry, candidates, count: int) -> np.ndarray:
    """Pick ``count`` of the candidate poses (n, 6) that make the identification best
    conditioned: greedy D-optimal design (each step adds the pose that most increases
    det(J^T J) of the 42 parameters). Returns indices into ``candidates``."""
    candidates = as_poses(candidates, 'candidate poses')
    if count < PARAMETERS_PER_LEG:
        raise CalibrationError(f'{count} poses cannot determine the 7 parameters of a leg; '
                               'ask for at least 7 (better 13 or more)')
    if count > len(candidates):
        raise InvalidInputError(f'cannot select {count} of {len(candidates)} candidate poses')
    data = PoseData(candidates, candidates, inverse_kinematics(geometry, candidates))
    blocks = identification_jacobian(geometry, data).reshape(len(candidates), LEGS, -1)
    # Per leg the information matrix is a 7 x 7 block; det(J^T J) is their product.
    information = np.repeat(np.eye(PARAMETERS_PER_LEG)[None] * 1e-12, LEGS, axis=0)
    chosen: list[int] = []
    available = np.ones(len(candidates), bool)
    for _ in range(count):
        gain = np.zeros(len(candidates))
        for i in range(LEGS):
            k = i * PARAMETERS_PER_LEG
            rows = blocks[:, i, k:k + PARAMETERS_PER_LEG]          # (n, 7)
            inverse = np.linalg.inv(information[i])
            # det(M + r r^T) = det(M) (1 + r^T M^-1 r)
            gain += np.log1p(np.einsum('ni,ij,nj->n', rows, inverse, rows))
        gain[~available] = -np.inf
        best = int(np.argmax(gain))
        chosen.append(best)
        available[best] = False
        for i in range(LEGS):
            k = i * PARAMETERS_PER_LEG
            row = blocks[best, i, k:k + PARAMETERS_PER_LEG]
            information[i] += np.outer(row, row)
    return np.array(chosen)


def compensate(geometry: HexapodGeometry, target_poses) -> np.ndarray:
    """Actuator lengths (m, (n, 6)) that put the platform at ``target_poses`` (n, 6)
    according to a calibrated ``geometry``: what the controller should command instead of
    its nominal inverse kinematics."""
    return inverse_kinematics(geometry, target_poses)


def pose_errors(target, actual) -> tuple[np.ndarray, np.ndarray]:
    """Displacement (m) and rotation angle (rad) between target and actual poses, (n,) each."""
    target, actual = as_poses(target, 'target poses'), as_poses(actual, 'actual poses')
    displacement = np.linalg.norm(actual[:, :3] - target[:, :3], axis=1)
    relative = np.einsum('nji,njk->nik', rotation_matrices(target[:, 3:]),
                         rotation_matrices(actual[:, 3:]))
    cos = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return displacement, np.arccos(cos)


def summarise_pose_errors(target, actual) -> dict:
    """Max and RMS displacement (m) and angle (rad) errors, as the paper reports them."""
    displacement, angle = pose_errors(target, actual)
    return {'num_poses': int(len(displacement)),
            'max_displacement_m': float(displacement.max()),
            'rms_displacement_m': float(np.sqrt(np.mean(displacement ** 2))),
            'max_angle_rad': float(angle.max()),
            'rms_angle_rad': float(np.sqrt(np.mean(angle ** 2)))}


DETERMINED_SIGMAS = 3.0


def undetermined_beyond(report: dict, nominal: HexapodGeometry, bound: float) -> dict:
    """Parameters further than ``bound`` (m) from the nominal but within
    :data:`DETERMINED_SIGMAS` of their standard deviation of it: name -> (change, sigma),
    m. The poses do not determine them (a joint moving along its leg trades against the
    leg's offset); they are no evidence of another machine, and are reported."""
    out = {}
    for name, value in nominal.parameters().as_dict().items():
        change = report['parameters'][name] - value
        sigma = report['std_devs'].get(name, np.inf)
        if abs(change) > bound and abs(change) <= DETERMINED_SIGMAS * sigma:
            out[name] = (float(change), float(sigma))
    return out


def check_identification(report: dict, nominal: HexapodGeometry, description=None,
                         causes: str | None = None) -> None:
    """Refuse an identification (``Identification.report()``) that cannot be the hexapod:
    leg-length residual RMS over :data:`MAX_LEG_RESIDUAL_RMS_M`, a joint centre or leg
    offset more than :data:`MAX_PARAMETER_CHANGE_M` from ``nominal``, or a standard
    deviation that is not finite. With a ``description``
    (:class:`hexapod_calib.core.description.HexapodDescription`) the limits are its own:
    the residual against its declared noise, the bound a share of its size, and a
    parameter beyond it is refused only where the data determine it there (more than
    :data:`DETERMINED_SIGMAS` sigma from the nominal; the others are listed by
    :func:`undetermined_beyond`); ``causes`` names the likely causes of a residual refused
    (most likely first).

    Raises
    ------
    CalibrationError
        Every failure named; nothing may be written or put in force."""
    gate = SanityGate('the hexapod identification')
    limit, bound = MAX_LEG_RESIDUAL_RMS_M, MAX_PARAMETER_CHANGE_M
    expected = 'a pose sensor closes the leg lengths to a few um'
    if description is not None:
        limit, bound = description.residual_limit(), description.parameter_bound()
        expected = description.expected_text()
    gate.residual(report['residual_rms_m'] * 1e6, limit * 1e6, 'um', expected,
                  **({'causes': causes} if causes else {}))
    loose = undetermined_beyond(report, nominal, bound) if description is not None else {}
    for name, value in nominal.parameters().as_dict().items():
        if name in loose:
            continue
        gate.within(name, report['parameters'][name], value - bound, value + bound, 'm',
                    f'within {bound * 1e3:.3g} mm of the nominal'
                    + ('; a quarter of the base radius: the data put it there, so the model '
                       'bends to absorb an error it lacks (a leg\'s lead or scale, play), or '
                       'the nominal is not this machine\'s; machine-align analyze hexapod '
                       'names what the model lacks' if description is not None else ''))
    gate.finite_std_devs(report['std_devs'])
    gate.enforce()
