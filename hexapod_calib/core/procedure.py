"""The hexapod calibration run, independent of ROS: plan poses, drive, measure, identify,
iterate with the recorded leg lengths, evaluate on separate poses.

The node injects its service calls as ``move_legs`` and ``measure``; tests and the offline
study inject the simulator directly. A recorded run replays through
:func:`identify_from_records` with the same result.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Callable

import numpy as np

from calib_core.checks import MAX_POSITION_M, MAX_SEED, whole_number
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.planning import Adaptive
from hexapod_calib.core.calibration import (
    Identification, PoseData, compensate, identifiability, identify, select_poses,
    summarise_pose_errors)
from hexapod_calib.core.geometry import HexapodGeometry, as_poses
from hexapod_calib.core.kinematics import MAX_CONDITION, condition_numbers, inverse_kinematics
from hexapod_calib.core.planning import exchange_poses, extend_poses, predict

IDENTIFY_PHASE = 'identify_{}'
EVALUATE_NOMINAL = 'evaluate_nominal'
EVALUATE_CALIBRATED = 'evaluate_calibrated'
DESIGNS = ('greedy', 'I', 'D')
WORKING_SAMPLE = 100        # candidates that stand for the box in the I criterion


@dataclass(frozen=True)
class HexapodPlan:
    """What a calibration run measures (SI units).

    Poses are drawn uniformly from a box about ``home`` (half-widths ``translation`` in m
    and ``rotation`` in rad), kept if the nominal leg lengths lie inside ``stroke`` with
    ``margin`` and the pose is well conditioned; ``num_poses`` of ``num_candidates`` are
    chosen for the best-conditioned identification (``design`` 'greedy': each leg's
    information determinant, greedily; 'I' or 'D': the shared exchange on the rows
    whitened by the pose sensor's and actuators' noise, 'I' for the least pose error over
    the box), ``num_evaluation`` others are kept for evaluation only. ``targets`` (n, 6;
    m, rad), when given, are a planned set measured instead (e.g. the CSV of
    ``machine-align plan hexapod``); ``num_poses`` is then their number.

    Adaptive with ``target_error`` > 0 (m, the predicted RMS displacement at working poses
    of the box): after the iterations, poses of the box are added ``step`` at a time (the
    ones that lower the prediction most about the geometry identified so far, measured as
    a further round of the iteration) up to ``max_poses`` pose measurements in all
    (repeats of a pose in later rounds count)."""

    num_poses: int = 30
    num_candidates: int = 400
    num_evaluation: int = 30
    iterations: int = 2
    seed: int = 0
    home: tuple = (0.0, 0.0, 0.20, 0.0, 0.0, 0.0)
    translation: tuple = (0.02, 0.02, 0.02)
    rotation: tuple = (0.1, 0.1, 0.1)
    stroke: tuple = (0.17, 0.30)
    margin: float = 0.002
    targets: tuple = ()
    design: str = 'greedy'
    target_error: float = 0.0
    max_poses: int = 60
    step: int = 4

    def __post_init__(self):
        if self.design not in DESIGNS:
            raise InvalidInputError(f'design must be one of {", ".join(DESIGNS)}, not '
                                    f'{self.design!r}')
        if len(self.targets):
            targets = as_poses(self.targets, 'targets')
            if np.abs(targets[:, :3]).max() > MAX_POSITION_M or \
                    np.abs(targets[:, 3:]).max() > np.pi:
                raise InvalidInputError('targets must be x, y, z in m and roll, pitch, yaw in '
                                        f'rad (values beyond {MAX_POSITION_M:g} m or pi: mm or '
                                        'degrees?)')
            object.__setattr__(self, 'targets', tuple(map(tuple, targets.tolist())))
            object.__setattr__(self, 'num_poses', len(targets))
        if not (isinstance(self.target_error, (int, float)) and np.isfinite(self.target_error)
                and 0 <= self.target_error < 1e-3):
            raise InvalidInputError(f'target_error must be a displacement in m (0 for none, '
                                    f'below 1 mm), not {self.target_error!r}')
        for name in ('num_poses', 'num_candidates', 'num_evaluation', 'iterations', 'seed',
                     'max_poses', 'step'):
            object.__setattr__(self, name, whole_number(getattr(self, name), name, *(
                (0, MAX_SEED) if name == 'seed' else (1,))))
        if not (isinstance(self.margin, (int, float)) and np.isfinite(self.margin)
                and self.margin >= 0):
            raise InvalidInputError(f'margin must be a length >= 0 (m), not {self.margin!r}')
        if (0 if len(self.targets) else self.num_poses) + self.num_evaluation > \
                self.num_candidates:
            raise InvalidInputError('num_candidates must be at least num_poses + num_evaluation')
        for name, size in (('home', 6), ('translation', 3), ('rotation', 3), ('stroke', 2)):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (size,) or not np.all(np.isfinite(value)):
                raise InvalidInputError(f'{name} must be {size} finite numbers')
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if min(self.translation + self.rotation) < 0 or self.stroke[0] >= self.stroke[1]:
            raise InvalidInputError('ranges must be >= 0 and stroke (min, max) increasing')

    @classmethod
    def from_mapping(cls, overrides: dict) -> 'HexapodPlan':
        known = {f.name for f in fields(cls)}
        unknown = set(overrides) - known
        if unknown:
            raise InvalidInputError(f'unknown plan keys {sorted(unknown)}; known: {sorted(known)}')
        return cls(**overrides)

    def poses(self, nominal: HexapodGeometry) -> tuple[np.ndarray, np.ndarray]:
        """(identification poses (num_poses, 6), evaluation poses (num_evaluation, 6)).

        Raises
        ------
        InvalidInputError
            Too few poses of the box lie inside the stroke.
        CalibrationError
            The chosen poses cannot determine the 42 parameters (e.g. they coincide)."""
        rng, candidates = self._candidates(nominal)
        planned = len(self.targets) > 0
        if len(candidates) < (0 if planned else self.num_poses) + self.num_evaluation:
            raise InvalidInputError(f'only {len(candidates)} poses of the box lie inside the '
                                    'stroke; shrink the ranges or ask for fewer poses')
        if planned:
            identification, rest = np.array(self.targets), np.arange(len(candidates))
            legs = inverse_kinematics(nominal, identification)
            outside = np.flatnonzero(np.any(legs < self.stroke[0] + self.margin, axis=1)
                                     | np.any(legs > self.stroke[1] - self.margin, axis=1))
            if len(outside):
                raise InvalidInputError(f'targets {outside.tolist()} put a leg outside the '
                                        f'stroke {self.stroke} m with margin {self.margin} m')
        else:
            if self.design == 'greedy':
                chosen = select_poses(nominal, candidates, self.num_poses)
            else:
                chosen = exchange_poses(nominal, candidates, self.num_poses, self.design,
                                        self._working(candidates))
            identification = candidates[chosen]
            rest = np.setdiff1d(np.arange(len(candidates)), chosen)
        # Poses that cannot determine the parameters fail here, before anything moves.
        identifiability(nominal, identification)
        return identification, candidates[rng.choice(rest, self.num_evaluation, replace=False)]

    def _candidates(self, nominal: HexapodGeometry) -> tuple[np.random.Generator, np.ndarray]:
        """The box's poses inside the stroke and well conditioned (num_candidates, 6), and
        the generator that drew them (the evaluation poses are drawn from it next)."""
        rng = np.random.default_rng(self.seed)
        half = np.array(self.translation + self.rotation)
        candidates = np.array(self.home) + rng.uniform(-1, 1, (4 * self.num_candidates, 6)) * half
        legs = inverse_kinematics(nominal, candidates)
        ok = (np.all(legs >= self.stroke[0] + self.margin, axis=1)
              & np.all(legs <= self.stroke[1] - self.margin, axis=1)
              & (condition_numbers(nominal, candidates) < MAX_CONDITION / 10))
        return rng, candidates[ok][:self.num_candidates]

    def _working(self, candidates: np.ndarray) -> np.ndarray:
        """The candidates that stand for the box in the I criterion, drawn from their own
        generator so the plan's draws stay as they are."""
        return candidates[np.random.default_rng(self.seed + 1).choice(
            len(candidates), min(WORKING_SAMPLE, len(candidates)), replace=False)]

    def extension(self, nominal: HexapodGeometry, taken) -> tuple[np.ndarray, np.ndarray]:
        """What the adaptive rounds choose from and aim at: the box's candidates other than
        the ``taken`` poses (identification and evaluation), and the working poses."""
        _, candidates = self._candidates(nominal)
        return other_than(candidates, taken), self._working(candidates)


