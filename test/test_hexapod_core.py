"""Hexapod kinematics, identification and the calibration run on the simulator (no ROS)."""
import dataclasses
import re

import numpy as np
import pytest

from calib_core.errors import CalibrationError, InvalidInputError, OutOfTravelError
from hexapod_calib.core.calibration import (
    PoseData, identifiability, identification_jacobian, identification_residuals, identify,
    pose_errors, select_poses)
from hexapod_calib.core.geometry import (
    HexapodGeometry, nominal_geometry, read_geometry, write_geometry)
from hexapod_calib.core.kinematics import (
    condition_numbers, forward_kinematics, inverse_kinematics, jacobian)
from hexapod_calib.core.procedure import HexapodPlan, identify_from_records, run_hexapod_calibration
from hexapod_calib.core.statics import leg_forces
from hexapod_calib.errors import ConvergenceError, SingularPoseError
from hexapod_calib.sim.hexapod import HexapodSim, HexapodTruth, PoseSensorSim, true_geometry

NOMINAL = nominal_geometry()
# The paper's results after calibration (0.35 mm / 0.0073 rad before).
PAPER_MAX_DISPLACEMENT = 0.0121e-3
PAPER_MAX_ANGLE = 0.0011


def random_poses(rng, n, translation=0.02, rotation=0.1):
    return np.column_stack([rng.uniform(-translation, translation, (n, 3)) + [0, 0, 0.2],
                            rng.uniform(-rotation, rotation, (n, 3))])


def test_forward_kinematics_inverts_inverse_kinematics(rng):
    poses = random_poses(rng, 200)
    solved = forward_kinematics(NOMINAL, inverse_kinematics(NOMINAL, poses))
    assert np.max(np.abs(solved - poses)) < 1e-12


def test_jacobian_matches_finite_differences(rng):
    pose = random_poses(rng, 1)[0]
    step = 1e-7
    numeric = np.zeros((6, 6))
    for k in range(6):
        twist = np.zeros(6)
        twist[k] = step
        # A small rotation about base axis k applied on the left of R.
        from scipy.spatial.transform import Rotation
        moved = pose.copy()
        moved[:3] += twist[:3]
        moved[3:] = (Rotation.from_rotvec(twist[3:]) * Rotation.from_euler('xyz', pose[3:])).as_euler('xyz')
        numeric[:, k] = (inverse_kinematics(NOMINAL, moved) - inverse_kinematics(NOMINAL, pose))[0] / step
    assert np.allclose(jacobian(NOMINAL, pose)[0], numeric, atol=1e-6)


def test_identification_jacobian_matches_finite_differences(rng):
    poses = random_poses(rng, 5)
    data = PoseData(poses, poses, inverse_kinematics(NOMINAL, poses) + rng.normal(0, 1e-4, (5, 6)))
    params = NOMINAL.parameters()
    analytic = identification_jacobian(NOMINAL, data)
    base = identification_residuals(NOMINAL, data).ravel()
    for k, name in enumerate(params.names):
        vector = params.free_vector()
        vector[k] += 1e-7
        moved = HexapodGeometry.from_parameters(params.with_free_vector(vector))
        numeric = (identification_residuals(moved, data).ravel() - base) / 1e-7
        assert np.allclose(analytic[:, k], numeric, atol=1e-6), name


def test_forward_kinematics_fails_clearly_on_unrealisable_lengths():
    with pytest.raises(ConvergenceError, match='may not be realisable'):
        forward_kinematics(NOMINAL, [0.2, 0.2, 0.2, 0.2, 0.2, 0.9])


def test_singular_pose_is_detected():
    # Rotating the platform by 90 deg about z puts every leg nearly in one plane.
    pose = np.array([0, 0, 0.2, 0, 0, np.radians(90)])
    assert condition_numbers(NOMINAL, pose)[0] > 1000
    with pytest.raises(SingularPoseError):
        forward_kinematics(NOMINAL, inverse_kinematics(NOMINAL, pose), initial=pose)


def test_leg_forces_balance_the_payload(rng):
    poses = random_poses(rng, 10)
    forces = leg_forces(NOMINAL, poses, 25.0, (0.03, -0.02, 0.08))
    units = jacobian(NOMINAL, poses)[:, :, :3]
    total = np.einsum('ni,nij->nj', forces, units)
    assert np.allclose(total, [0, 0, 25.0 * 9.81], atol=1e-9)


def test_identification_recovers_all_42_parameters_from_exact_data(rng):
    truth = true_geometry(NOMINAL, seed=3)
    poses = random_poses(rng, 30)
    data = PoseData(poses, poses, inverse_kinematics(truth, poses))
    result = identify(data, NOMINAL)
    for name, value in truth.parameters().as_dict().items():
        assert result.geometry.parameters()[name] == pytest.approx(value, abs=2e-9), name


