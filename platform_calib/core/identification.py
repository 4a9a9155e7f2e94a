"""Identification of the 18 parameters from laser-tracker poses and the feeds' displacement
sensors (the source's least squares, chain by chain): for chain i and pose k the loop must
close, ``|C_i(P_k) - A_i - rho_ik e_i| = L_i``. One equation per chain and pose, six
unknowns per chain: at least 6 poses, and poses that move every chain's joint in enough
directions. The residual is the closure error in m."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.datasets import read_columns, write_columns
from calib_core.sanity import SanityGate
from calib_core.schema import Column, Schema
from platform_calib.core.geometry import CHAIN_PARAMETERS, UNITS, PlatformGeometry, parameter_names
from platform_calib.core.kinematics import joint_positions, pose_jacobians, slide_positions

MIN_POSES = 6
FEED_COLUMNS = ('feed1', 'feed2', 'feed3')     # the feeds' readings: the actuators
COLUMNS = FEED_COLUMNS + ('x', 'y', 'theta')
DIRECTION_COLUMNS = ('direction1', 'direction2', 'direction3')
COVARIATE_COLUMNS = ('time', 'temperature')
# What a screen-registration platform's tracker reports: positions within half a metre of
# its zero, turns of a few degrees (a 3-PRR platform of this kind turns well under 45 deg);
# feed sensors within a metre whatever the stroke (the stroke is checked against the
# geometry: check_within_stroke).
POSE_SCHEMA = Schema((
    Column('x', 'm', -0.5, 0.5, 'measured platform x'),
    Column('y', 'm', -0.5, 0.5, 'measured platform y'),
    Column('theta', 'rad', -np.pi / 4, np.pi / 4, 'measured platform angle'),
    *(Column(f'feed{i}', 'm', -1.0, 1.0, f'feed {i} reading') for i in (1, 2, 3))))
# A feed may read a little outside its stroke (a sensor's zero); by this share of the
# stroke's length at most.
STROKE_MARGIN = 0.25
# Below this singular value (of the chain's Jacobian with unit columns, relative to the
# largest) a parameter combination is taken as not determined by the poses.
RANK_TOLERANCE = 1e-6


@dataclass(frozen=True)
class PoseData:
    """Measured poses (n, 3) (x m, y m, theta rad, tracker's base frame) and the feeds'
    sensor readings (n, 3) m; ``covariates`` (name -> (n,) or (n, 3)) for the closed loop:
    ``direction`` of each feed's last motion (+1 / -1), ``time`` (s), ``temperature`` (K)."""

    poses: np.ndarray
    feeds: np.ndarray
    covariates: dict | None = None

    def __post_init__(self):
        for name in ('poses', 'feeds'):
            value = np.atleast_2d(np.asarray(getattr(self, name), dtype=float))
            if value.ndim != 2 or value.shape[1] != 3:
                raise InvalidInputError(f'{name} must be rows of three values')
            if not np.all(np.isfinite(value)):
                raise InvalidInputError(f'{name} contain NaN or infinite values')
            object.__setattr__(self, name, value)
        if len(self.poses) != len(self.feeds):
            raise InvalidInputError('one feed triple per pose is needed')
        POSE_SCHEMA.check(dict(zip(('x', 'y', 'theta', 'feed1', 'feed2', 'feed3'),
                                   np.hstack([self.poses, self.feeds]).T)), 'the pose data')

    def __len__(self) -> int:
        return len(self.poses)

    @classmethod
    def from_csv(cls, path, dropped: dict | None = None,
                 feed_m_per_unit: float = 1.0) -> 'PoseData':
        """Columns feed1, feed2, feed3 (m, or units of ``feed_m_per_unit`` m: revolutions
        of a lead), x, y (m), theta (rad); optional direction1..3, time, temperature
        (covariates with NaN are left out and named in ``dropped``)."""
        columns = read_columns(path, list(COLUMNS), dropped)
        for name in ('feed1', 'feed2', 'feed3'):
            columns[name] = columns[name] * feed_m_per_unit
        covariates = {k: columns[k] for k in COVARIATE_COLUMNS if k in columns}
        if all(c in columns for c in DIRECTION_COLUMNS):
            covariates['direction'] = np.column_stack([columns[c] for c in DIRECTION_COLUMNS])
        return cls(np.column_stack([columns['x'], columns['y'], columns['theta']]),
                   np.column_stack([columns['feed1'], columns['feed2'], columns['feed3']]),
                   covariates or None)

    def to_csv(self, path, feed_m_per_unit: float = 1.0) -> None:
        """The CSV :meth:`from_csv` reads, the feeds in units of ``feed_m_per_unit`` m."""
        extra = dict(self.covariates or {})
        direction = extra.pop('direction', None)
        names = list(COLUMNS) + (list(DIRECTION_COLUMNS) if direction is not None else [])
        columns = ([self.feeds / feed_m_per_unit, self.poses]
                   + ([direction] if direction is not None else []))
        write_columns(path, names + sorted(extra), columns + [extra[k] for k in sorted(extra)])


@dataclass(frozen=True)
class Identification:
    """The identified geometry with 1-sigma standard deviations (18,) in SI units (NaN
    where the poses leave no redundancy), the closure residuals (n, 3) m and each chain's
    condition number."""

    geometry: PlatformGeometry
    std_devs: np.ndarray
    residuals: np.ndarray
    condition: np.ndarray

    def report(self) -> dict:
        names = parameter_names()
        r = self.residuals
        return {'parameters': self.geometry.as_dict(),
                'std_devs': dict(zip(names, map(float, self.std_devs))),
                'units': {n: UNITS[n.rstrip('123')] for n in names},
                'residual_rms_m': float(np.sqrt(np.mean(r ** 2))),
                'residual_max_m': float(np.abs(r).max()),
                'condition_per_chain': [float(c) for c in self.condition],
                'poses': int(len(r))}


def _chain_gap(geometry: PlatformGeometry, chain: int, vector: np.ndarray, data: PoseData):
    """The geometry with chain ``chain``'s six parameters set to ``vector``, and C_i - B_i
    of that chain at every pose (n, 2) m."""
    full = geometry.vector()
    full[6 * chain:6 * chain + 6] = vector
    candidate = geometry.with_vector(full)
    gap = joint_positions(candidate, data.poses) - slide_positions(candidate, data.feeds)
    return candidate, gap[:, chain]


def _chain_residual(geometry: PlatformGeometry, chain: int, vector: np.ndarray,
                    data: PoseData) -> np.ndarray:
    candidate, d = _chain_gap(geometry, chain, vector, data)
    return np.linalg.norm(d, axis=-1) - candidate.length[chain]


def _chain_jacobian(geometry: PlatformGeometry, chain: int, vector: np.ndarray,
                    data: PoseData) -> np.ndarray:
    candidate, d = _chain_gap(geometry, chain, vector, data)
    distance = np.linalg.norm(d, axis=-1)
    g_par = pose_jacobians(candidate, data.poses, data.feeds)[2][:, chain, 6 * chain:6 * chain + 6]
    jacobian = g_par / (2 * distance[:, None])      # d|d|/de = (dg/de) / (2 |d|)
    jacobian[:, 3] = -1.0                            # d(|d| - L)/dL
    return jacobian


def undetermined(jacobian: np.ndarray, chain: int) -> list[str]:
    """Names of the chain's parameters in directions the poses do not determine."""
    scale = np.linalg.norm(jacobian, axis=0)
    if np.any(scale == 0):
        return [f'{CHAIN_PARAMETERS[k]}{chain + 1}' for k in np.flatnonzero(scale == 0)]
    _, singular, vt = np.linalg.svd(jacobian / scale, full_matrices=False)
    weak = singular < RANK_TOLERANCE * singular[0]
    names = set()
    for row in vt[weak]:
        names |= {f'{CHAIN_PARAMETERS[k]}{chain + 1}' for k in np.flatnonzero(np.abs(row) > 0.3)}
    return sorted(names)


def check_within_stroke(data: PoseData, geometry: PlatformGeometry) -> None:
    """Refuse feed readings outside ``geometry``'s stroke (by more than
    :data:`STROKE_MARGIN` of its length): the platform cannot have been there, so the feeds
    are in another unit or from another zero.

    Raises
    ------
    InvalidInputError"""
    low, high = geometry.stroke
    margin = STROKE_MARGIN * (high - low)
    feeds = Schema(tuple(
        Column(f'feed{i + 1}', 'm', low - margin, high + margin,
               f'feed {i + 1} reading, stroke {low * 1e3:g}..{high * 1e3:g} mm')
        for i in range(3)))
    feeds.check({f'feed{i + 1}': data.feeds[:, i] for i in range(3)}, 'the pose data')


def check_determined(data: PoseData, start: PlatformGeometry) -> None:
    """Refuse pose data that cannot determine the 18 parameters about ``start``: readings
    outside the stroke, fewer than 6 poses, or a chain's parameters left undetermined
    (named) by poses too alike.

    Raises
    ------
    CalibrationError, InvalidInputError"""
    check_within_stroke(data, start)
    if len(data) < MIN_POSES:
        raise CalibrationError(f'the 18 parameters need at least {MIN_POSES} poses (6 per '
                               f'chain, one equation each per pose); got {len(data)}')
    for chain in range(3):
        x0 = start.vector()[6 * chain:6 * chain + 6]
        lacking = undetermined(_chain_jacobian(start, chain, x0, data), chain)
        if lacking:
            raise CalibrationError(f'the poses do not determine chain {chain + 1}: '
                                   f'{", ".join(lacking)} (move the platform in x, y and '
                                   'theta, with every feed over its stroke)')


def identify(data: PoseData, start: PlatformGeometry,
             derivatives: str = 'analytic') -> Identification:
    """The 18 parameters by least squares, chain by chain, from ``start`` (the nominal).
    ``derivatives``: ``'analytic'`` (the chains' Jacobians) or ``'2-point'`` (scipy's
    finite differences: the baseline ``make bench`` times against).

    Raises
    ------
    CalibrationError
        Fewer than 6 poses, or poses that do not determine a chain's parameters (named)."""
    if derivatives not in ('analytic', '2-point'):
        raise InvalidInputError(f"derivatives must be 'analytic' or '2-point', not {derivatives!r}")
    analytic = derivatives == 'analytic'
    check_determined(data, start)
    geometry, std, residuals, condition = start, np.full(18, np.nan), [], []
    for chain in range(3):
        x0 = start.vector()[6 * chain:6 * chain + 6]
        # The link length stays positive (a geometry needs it); nothing else is bounded.
        lower = np.full(6, -np.inf)
        lower[3] = 1e-6
        solution = least_squares(
            lambda v: _chain_residual(start, chain, v, data), x0,
            jac=(lambda v: _chain_jacobian(start, chain, v, data)) if analytic else '2-point',
            method='trf',
            bounds=(lower, np.inf), xtol=1e-15, ftol=1e-15, gtol=1e-15)
        full = geometry.vector()
        full[6 * chain:6 * chain + 6] = solution.x
        geometry = geometry.with_vector(full)
        jacobian = solution.jac
        scale = np.linalg.norm(jacobian, axis=0)
        singular = np.linalg.svd(jacobian / scale, compute_uv=False)
        condition.append(singular[0] / singular[-1])
        dof = len(data) - 6
        if dof > 0:
            variance = float(solution.fun @ solution.fun) / dof
            cov = np.linalg.inv(jacobian.T @ jacobian) * variance
            std[6 * chain:6 * chain + 6] = np.sqrt(np.clip(np.diag(cov), 0, None))
        residuals.append(solution.fun)
    return Identification(geometry, std, np.column_stack(residuals), np.array(condition))


# The gate before a geometry is written or put in force. A laser tracker and the feed
# sensors close the loop to about 10 um RMS (the simulated platform: 9.9 um at 20 poses);
# ten times that is a fit to data in another unit or of another machine.
MAX_CLOSURE_RMS_M = 100e-6
# How far an identified platform may lie from its nominal and still be that platform.
MAX_POSITION_SHIFT_M = 10e-3      # base and joint positions
MAX_DIRECTION_CHANGE_RAD = 0.2    # feed directions
MAX_LENGTH_CHANGE = 0.2           # links, relative


def check_identification(result: Identification, nominal: PlatformGeometry,
                         description=None, causes: str | None = None) -> None:
    """Refuse an identification that cannot be the platform: closure residual RMS over
    :data:`MAX_CLOSURE_RMS_M`, a parameter beyond its bound from the nominal, or a standard
    deviation that is not finite (poses that leave no redundancy). With a ``description``
    (:class:`platform_calib.core.description.PlatformDescription`) the residual limit is
    its declared noise's and the position bound a share of its size; ``causes`` names the
    likely causes of a residual refused (most likely first).

    Raises
    ------
    CalibrationError
        Every failure named; nothing may be written."""
    gate = SanityGate('the platform identification')
    report = result.report()
    limit, shift = MAX_CLOSURE_RMS_M, MAX_POSITION_SHIFT_M
    expected = 'a laser tracker and feed sensors close the loop to about 10 um'
    if description is not None:
        limit, shift = description.residual_limit(), description.position_bound()
        expected = description.expected_text()
    gate.residual(report['residual_rms_m'] * 1e6, limit * 1e6, 'um', expected,
                  **({'causes': causes} if causes else {}))
    identified, start = result.geometry, nominal
    for i in range(3):
        k = i + 1
        for name, value, ref in ((f'x_A{k}', identified.base[i, 0], start.base[i, 0]),
                                 (f'y_A{k}', identified.base[i, 1], start.base[i, 1]),
                                 (f'x_C{k}', identified.joints[i, 0], start.joints[i, 0]),
                                 (f'y_C{k}', identified.joints[i, 1], start.joints[i, 1])):
            gate.within(name, value, ref - shift, ref + shift, 'm',
                        f'within {shift * 1e3:.3g} mm of the nominal')
        turned = start.alpha[i] + np.angle(np.exp(1j * (identified.alpha[i] - start.alpha[i])))
        gate.within(f'alpha{k}', turned, start.alpha[i] - MAX_DIRECTION_CHANGE_RAD,
                    start.alpha[i] + MAX_DIRECTION_CHANGE_RAD, 'rad',
                    f'within {MAX_DIRECTION_CHANGE_RAD:g} rad of the nominal feed direction')
        gate.within(f'L{k}', identified.length[i], start.length[i] * (1 - MAX_LENGTH_CHANGE),
                    start.length[i] * (1 + MAX_LENGTH_CHANGE), 'm',
                    f'within {MAX_LENGTH_CHANGE:.0%} of the nominal link')
    gate.finite_std_devs(report['std_devs'])
    gate.enforce()
