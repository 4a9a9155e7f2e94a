"""Simulated XY-Theta alignment stage with the paper's error magnitudes.

The truth has every error source of :class:`StageGeometry` (lead ratios as identified in
the paper, alpha1 = 89.867 deg, input offsets, structural and angle errors, backlash per
chain) and a landing scatter per chain, so that the stage's repeatability is like the
paper's (3-6 um). The stage is mounted in the plate frame so that the two calibration
Marks on the platform lie under the camera gantry's travel, 3-4 mm and 0.3 deg away from
where the drawing puts it: together about 100-200 um of alignment error uncalibrated.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib_core.errors import InvalidInputError, OutOfTravelError
from calib_core.iso9283 import multidirectional_variation, pose_repeatability
from printer_alignment.core.alignment import plan_alignment, rigid_fit
from calib_core.marks import detect_marks
from printer_alignment.core.stage import (
    NOMINAL_D, NOMINAL_LEAD, STROKE, StageGeometry, check_stroke, landing_path, path_from_below,
    platform_points_in_plate)
from printer_alignment.core.stage_calibration import StageData, StagePlan
from printer_alignment.sim.camera import CameraSim
from printer_alignment.sim.scene import MarkSet, PlateMark

# Calibration Marks on the platform (platform frame, m): under the gantry at plate
# (40, 75) mm and (160, 75) mm when the stage is at home.
CALIBRATION_MARKS = np.array([[0.180, 0.130], [0.300, 0.130]])

TRUE_STAGE = StageGeometry(
    lead=(2.0064e-3, 2.0027e-3, 2.0021e-3), input_offset=(35e-6, -22e-6, 41e-6),
    d=(0.2688, 0.0387, 0.4326), link_difference=60e-6, beta=(1.2e-3, -0.6e-3, 0.9e-3),
    alpha1=np.deg2rad(89.867), alpha2=0.5e-3, backlash=(3.0e-6, 4.0e-6, 2.5e-6),
    stage2plate=(-0.1436, -0.0517, np.deg2rad(0.30)))


# Where the shipped stage's calibration Marks are taught (plate frame, m, stage at home):
# the stage calibrator's default ``calibration_marks``.
TAUGHT_MARKS = np.array([[0.0351, 0.0791], [0.1551, 0.0797]])


def described_home_marks(description) -> np.ndarray:
    """Where a user teaches the calibration Marks of the described stage (plate frame, m,
    (2, 2), stage at home) when the simulation mounts it (:func:`described_truth`): the
    described Marks about the shipped taught pair's centroid, turned as that pair is turned
    from the shipped Marks (for the shipped stage's description, :data:`TAUGHT_MARKS`)."""
    marks = np.asarray(description.marks, dtype=float)
    turn, _ = rigid_fit(CALIBRATION_MARKS, TAUGHT_MARKS)
    c, s = np.cos(turn), np.sin(turn)
    return (marks - marks.mean(axis=0)) @ np.array([[c, s], [-s, c]]) + TAUGHT_MARKS.mean(axis=0)


def described_truth(description, ideal: bool = False) -> StageGeometry:
    """A user's stage (a :class:`~printer_alignment.core.stage_description.
    StageDescription`) as the live simulation builds it: the shipped stage's errors
    (TRUE_STAGE's leads, offsets, angles, backlash, its guides as far off the drawing) on
    the described guides, mounted under the camera gantry as the shipped stage is: its
    Marks' centroid at home where the shipped stage's is, turned as the shipped stage is
    turned. ``ideal``: the described stage without errors, mounted where the Marks are
    taught (:func:`described_home_marks`). Deterministic, so the stage and the camera
    simulators build the same stage from the same file."""
    if ideal:
        return description.nominal(described_home_marks(description))
    off_drawing = np.asarray(TRUE_STAGE.d) - np.asarray(NOMINAL_D)
    unmounted = TRUE_STAGE.with_changes(d=tuple(np.asarray(description.d) + off_drawing),
                                        stage2plate=(0.0, 0.0, 0.0))
    shipped_home = platform_points_in_plate(
        TRUE_STAGE.stage_to_plate(TRUE_STAGE.forward(np.zeros((1, 3)))),
        CALIBRATION_MARKS)[0].mean(axis=0)
    home = unmounted.forward(np.zeros((1, 3)))
    centroid = platform_points_in_plate(home, description.marks)[0].mean(axis=0)
    turn = TRUE_STAGE.stage2plate[2]
    c, s = np.cos(turn), np.sin(turn)
    shift = shipped_home - np.array([[c, -s], [s, c]]) @ centroid
    return unmounted.with_changes(stage2plate=(float(shift[0]), float(shift[1]), turn))


def random_stage(seed: int, nominal_d=NOMINAL_D) -> StageGeometry:
    """A stage with its errors drawn afresh (sizes like TRUE_STAGE's): leads 0.2 %,
    offsets 40 um, guide places 1 mm about ``nominal_d`` (m), angles 0.5-2 mrad, backlash
    1-5 um, mounting 3 mm and 3 mrad (1 sigma, or the range)."""
    rng = np.random.default_rng(1000 + seed)
    return replace(
        TRUE_STAGE, lead=tuple(NOMINAL_LEAD * (1 + rng.normal(0, 2e-3, 3))),
        input_offset=tuple(rng.normal(0, 40e-6, 3)),
        d=tuple(np.asarray(nominal_d) + rng.normal(0, 1e-3, 3)),
        link_difference=float(rng.normal(0, 60e-6)), beta=tuple(rng.normal(0, 1e-3, 3)),
        alpha1=float(np.pi / 2 + rng.normal(0, 2e-3)), alpha2=float(rng.normal(0, 0.5e-3)),
        backlash=tuple(rng.uniform(1e-6, 5e-6, 3)),
        stage2plate=tuple(np.asarray(TRUE_STAGE.stage2plate) + rng.normal(0, 3e-3, 3)))


class StageSim:
    """The simulated stage: commanded inputs in, true platform pose out.

    Parameters
    ----------
    truth : StageGeometry
        The true geometry (sim only).
    landing_sigma : float
        Random landing error per chain and move, m (1 sigma): the stage's repeatability.
    seed : int
    screw : sequence of 3 float
        Each chain's lead-screw error once per turn, m (slider displacement
        a sin(2 pi q / lead)): an error the stage model does not declare.
    bow : sequence of 2 float
        The platform off by a bow over its travel in the plate frame, m at the stroke: x by
        ``bow[0] (dy / stroke)^2`` and y by ``bow[1] (dx / stroke)^2``, dx and dy the
        displacement of the calibration Marks' centroid (the place the loop's map is kept
        at) from where it is at zero inputs. An error the stage model does not declare.
    stroke : float
        Each input's limit either way, m; a move beyond it is refused.
    marks : (2, 2) array
        The calibration Marks on the platform (platform frame, m).
    """

    def __init__(self, truth: StageGeometry = TRUE_STAGE, landing_sigma: float = 1.2e-6,
                 seed: int | None = 0, screw=(0.0, 0.0, 0.0), bow=(0.0, 0.0),
                 stroke: float = STROKE, marks=CALIBRATION_MARKS):
        if not landing_sigma >= 0:
            raise InvalidInputError('landing_sigma must be >= 0')
        self.truth = truth
        self.stroke = stroke
        self.marks = np.asarray(marks, dtype=float)
        self.screw = np.asarray(screw, dtype=float)
        self.bow = np.asarray(bow, dtype=float)
        self._home = self._centroid(truth.stage_to_plate(truth.forward(np.zeros((1, 3))))[0])
        self.landing_sigma = landing_sigma
        self.rng = np.random.default_rng(seed)
        self.q = np.zeros(3)
        self.directions = np.ones(3)
        self._landing = np.zeros(3)

    def move(self, q) -> np.ndarray:
        """Move to inputs ``q`` (m, (3,)); refused (OutOfTravelError) outside the stroke.
        Returns the encoder reading (m, (3,)): the commanded input, exactly."""
        q = check_stroke(np.asarray(q, dtype=float).reshape(1, 3), self.stroke)[0]
        step = q - self.q
        moved = step != 0
        self.directions[moved] = np.sign(step[moved])
        self._landing[moved] = self.rng.normal(0.0, self.landing_sigma, moved.sum())
        self.q = q
        return self.q.copy()

    def true_pose(self) -> np.ndarray:
        """Platform pose in the plate frame (x m, y m, theta rad). Truth: sim only."""
        lead_ratio = np.asarray(self.truth.lead) / NOMINAL_LEAD
        # A landing error is a slider displacement; as an input it is divided by the ratio.
        turn = 2 * np.pi * self.q / np.asarray(self.truth.lead)
        q_effective = self.q + (self._landing + self.screw * np.sin(turn)) / lead_ratio
        pose = self.truth.stage_to_plate(
            self.truth.forward(q_effective[None], self.directions[None]))[0]
        dx, dy = (self._centroid(pose) - self._home) / self.stroke
        return pose + np.array([self.bow[0] * dy ** 2, self.bow[1] * dx ** 2, 0.0])

    def _centroid(self, pose) -> np.ndarray:
        """The calibration Marks' centroid in the plate frame (m, (2,)) at platform ``pose``."""
        return platform_points_in_plate(pose[None], self.marks.mean(axis=0)[None])[0, 0]

    def true_points(self, platform_points) -> np.ndarray:
        """Plate positions (m, (k, 2)) of platform-frame points ((k, 2)). Truth: sim only."""
        return platform_points_in_plate(self.true_pose()[None], platform_points)[0]


def measure_marks(stage: StageSim, platform_points=CALIBRATION_MARKS, noise: float = 0.3e-6,
                  rng: np.random.Generator | None = None) -> np.ndarray:
    """Camera measurement of Marks on the platform (m, (k, 2)) with Gaussian ``noise`` (m,
    1 sigma per coordinate): the camera's centre error at 1/50 px."""
    rng = rng or np.random.default_rng()
    points = stage.true_points(platform_points)
    return points + rng.normal(0.0, noise, points.shape)


# Substrate fiducials (platform frame, m) as designed; each load adds a fixing error.
SUBSTRATE_MARKS = np.array([[0.185, 0.115], [0.295, 0.145]])


def approach_from_below(stage: StageSim, q) -> np.ndarray:
    """Move to ``q`` with the last motion of every chain upwards
    (:func:`~printer_alignment.core.stage.path_from_below`)."""
    before, target = path_from_below(q)
    stage.move(before)
    return stage.move(target)


def evaluate_alignment(model, truth: StageGeometry = TRUE_STAGE, poses: int = 8,
                       repeats: int = 5, landing_sigma: float = 1.2e-6,
                       camera_noise: float = 0.3e-6, fixing_error=(200e-6, np.deg2rad(0.05)),
                       reach: float = 4e-3, seed: int = 0) -> dict:
    """The paper's evaluation: ``poses`` random target poses across the workspace, each
    aligned ``repeats`` times with the substrate fixed again (random shift and rotation of
    ``fixing_error`` (m, rad) 1 sigma). Each alignment measures the substrate Marks at home,
    plans with ``model``, moves once (approached from below) and compares the true
    substrate Marks with the stencil Marks.

    Loads that would need an input beyond the stroke are refused and counted.
    Returns a dict with the max and mean of, per alignment, the position error of the
    Marks' centroid (m), the orientation error (rad) and the larger of the two Marks'
    errors (m); and the position and orientation errors themselves (arrays).
    """
    rng = np.random.default_rng(seed)
    stage = StageSim(truth, landing_sigma, seed=seed + 1)
    position, orientation, mark_error = [], [], []
    refused = 0
    for _ in range(poses):
        q_goal = rng.uniform(-reach, reach, 3)
        goal_pose = truth.stage_to_plate(truth.forward(q_goal[None], np.ones((1, 3))))
        stencil = platform_points_in_plate(goal_pose, SUBSTRATE_MARKS)[0]
        for _ in range(repeats):
            shift = rng.normal(0, fixing_error[0], 2)
            turn = rng.normal(0, fixing_error[1])
            c, s = np.cos(turn), np.sin(turn)
            substrate = SUBSTRATE_MARKS @ np.array([[c, s], [-s, c]]) + shift
            approach_from_below(stage, np.zeros(3))
            measured = stage.true_points(substrate) + rng.normal(0, camera_noise, (2, 2))
            try:
                plan = plan_alignment(model, stage.q, measured, stencil)
            except OutOfTravelError:
                refused += 1    # the load put the target beyond the stroke: not moved
                continue
            approach_from_below(stage, plan.q)
            reached = stage.true_points(substrate)
            angle, _ = rigid_fit(stencil, reached)
            position.append(np.linalg.norm(reached.mean(axis=0) - stencil.mean(axis=0)))
            orientation.append(abs(angle))
            mark_error.append(np.max(np.linalg.norm(reached - stencil, axis=1)))
    position, orientation, mark_error = map(np.array, (position, orientation, mark_error))
    return {'alignments': int(len(position)), 'refused_outside_workspace': refused,
            'position_max_m': float(position.max()), 'position_mean_m': float(position.mean()),
            'orientation_max_rad': float(orientation.max()),
            'orientation_mean_rad': float(orientation.mean()),
            'mark_error_max_m': float(mark_error.max()),
            'mark_error_mean_m': float(mark_error.mean()),
            'position_m': position, 'orientation_rad': orientation}


def camera_pose_sensor(stage: StageSim, platform_points=CALIBRATION_MARKS, seed: int = 0):
    """A function that measures the platform's plate pose (x, y m of the Marks' centroid,
    theta rad) through the simulated camera: it renders each Mark with a camera parked
    above its home position, detects it and converts pixels with the camera's scale."""
    parked = stage.true_points(platform_points)
    camera = CameraSim(None, seed=seed)
    c2p = camera.optics.camera2plate

    def measure() -> np.ndarray:
        points = stage.true_points(platform_points)
        found = []
        for park, point in zip(parked, points):
            camera.scene = MarkSet((PlateMark('circle', *point, 0.5e-3),))
            detection = detect_marks(camera.capture(park), shape='circle', expected_count=1)
            found.append(park + c2p.offset([[detection.marks[0].u, detection.marks[0].v]])[0])
        found = np.array(found)
        gap = found[1] - found[0]
        return np.array([*found.mean(axis=0), np.arctan2(gap[1], gap[0])])
    return measure


def measure_repeatability(truth: StageGeometry = TRUE_STAGE, q=(1e-3, -1.5e-3, 2e-3),
                          cycles: int = 30, landing_sigma: float = 1.2e-6,
                          offset: float = 0.5e-3, seed: int = 0) -> dict:
    """ISO 9283 pose repeatability of the simulated stage at inputs ``q`` (m), measured
    through the camera: ``cycles`` visits from a start ``offset`` (m) below on every
    chain (unidirectional), then the same from above and from a mixed start
    (multi-directional)."""
    q = np.asarray(q, dtype=float)
    stage = StageSim(truth, landing_sigma, seed=seed)
    stage.move(q)
    measure = camera_pose_sensor(stage, seed=seed + 1)
    groups = []
    for sign in (np.array([-1, -1, -1]), np.array([1, 1, 1]), np.array([-1, 1, -1])):
        poses = []
        for _ in range(cycles):
            stage.move(q + sign * offset)
            stage.move(q)
            poses.append(measure())
        poses = np.array(poses)
        groups.append((poses[:, :2], poses[:, 2]))
    unidirectional = pose_repeatability(*groups[0])
    pooled = pose_repeatability(np.vstack([g[0] for g in groups]),
                                np.concatenate([g[1] for g in groups]))
    return {'unidirectional': unidirectional, 'multidirectional': pooled,
            'variation': multidirectional_variation(groups), 'q_m': q.tolist()}


def simulate_calibration_run(truth: StageGeometry = TRUE_STAGE, plan=None,
                             landing_sigma: float = 1.2e-6, camera_noise: float = 0.3e-6,
                             seed: int = 0, screw=(0.0, 0.0, 0.0), bow=(0.0, 0.0),
                             stroke: float = STROKE, marks=CALIBRATION_MARKS):
    """The calibration run of ``plan`` (default :class:`StagePlan` in the ``stroke``, m) on
    a simulated stage, its calibration ``marks`` (2, 2) (platform frame, m) measured by a
    camera with ``camera_noise`` (m, 1 sigma): a
    :class:`~printer_alignment.core.stage_calibration.StageData`. Every chain lands afresh
    at each target with a short last motion in its direction of travel
    (:func:`~printer_alignment.core.stage.landing_path`), so the sweeps approach from both
    directions. ``screw`` and ``bow``: see :class:`StageSim`."""
    plan = plan or StagePlan(stroke=stroke)
    stage = StageSim(truth, landing_sigma, seed=seed, screw=screw, bow=bow, stroke=stroke,
                     marks=marks)
    rng = np.random.default_rng(seed + 1)
    targets = plan.targets()
    marks_seen, directions = [], []
    for q in targets:
        for waypoint in landing_path(stage.q, q, stage.directions, stroke=stroke):
            stage.move(waypoint)
        marks_seen.append(measure_marks(stage, stage.marks, camera_noise, rng))
        directions.append(stage.directions.copy())
    return StageData(targets, np.array(directions), np.array(marks_seen))