def test_too_few_poses_and_degenerate_pose_sets_are_refused(rng):
    truth = true_geometry(NOMINAL, seed=3)
    poses = random_poses(rng, 6)
    with pytest.raises(CalibrationError, match='6 poses give 36 equations for 42'):
        identify(PoseData(poses, poses, inverse_kinematics(truth, poses)), NOMINAL)
    # Pure translations cannot tell a base joint from a platform joint.
    translations = random_poses(rng, 40, rotation=0.0)
    with pytest.raises(CalibrationError, match=r'cannot separate parameters (base|platform)\d_[xyz] '
                                               r'and (base|platform)\d_[xyz]'):
        identifiability(NOMINAL, translations)
    with pytest.raises(CalibrationError, match='cannot separate'):
        identify(PoseData(translations, translations, inverse_kinematics(truth, translations)),
                 NOMINAL)


def test_nan_in_pose_data_is_refused(rng):
    poses = random_poses(rng, 20)
    measured = poses.copy()
    measured[3, 2] = np.nan
    with pytest.raises(InvalidInputError, match='NaN'):
        PoseData(poses, measured, inverse_kinematics(NOMINAL, poses))


def test_pose_selection_conditions_the_identification_better_than_random(rng):
    candidates = random_poses(rng, 400)
    chosen = select_poses(NOMINAL, candidates, 13)
    assert len(set(chosen.tolist())) == 13
    selected = identifiability(NOMINAL, candidates[chosen])
    randomly = np.median([identifiability(NOMINAL, candidates[rng.choice(400, 13, replace=False)])
                          for _ in range(10)])
    assert selected < 0.75 * randomly


def test_simulated_hexapod_refuses_moves_outside_the_stroke():
    sim = HexapodSim()
    before = sim.pose.copy()
    with pytest.raises(OutOfTravelError, match='leg 1 length'):
        sim.move_legs([0.35, 0.22, 0.22, 0.22, 0.22, 0.22])
    with pytest.raises(OutOfTravelError, match='singularity'):
        sim.move_pose([0, 0, 0.2, 0, 0, np.radians(90)])
    assert np.array_equal(sim.pose, before)


def test_calibration_run_beats_the_paper_and_recovers_the_truth():
    """True errors of a few tenths of a mm, 8.3-9.9 um play per leg, 0.5 um actuator noise,
    0.6 um / 6 urad sensor noise; 30 selected poses, two rounds, 30 separate poses."""
    truth = HexapodTruth.default(NOMINAL, seed=2)
    sim, sensor = HexapodSim(truth, seed=4), PoseSensorSim(seed=5)
    records = []
    calibration = run_hexapod_calibration(
        HexapodPlan(), NOMINAL, sim.move_legs, lambda: sensor.measure(sim.pose),
        record=lambda *r: records.append(r))
    before, after = calibration.report['evaluation']['before'], calibration.report['evaluation']['after']
    assert before['max_displacement_m'] > 0.2e-3        # an uncalibrated machine is far off
    assert after['max_displacement_m'] < PAPER_MAX_DISPLACEMENT
    assert after['max_angle_rad'] < PAPER_MAX_ANGLE / 5
    report = calibration.report['identification']
    z = [(report['parameters'][k] - v) / report['std_devs'][k]
         for k, v in truth.geometry.parameters().as_dict().items()]
    assert np.mean(np.abs(z) < 3) >= 0.9
    # Single joint coordinates along a leg trade off against its offset (large sigma); the
    # leg lengths the model predicts over the workspace are what must be right. Where a
    # leg's load closes its play, the play shifts that leg by a constant half play.
    poses = random_poses(np.random.default_rng(9), 500)
    force = leg_forces(truth.geometry, poses, truth.payload_mass, truth.payload_centre)
    loaded = np.all(np.abs(force) > truth.force_to_close_play, axis=1)
    needed = inverse_kinematics(truth.geometry, poses) + 0.5 * truth.leg_play * np.sign(force)
    predicted = inverse_kinematics(calibration.geometry, poses)
    assert loaded.mean() > 0.5
    difference = (predicted - needed)[loaded]
    # Legs whose load changes sign take their play from side to side, which the 42
    # parameters cannot follow: up to one play (< 10 um) there, about 1 um elsewhere.
    assert np.sqrt(np.mean(difference ** 2)) < 2e-6
    assert np.max(np.abs(difference)) < 10e-6
    assert np.max(np.abs(inverse_kinematics(NOMINAL, poses)
                         - inverse_kinematics(truth.geometry, poses))) > 0.3e-3
    replayed, _ = identify_from_records(records, NOMINAL)
    assert replayed.geometry.parameters().as_dict() == report['parameters']


