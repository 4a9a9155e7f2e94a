"""Machines shaped like those users bring, simulated independently of the suite's own
simulators (issue 56), for the closed loop's tests and bench: a 0.8 m hexapod whose legs are
read in motor revolutions, a shop's temperature cycle, a sparse ISO 230-2 acceptance run."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core.axis import AxisData
from hexapod_calib.core.calibration import PoseData
from hexapod_calib.core.geometry import HexapodGeometry, nominal_geometry

# A 0.8 m hexapod: base joints on a 410 mm radius, platform joints on 219 mm; the legs'
# fixed part 0.54 m, the actuator reads the rest (about 0.10 m at home).
FIXED_PART = 0.54
_SYMMETRIC = nominal_geometry(base_radius=0.410, platform_radius=0.219)
NOMINAL = HexapodGeometry(_SYMMETRIC.base_joints, _SYMMETRIC.platform_joints,
                          np.full(6, FIXED_PART))
HOME_Z = 0.58
LEAD_NOMINAL = 5e-3                    # m per motor revolution
LEAD_RATIO = np.array([1.004, 0.994, 1.06, 1.003, 0.998, 1.008])   # true / nominal
MOCAP_POSITION, MOCAP_ANGLE = 0.4e-3, 2e-3      # 1 sigma, m and rad


def leg_vectors(base, platform, poses):
    rotation = Rotation.from_euler('xyz', poses[:, 3:]).as_matrix()
    return (poses[:, None, :3] + np.einsum('nij,kj->nki', rotation, platform) - base[None])


def hexapod_day(seed: int, count: int, lead_ratio=LEAD_RATIO, workspace=0.06,
                 tilt=np.radians(4), noise=(MOCAP_POSITION, MOCAP_ANGLE), machine: int = 1000,
                 rehome=0.0):
    """Poses over the workspace (+-``workspace`` m in x and y, 2/3 of it in z, +-``tilt``
    rad), the platform measured with ``noise`` (m, rad; motion capture by default), the legs
    read in revolutions from home converted with the nominal lead. ``machine`` seeds the
    joint and leg errors (2 mm, 1 sigma), ``seed`` the poses and the noise; ``rehome``
    (m, per leg) shifts each leg's reading, as homing the legs again on another day does."""
    rng = np.random.default_rng(seed)
    truth = np.random.default_rng(machine)
    base = NOMINAL.base_joints + truth.normal(0, 2e-3, (6, 3))
    platform = NOMINAL.platform_joints + truth.normal(0, 2e-3, (6, 3))
    fixed = FIXED_PART + truth.normal(0, 2e-3, 6)
    poses = np.column_stack([rng.uniform(-workspace, workspace, (count, 2)),
                             HOME_Z + rng.uniform(-2 * workspace / 3, 2 * workspace / 3, count),
                             rng.uniform(-tilt, tilt, (count, 3))])
    lengths = np.linalg.norm(leg_vectors(base, platform, poses), axis=2)
    home = np.linalg.norm(leg_vectors(base, platform, np.array([[0, 0, HOME_Z, 0, 0, 0]])),
                          axis=2)[0]
    # revolutions turned from home, read back with the nominal lead
    revolutions = (lengths - home) / (LEAD_NOMINAL * np.asarray(lead_ratio))
    read = (home - fixed) + np.asarray(rehome) + revolutions * LEAD_NOMINAL
    measured = poses + np.column_stack([rng.normal(0, noise[0], (count, 3)),
                                        rng.normal(0, noise[1], (count, 3))])
    return PoseData(poses, measured, read)


def temperature_cycle(count: int, rng) -> np.ndarray:
    """K: a shop's 3 K cycle over the run, logged at each pose."""
    phase = np.sort(rng.uniform(0, 1, count))
    return 293.15 + 1.5 * np.sin(2 * np.pi * phase)


def iso_run(seed: int, drift: float, sigma: float = 1.5e-6, backlash: float = 5e-6):
    """An ISO 230-2 run: 5 irregular targets over 100 mm, 5 bidirectional cycles, 1.5 um
    scatter, 5 um backlash, 25 ppm lead error, and ``drift`` (m) over the run linear in the
    approach number; no clock logged, only the approach number."""
    rng = np.random.default_rng(seed)
    targets = np.array([0.0, 0.0212, 0.0497, 0.0731, 0.0986])
    command, direction, cycle = [], [], []
    for c in range(5):
        for d, order in ((1, targets), (-1, targets[::-1])):
            command += list(order)
            direction += [d] * len(order)
            cycle += [c + 1] * len(order)
    command, direction = np.array(command), np.array(direction, float)
    sequence = np.arange(len(command), dtype=float)
    measured = (command + 3e-6 + 25e-6 * command - backlash / 2 * direction
                + drift * sequence / sequence[-1] + rng.normal(0, sigma, len(command)))
    return AxisData(command, measured, direction, {'cycle': np.array(cycle, float),
                                                   'sequence': sequence})


def growing_leg(seed: int, growth: float, count: int = 90, machine: int = 1000) -> PoseData:
    """The hexapod moving +-4 mm and +-0.3 deg (legs +-5 mm), measured to 2 um and 10 urad,
    through a 3 K temperature cycle, leg 2 growing ``growth`` m/K (12 ppm/K of 0.64 m is
    7.7e-6): the leg reads short by what it grew."""
    rng = np.random.default_rng(seed + 7)
    data = hexapod_day(seed, count, lead_ratio=np.ones(6), workspace=0.004,
                       tilt=np.radians(0.3), noise=(2e-6, 10e-6), machine=machine)
    temperature = temperature_cycle(count, rng)
    legs = data.leg_lengths.copy()
    legs[:, 1] -= growth * (temperature - temperature.mean())
    return PoseData(data.commanded, data.measured, legs, {'temperature': temperature})


def bow(command: np.ndarray, amplitude: float) -> np.ndarray:
    """A smooth 2-D error (m, (n, 2)) over the travel the commands span: x bows with y
    (amplitude * v^2), y with x and the diagonal (0.7 amplitude (u^2 - u v)), u and v the
    positions scaled to [-1, 1] over the travel."""
    u = 2 * (command - command.min(axis=0)) / np.ptp(command, axis=0) - 1
    return np.column_stack([amplitude * u[:, 1] ** 2,
                            0.7 * amplitude * (u[:, 0] ** 2 - u[:, 0] * u[:, 1])])


def independent_fit(data: PoseData, with_scale: bool):
    """A least-squares fit of the hexapod written here, not the suite's identification:
    joints (36), leg offsets (6) and, ``with_scale``, a scale per leg (6) to the leg
    lengths (m), from :data:`NOMINAL`. Returns the solution and its residual function
    ``residuals(x, measured poses, leg lengths)`` (m, flattened), to evaluate it on other
    poses."""
    from scipy.optimize import least_squares

    def residuals(x, measured, legs):
        base, platform = x[:18].reshape(6, 3), x[18:36].reshape(6, 3)
        scale = x[42:48] if with_scale else np.zeros(6)
        return (np.linalg.norm(leg_vectors(base, platform, measured), axis=2) - x[36:42]
                - legs * (1 + scale)).ravel()
    start = np.concatenate([NOMINAL.base_joints.ravel(), NOMINAL.platform_joints.ravel(),
                            NOMINAL.leg_length_offsets] + ([np.zeros(6)] if with_scale else []))
    return least_squares(residuals, start, args=(data.measured, data.leg_lengths)).x, residuals