def other_than(poses: np.ndarray, taken) -> np.ndarray:
    """``poses`` (n, 6) without those equal to one of ``taken`` (k, 6)."""
    taken = np.asarray(taken, dtype=float)
    return poses[~np.any(np.all(np.abs(poses[:, None] - taken[None]) < 1e-12, axis=2), axis=1)]


@dataclass
class HexapodCalibration:
    """Outcome of a run: the identified geometry and the report (SI units)."""

    identification: Identification
    report: dict = field(default_factory=dict)

    @property
    def geometry(self) -> HexapodGeometry:
        return self.identification.geometry


def measure_poses(targets, legs, move_legs, measure, phase: str = 'measure', record=None,
                  progress=None, step: int = 0, total: int | None = None) -> PoseData:
    """Drive ``legs`` (n, 6; m) one after the other and measure each pose.

    ``record(phase, target, recorded legs, measured pose)`` and ``progress(step, total,
    message)`` are called at every stop when given."""
    total = len(targets) if total is None else total
    recorded, measured = [], []
    for k, (target, lengths) in enumerate(zip(targets, legs)):
        recorded.append(np.asarray(move_legs(lengths), dtype=float))
        measured.append(np.asarray(measure(), dtype=float))
        if record:
            record(phase, target, recorded[-1], measured[-1])
        if progress:
            progress(step + k + 1, total, f'{phase}: pose {k + 1}/{len(targets)}')
    return PoseData(targets, np.array(measured), np.array(recorded))


