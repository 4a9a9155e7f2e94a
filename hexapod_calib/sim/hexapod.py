"""Simulated hexapod and pose sensor.

The true hexapod differs from the nominal one by geometric errors of a few tenths of a mm
(joint centres, actuator offsets), which the 42-parameter model describes, and by effects
it does not: joint play of 8-10 um per leg (linear guide backlash plus two universal joints,
taken up by the static leg force, or by the direction of the last move where that force is
too small to close it), and actuator positioning noise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import InvalidInputError, OutOfTravelError
from hexapod_calib.core.geometry import (
    HexapodGeometry, as_poses, nominal_geometry)
from hexapod_calib.core.kinematics import (
    MAX_CONDITION, condition_numbers, forward_kinematics, inverse_kinematics)
from hexapod_calib.core.statics import leg_forces

def true_geometry(nominal: HexapodGeometry, seed: int = 2, joint_sigma: float = 0.1e-3,
                  offset_sigma: float = 0.1e-3) -> HexapodGeometry:
    """The nominal geometry with random joint-centre (m, per coordinate) and actuator
    offset (m) errors."""
    rng = np.random.default_rng(seed)
    return HexapodGeometry(nominal.base_joints + rng.normal(0, joint_sigma, (6, 3)),
                           nominal.platform_joints + rng.normal(0, joint_sigma, (6, 3)),
                           nominal.leg_length_offsets + rng.normal(0, offset_sigma, 6))


@dataclass(frozen=True)
class HexapodTruth:
    """What the simulated hexapod really is (SI units).

    Attributes
    ----------
    geometry : HexapodGeometry
    leg_play : ndarray (6,)
        Total play per leg, m (the paper: 3 um guide backlash + 2 joints of ~3 um).
    payload_mass : float
        kg, carried by the platform.
    payload_centre : ndarray (3,)
        Centre of mass in the platform frame, m; off-centre so leg forces vary over the
        workspace.
    force_to_close_play : float
        N; below this axial force the play stays where the last move left it.
    actuator_noise : float
        1-sigma random positioning error per leg and move, m.
    lead_ratio : tuple (6,)
        True over nominal lead per leg: the leg travels this times the commanded length
        (a lead screw's lead off, read with the nominal one).
    """

    geometry: HexapodGeometry
    leg_play: np.ndarray
    payload_mass: float = 25.0
    payload_centre: tuple = (0.03, -0.02, 0.08)
    force_to_close_play: float = 5.0
    actuator_noise: float = 0.5e-6
    lead_ratio: tuple = (1.0,) * 6

    @classmethod
    def default(cls, nominal: HexapodGeometry | None = None, seed: int = 2) -> 'HexapodTruth':
        nominal = nominal or nominal_geometry()
        rng = np.random.default_rng(seed + 1)
        return cls(true_geometry(nominal, seed), rng.uniform(8.3e-6, 9.9e-6, 6))

    @classmethod
    def ideal(cls, nominal: HexapodGeometry | None = None) -> 'HexapodTruth':
        """No geometric error, no play, no noise: for tests of the kinematics."""
        return cls(nominal or nominal_geometry(), np.zeros(6), actuator_noise=0.0)


@dataclass(frozen=True)
class Stroke:
    """Actuator stroke limits, m."""

    minimum: float = 0.17
    maximum: float = 0.30

    def check(self, lengths: np.ndarray) -> None:
        low, high = lengths < self.minimum, lengths > self.maximum
        if np.any(low | high):
            leg = int(np.argmax(low | high))
            raise OutOfTravelError(f'leg {leg + 1} length {lengths[leg] * 1e3:.3f} mm is outside '
                                   f'the stroke [{self.minimum * 1e3:.1f}, '
                                   f'{self.maximum * 1e3:.1f}] mm; not moved')


HOME_POSE = np.array([0.0, 0.0, 0.20, 0.0, 0.0, 0.0])
# Centre of mass of a tall fixture (platform frame, m): its weight's lever arm makes every
# leg's static force change sign over the workspace, so joint play shows in every leg.
TALL_PAYLOAD_CENTRE = (0.02, -0.01, 0.5)


class HexapodSim:
    """A hexapod that moves to commanded actuator lengths (or to poses through its
    controller's nominal inverse kinematics) and refuses lengths outside the stroke, poses
    near a singularity and lengths no pose realises."""

    def __init__(self, truth: HexapodTruth | None = None, nominal: HexapodGeometry | None = None,
                 stroke: Stroke = Stroke(), max_condition: float = MAX_CONDITION, seed: int = 0,
                 home=HOME_POSE):
        self.nominal = nominal or nominal_geometry()
        self.truth = truth or HexapodTruth.default(self.nominal)
        self.stroke = stroke
        self.max_condition = max_condition
        self._rng = np.random.default_rng(seed)
        self.pose = as_poses(home)[0].copy()
        self.leg_lengths = inverse_kinematics(self.nominal, self.pose)[0]
        self._play_side = np.zeros(6)      # -1/+1: where the play sits in weakly loaded legs
        self.pose, self._play_side = self._realise(self.leg_lengths, np.zeros(6))

    def _play(self, pose: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Leg length change by joint play at ``pose`` (m, (6,)) and the side (-1/+1) the
        play sits on in each leg."""
        truth = self.truth
        force = leg_forces(truth.geometry, pose, truth.payload_mass, truth.payload_centre)[0]
        side = np.where(direction != 0, -np.sign(direction), self._play_side)
        side = np.where(np.abs(force) >= truth.force_to_close_play, -np.sign(force), side)
        return 0.5 * truth.leg_play * side, side

    def _realise(self, lengths: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pose the true hexapod takes for commanded ``lengths``, and the play sides."""
        geometry = self.truth.geometry
        lengths = lengths * np.asarray(self.truth.lead_ratio)
        pose = forward_kinematics(geometry, lengths, initial=self.pose,
                                  max_condition=self.max_condition)[0]
        noise = self._rng.normal(0.0, self.truth.actuator_noise, 6)
        # The play depends on the load at the pose it produces: two fixed-point steps settle it.
        for _ in range(2):
            shift, side = self._play(pose, direction)
            pose = forward_kinematics(geometry, lengths + shift + noise, initial=pose,
                                      max_condition=self.max_condition)[0]
        return pose, side

    def move_legs(self, lengths) -> np.ndarray:
        """Command actuator lengths (m, (6,)); return the commanded lengths as recorded.
        A refused move changes nothing."""
        lengths = np.asarray(lengths, dtype=float)
        if lengths.shape != (6,) or not np.all(np.isfinite(lengths)):
            raise InvalidInputError(f'need six finite leg lengths, got {lengths!r}')
        self.stroke.check(lengths)
        self.pose, self._play_side = self._realise(lengths, np.sign(lengths - self.leg_lengths))
        self.leg_lengths = lengths.copy()
        return self.leg_lengths.copy()

    def move_pose(self, pose) -> np.ndarray:
        """Move to ``pose`` (6,) through the controller's nominal inverse kinematics;
        refuse poses near a singularity. Returns the commanded leg lengths, m."""
        pose = as_poses(pose)[0]
        condition = condition_numbers(self.nominal, pose)[0]
        if condition > self.max_condition:
            raise OutOfTravelError(f'pose is near a singularity (condition number '
                                   f'{condition:.3g}); not moved')
        return self.move_legs(inverse_kinematics(self.nominal, pose)[0])


class PoseSensorSim:
    """An external instrument (CMM / laser tracker) measuring the platform pose.

    Noise (1 sigma): ``position_noise`` m per axis, ``angle_noise`` rad per axis."""

    def __init__(self, position_noise: float = 0.6e-6, angle_noise: float = 6e-6, seed: int = 1):
        if position_noise < 0 or angle_noise < 0:
            raise InvalidInputError('noise levels must be >= 0')
        self.position_noise, self.angle_noise = position_noise, angle_noise
        self._rng = np.random.default_rng(seed)

    def measure(self, true_pose) -> np.ndarray:
        """A measured pose (6,), m and rad."""
        noise = np.concatenate([self._rng.normal(0, self.position_noise, 3),
                                self._rng.normal(0, self.angle_noise, 3)])
        return as_poses(true_pose)[0] + noise

    def covariance(self) -> np.ndarray:
        """Measurement covariance, (6, 6), m^2 and rad^2."""
        return np.diag([self.position_noise ** 2] * 3 + [self.angle_noise ** 2] * 3)


def measure_random_poses(truth: HexapodTruth, count: int, seed: int,
                         nominal: HexapodGeometry | None = None):
    """Drive the simulated hexapod through ``count`` well-conditioned random poses with the
    nominal leg lengths and measure each with the pose sensor. Returns the PoseData and
    the static leg forces (N, (count, 6)) an engineer computes from the known payload
    with the nominal geometry."""
    from hexapod_calib.core.procedure import HexapodPlan, measure_poses
    nominal = nominal or nominal_geometry()
    sim, sensor = HexapodSim(truth, nominal, seed=seed), PoseSensorSim(seed=seed + 1)
    poses, _ = HexapodPlan(num_poses=count, num_evaluation=1, num_candidates=2 * count + 10,
                           seed=seed + 2).poses(nominal)
    data = measure_poses(poses, inverse_kinematics(nominal, poses), sim.move_legs,
                         lambda: sensor.measure(sim.pose))
    return data, leg_forces(nominal, poses, truth.payload_mass, truth.payload_centre)


def displacement_after_identifying(truth: HexapodTruth, nominal: HexapodGeometry, poses,
                                   working, seed: int) -> float:
    """The simulated hexapod ``truth`` measured at ``poses`` (n, 6) with the nominal legs,
    its 42 parameters identified, then sent to ``working`` (W, 6) with the identified
    geometry: the RMS displacement error there (m), what a plan's prediction predicts."""
    from hexapod_calib.core.calibration import identify, pose_errors
    from hexapod_calib.core.procedure import measure_poses
    sim, sensor = HexapodSim(truth, nominal, seed=seed), PoseSensorSim(seed=seed + 1)
    data = measure_poses(poses, inverse_kinematics(nominal, poses), sim.move_legs,
                         lambda: sensor.measure(sim.pose))
    identified = identify(data, nominal).geometry
    reached = []
    for legs in inverse_kinematics(identified, working):
        sim.move_legs(legs)
        reached.append(sim.pose.copy())
    return float(np.sqrt(np.mean(pose_errors(working, np.array(reached))[0] ** 2)))