@pytest.mark.parametrize('overrides, message', [
    ({'num_poses': 2.5}, 'num_poses must be an integer from 1 to'),
    ({'num_poses': 'many'}, 'num_poses must be an integer'),
    ({'translation': [0.01, 0.01]}, 'translation must be 3 finite numbers'),
    ({'stroke': [0.3, 0.2]}, 'stroke (min, max) increasing'),
    ({'num_poses': 300, 'num_evaluation': 200}, 'num_candidates must be at least'),
    ({'rotation_speed': 1}, 'unknown plan keys'),
])
def test_bad_plans_are_refused(overrides, message):
    with pytest.raises(InvalidInputError, match=re.escape(message)):
        HexapodPlan.from_mapping(overrides)


def test_plan_outside_the_stroke_is_refused_before_moving():
    with pytest.raises(InvalidInputError, match='inside the stroke'):
        HexapodPlan(home=(0, 0, 0.45, 0, 0, 0)).poses(NOMINAL)


def test_geometry_yaml_round_trip_and_malformed_files(tmp_path):
    truth = true_geometry(NOMINAL)
    write_geometry(tmp_path / 'g.yaml', truth)
    assert read_geometry(tmp_path / 'g.yaml').parameters().as_dict() == truth.parameters().as_dict()
    (tmp_path / 'bad.yaml').write_text('base_joints: [[0, 0, 0]]\nplatform_joints: []\n')
    with pytest.raises(InvalidInputError, match=r'base_joints must have shape \(6, 3\)'):
        read_geometry(tmp_path / 'bad.yaml')
    (tmp_path / 'broken.yaml').write_text('base_joints: [[0, 0\n')
    with pytest.raises(InvalidInputError, match='not valid YAML'):
        read_geometry(tmp_path / 'broken.yaml')
    with pytest.raises(InvalidInputError, match='no such file'):
        read_geometry(tmp_path / 'missing.yaml')


def test_pose_errors_measure_displacement_and_angle():
    target = np.array([[0, 0, 0.2, 0, 0, 0]])
    actual = np.array([[3e-6, 4e-6, 0.2, 0, 0, 1e-4]])
    displacement, angle = pose_errors(target, actual)
    assert displacement[0] == pytest.approx(5e-6)
    assert angle[0] == pytest.approx(1e-4)


def _adaptive_run(target: float, max_poses: int):
    """13 greedy poses measured twice, then adaptive rounds of 4 on a hexapod without play
    (the effect the 42 parameters lack is the closed loop's)."""
    truth = dataclasses.replace(HexapodTruth.default(NOMINAL, seed=2), leg_play=np.zeros(6))
    sim, sensor = HexapodSim(truth, seed=4), PoseSensorSim(seed=5)
    records = []
    calibration = run_hexapod_calibration(
        HexapodPlan(num_poses=13, num_evaluation=10, target_error=target, max_poses=max_poses),
        NOMINAL, sim.move_legs, lambda: sensor.measure(sim.pose),
        record=lambda *r: records.append(r))
    return calibration, records


def test_adaptive_rounds_add_poses_until_the_predicted_displacement_meets_the_target():
    """From 26 pose measurements predicted 1.27 um to 1.2 um: rounds of 4 new poses of the
    box, each predicting less, recorded as further rounds of the iteration, which the
    replay of the records identifies to the same geometry."""
    calibration, records = _adaptive_run(1.2e-6, 80)
    adaptive = calibration.report['adaptive']
    assert adaptive['stopped'] == 'target met'
    counts = [r['poses'] for r in adaptive['rounds']]
    assert counts[0] == 26 and np.all(np.diff(counts) == 4) and len(counts) > 1
    predicted = [r['predicted_rms_m'] for r in adaptive['rounds']]
    assert all(b < a for a, b in zip(predicted, predicted[1:]))
    assert predicted[-1] <= 1.2e-6 < predicted[-2]
    assert len({tuple(r[1]) for r in records if r[0].startswith('identify_')}) == counts[-1] - 13
    replayed, _ = identify_from_records(records, NOMINAL)
    assert replayed.geometry.parameters().as_dict() == \
        calibration.report['identification']['parameters']


def test_adaptive_rounds_say_when_the_box_cannot_meet_the_target():
    calibration, _ = _adaptive_run(0.5e-6, 60)
    adaptive = calibration.report['adaptive']
    assert adaptive['stopped'].startswith('target cannot be met within max_poses = 60')
    assert adaptive['rounds'][-1]['best_at_max_poses_m'] > 0.5e-6
    assert [r['poses'] for r in adaptive['rounds']] == [26]
    with pytest.raises(InvalidInputError, match='target_error'):
        HexapodPlan(target_error=5.0)