def _identify_round(rounds: list[PoseData], geometry: HexapodGeometry) -> tuple[
        Identification, dict]:
    """One step of the paper's iteration: identify from every round so far with the
    recorded leg lengths, starting from the previous estimate ``geometry``."""
    identification = identify(PoseData.concatenate(rounds), geometry)
    report = identification.report()
    change = np.array(list(report['change_from_initial'].values()))
    return identification, {'round': len(rounds) - 1, 'num_poses': identification.num_poses,
                            'residual_rms_m': report['residual_rms_m'],
                            'parameter_change_max_m': float(np.max(np.abs(change)))}


def iterate_identification(rounds: list[PoseData], nominal: HexapodGeometry) -> tuple[
        Identification, list[dict]]:
    """The paper's iteration over recorded rounds: round k's poses were driven with the
    geometry identified after round k-1."""
    geometry, history, identification = nominal, [], None
    for k in range(len(rounds)):
        identification, entry = _identify_round(rounds[:k + 1], geometry)
        history.append(entry)
        geometry = identification.geometry
    return identification, history


def run_hexapod_calibration(plan: HexapodPlan, nominal: HexapodGeometry,
                            move_legs: Callable, measure: Callable,
                            progress: Callable | None = None,
                            record: Callable | None = None,
                            poses: tuple | None = None) -> HexapodCalibration:
    """Drive, measure, identify and evaluate.

    Parameters
    ----------
    move_legs : callable (6,) -> (6,)
        Commands actuator lengths (m); returns the lengths the controller recorded.
    measure : callable () -> (6,)
        The pose sensor: measured platform pose (m, rad).
    progress : callable (step, total, message), optional
    record : callable (phase, target, leg_lengths, measured), optional
        Called for every stop, e.g. to write it to a bag.
    poses : (identification poses, evaluation poses), optional
        ``plan.poses(nominal)`` when already computed (it is deterministic).
    """
    targets, evaluation = plan.poses(nominal) if poses is None else poses
    identifiability(nominal, targets)
    total = plan.iterations * len(targets) + 2 * len(evaluation)
    rounds, history, geometry = [], [], nominal
    for k in range(plan.iterations):
        legs = compensate(geometry, targets)
        rounds.append(measure_poses(targets, legs, move_legs, measure, IDENTIFY_PHASE.format(k),
                                    record, progress, k * len(targets), total))
        identification, entry = _identify_round(rounds, geometry)
        history.append(entry)
        geometry = identification.geometry
    adaptive = None
    if plan.target_error > 0:
        adaptive = Adaptive(plan.target_error, plan.max_poses, plan.step, 'poses',
                            ' (the pose sensor\'s and actuators\' noise and the box decide it)')
        pool, working = plan.extension(nominal, np.vstack([targets, evaluation]))
    while adaptive is not None:
        measured = PoseData.concatenate(rounds).commanded
        now = predict(geometry, measured, working)['predicted_displacement_m']['rms']

        def extend(room, measured=measured, geometry=geometry):
            added, best = extend_poses(geometry, measured, pool, room, working)
            return added, best['predicted_displacement_m']['rms']
        more = adaptive.more(now, len(measured), extend)
        if more is None:
            break
        rounds.append(measure_poses(more, compensate(geometry, more), move_legs, measure,
                                    IDENTIFY_PHASE.format(len(rounds)), record, progress,
                                    len(measured), len(measured) + len(more) + 2 * len(evaluation)))
        identification, entry = _identify_round(rounds, geometry)
        history.append(entry)
        geometry = identification.geometry
        pool = other_than(pool, more)
    step = sum(len(r) for r in rounds)
    total = step + 2 * len(evaluation)
    before = measure_poses(evaluation, inverse_kinematics(nominal, evaluation), move_legs, measure,
                           EVALUATE_NOMINAL, record, progress, step, total)
    after = measure_poses(evaluation, compensate(geometry, evaluation), move_legs, measure,
                          EVALUATE_CALIBRATED, record, progress, step + len(evaluation), total)
    return HexapodCalibration(identification, {
        'nominal_geometry': nominal.as_dict(),
        'identification': identification.report(),
        'iterations': history,
        **({'adaptive': adaptive.report()} if adaptive is not None else {}),
        'evaluation': {'note': 'poses not used for fitting, measured by the pose sensor',
                       'before': summarise_pose_errors(before.commanded, before.measured),
                       'after': summarise_pose_errors(after.commanded, after.measured)},
    })


def identify_from_records(records: list[tuple], nominal: HexapodGeometry) -> tuple[
        Identification, list[dict]]:
    """Rerun the identification of a recorded run.

    ``records`` are (phase, target (6,), leg_lengths (6,), measured (6,)) in recorded order."""
    rounds: dict[int, list] = {}
    for phase, target, legs, measured in records:
        if phase.startswith('identify_'):
            rounds.setdefault(int(phase.split('_')[1]), []).append((target, legs, measured))
    if not rounds:
        raise CalibrationError('the records hold no identification poses')
    if sorted(rounds) != list(range(len(rounds))):
        raise CalibrationError(f'identification rounds {sorted(rounds)} are incomplete '
                               '(was the run interrupted?)')
    data = [PoseData(np.array([r[0] for r in rows]), np.array([r[2] for r in rows]),
                     np.array([r[1] for r in rows])) for _, rows in sorted(rounds.items())]
    return iterate_identification(data, nominal)
