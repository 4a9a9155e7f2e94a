"""The 3-PRR screen-registration platform without ROS (issue 22): kinematics round trip
and Jacobians against finite differences, the 18 parameters recovered against the
simulation's truth (noise-free exactly from 6 poses, with noise within 3 sigma),
compensation by the exact inverse, Levenberg-Marquardt and the source's particle swarm,
and bad input refused."""
import json

import numpy as np
import pytest

from calib_core.errors import CalibrationError, InvalidInputError
from platform_calib.core.compensation import PSOSettings, compensate, composite_error
from platform_calib.core.geometry import nominal_geometry, parameter_names
from platform_calib.core.identification import PoseData, identify
from platform_calib.core.kinematics import (
    feed_jacobian, forward, inverse, parameter_jacobian)
from platform_calib.errors import WorkspaceError
from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry

NOMINAL = nominal_geometry()
TOLERANCE = {'round_trip': 1e-12, 'jacobian': 1e-8, 'noise_free': 1e-9, 'sigmas': 3.0}


def test_inverse_and_forward_round_trip():
    poses = plan_poses(50, seed=1)
    for geometry in (NOMINAL, true_geometry(2)):
        assert np.abs(forward(geometry, inverse(geometry, poses)) - poses).max() < \
            TOLERANCE['round_trip']


def test_jacobians_match_finite_differences():
    geometry, poses = true_geometry(3), plan_poses(8, seed=3)
    feeds = inverse(geometry, poses)
    analytic = parameter_jacobian(geometry, poses, feeds)
    v, h = geometry.vector(), 1e-7
    for k in range(18):
        up, down = v.copy(), v.copy()
        up[k] += h
        down[k] -= h
        numeric = (forward(geometry.with_vector(up), feeds, poses)
                   - forward(geometry.with_vector(down), feeds, poses)) / (2 * h)
        assert np.abs(analytic[:, :, k] - numeric).max() < TOLERANCE['jacobian'], parameter_names()[k]
    by_feed = feed_jacobian(geometry, poses, feeds)
    for i in range(3):
        up, down = feeds.copy(), feeds.copy()
        up[:, i] += h
        down[:, i] -= h
        numeric = (forward(geometry, up, poses) - forward(geometry, down, poses)) / (2 * h)
        assert np.abs(by_feed[:, :, i] - numeric).max() < TOLERANCE['jacobian']


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_noise_free_six_poses_recover_all_18_parameters(seed):
    truth = true_geometry(seed)
    sim = PlatformSim(truth, seed, feed_noise=0.0, tracker_noise=(0.0, 0.0, 0.0))
    result = identify(measure_poses(sim, plan_poses(6, seed), NOMINAL), NOMINAL)
    assert np.abs(result.geometry.vector() - truth.vector()).max() < TOLERANCE['noise_free']


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_with_noise_every_parameter_lies_within_three_sigma(seed):
    truth = true_geometry(seed)
    result = identify(measure_poses(PlatformSim(truth, seed), plan_poses(30, seed), NOMINAL),
                      NOMINAL)
    z = (result.geometry.vector() - truth.vector()) / result.std_devs
    assert np.abs(z).max() < TOLERANCE['sigmas'], dict(zip(parameter_names(), z))


def test_too_few_or_degenerate_poses_are_refused_with_the_parameters_named():
    sim = PlatformSim(true_geometry(1), 1)
    with pytest.raises(CalibrationError, match='at least 6 poses'):
        identify(measure_poses(sim, plan_poses(5, 1), NOMINAL), NOMINAL)
    same = np.repeat(plan_poses(1, 1), 8, axis=0)
    with pytest.raises(CalibrationError, match=r'do not determine chain 1: .*x_A1'):
        identify(measure_poses(sim, same, NOMINAL), NOMINAL)
    data = measure_poses(sim, plan_poses(8, 1), NOMINAL)
    with pytest.raises(InvalidInputError, match='NaN'):
        PoseData(data.poses * np.nan, data.feeds)


def test_targets_outside_the_workspace_or_stroke_are_refused():
    with pytest.raises(WorkspaceError, match='outside the stroke'):
        inverse(NOMINAL, [[0.03, 0.0, 0.0]])
    with pytest.raises(WorkspaceError, match='cannot reach'):
        inverse(NOMINAL, [[0.0, 0.0, np.deg2rad(60)]], check=False)
    # Feeds whose only closure lies on the other branch (the link folded back).
    folded = inverse(NOMINAL, [[0.0, 0.0, 0.0]], check=False)
    folded[0, 0] += 2 * NOMINAL.length[0]
    with pytest.raises(WorkspaceError, match='other branch|no pose closes'):
        forward(NOMINAL, folded)
    sim = PlatformSim(NOMINAL)
    before = sim.pose.copy()
    with pytest.raises(WorkspaceError):
        sim.move([0.05, 0.02, 0.02])
    assert np.array_equal(sim.pose, before)


def test_compensation_exact_and_lm_reach_the_floor_the_source_swarm_does_not_converge():
    truth = true_geometry(4, scale=0.15)
    model = identify(measure_poses(PlatformSim(truth, 4), plan_poses(30, 4), NOMINAL),
                     NOMINAL).geometry
    target = np.array([2e-3, -1e-3, np.deg2rad(3.0)])
    before = composite_error(forward(truth, inverse(NOMINAL, target[None]), target[None]),
                             target[None])[0]
    after = {}
    for method, pso in (('exact', None), ('lm', None), ('pso', PSOSettings.source(1)),
                        ('pso-stable', PSOSettings.stable(1))):
        result = compensate(model, NOMINAL, target, method.split('-')[0],
                            pso=pso or PSOSettings())
        after[method] = composite_error(forward(truth, result.feeds[None], target[None]),
                                        target[None])[0]
        if method == 'pso':
            assert not result.converged and 'not converged' in result.message
        if method == 'pso-stable':
            assert result.converged, result.message
    assert before > 0.2e-3
    assert after['exact'] < 0.05 * before
    assert abs(after['lm'] - after['exact']) < 1e-9
    assert after['pso'] > 10 * after['exact']
    assert abs(after['pso-stable'] - after['exact']) < 1e-6
    assert not PSOSettings.source().order2_stable() and PSOSettings.stable().order2_stable()


def test_pose_csv_round_trip(tmp_path):
    data = measure_poses(PlatformSim(true_geometry(5), 5), plan_poses(7, 5), NOMINAL)
    path = tmp_path / 'poses.csv'
    data.to_csv(path)
    back = PoseData.from_csv(path)
    assert np.allclose(back.poses, data.poses, atol=1e-15) and np.allclose(back.feeds, data.feeds)
    path.write_text('feed1,feed2\n1,2\n')
    with pytest.raises(InvalidInputError, match='lacks column.*feed3, x, y, theta'):
        PoseData.from_csv(path)


def test_command_line_simulate_calibrate_compensate(tmp_path, capsys):
    """The three subcommands chain on files; an unconverged swarm is reported and exits 2
    so a script does not use its feeds."""
    from machine_alignment.cli import main
    poses, geometry = tmp_path / 'poses.csv', tmp_path / 'identified.yaml'
    assert main(['simulate', 'platform', '--out', str(poses), '--poses', '12', '--seed', '3']) == 0
    assert main(['calibrate', 'platform', '--data', str(poses), '--out', str(geometry)]) == 0
    assert main(['compensate', 'platform', '--geometry', str(geometry), '--count', '4',
                 '--json', str(tmp_path / 'exact.json'), '--csv', str(tmp_path / 'feeds.csv')]) == 0
    assert (tmp_path / 'exact.png').exists()
    # The feeds per target as a labelled table, the same values as the report's.
    header = (tmp_path / 'feeds.csv').read_text().splitlines()[0]
    assert header == 'x_m,y_m,theta_rad,feed1_m,feed2_m,feed3_m,converged'
    table = np.loadtxt(tmp_path / 'feeds.csv', delimiter=',', skiprows=1)
    report = json.loads((tmp_path / 'exact.json').read_text())
    np.testing.assert_allclose(table[:, 3:6], [t['feeds_m'] for t in report['targets']],
                               rtol=1e-11)
    capsys.readouterr()
    assert main(['compensate', 'platform', '--geometry', str(geometry), '--count', '2',
                 '--method', 'pso']) == 2
    assert 'NOT CONVERGED' in capsys.readouterr().out
    assert main(['compensate', 'platform', '--geometry', str(geometry), '--count', '2',
                 '--method', 'pso', '--swarm', 'stable']) == 0
    short = tmp_path / 'short.csv'
    short.write_text('\n'.join(poses.read_text().splitlines()[:5]) + '\n')
    assert main(['calibrate', 'platform', '--data', str(short)]) == 2
    assert 'at least 6 poses' in capsys.readouterr().err


def test_registration_puts_the_marks_on_target_and_refuses_a_bad_swarm():
    """With the true model and a noise-free camera the marks land on their targets to
    1e-9 m from any screen mounting; marks that are not the screen's and an unconverged
    swarm are refused, and the platform does not move."""
    from platform_calib.core.compensation import mark_positions
    from platform_calib.core.registration import compose, pose_of_marks, register
    truth = true_geometry(6, scale=0.2)
    sim = PlatformSim(truth, 6)
    screen = np.array([0.8e-3, -0.5e-3, np.deg2rad(0.2)])
    targets = mark_positions(np.zeros((1, 3)))[0]

    def seen():
        return mark_positions(compose(sim.pose, screen)[None])[0]
    assert np.allclose(pose_of_marks(seen()), compose(sim.pose, screen), atol=1e-12)
    register(truth, NOMINAL, sim.feeds, seen, sim.move, targets)
    assert np.abs(seen() - targets).max() < 1e-9
    before = sim.pose.copy()
    with pytest.raises(InvalidInputError, match='apart'):
        register(truth, NOMINAL, sim.feeds, lambda: seen() * 1.1, sim.move, targets)
    with pytest.raises(InvalidInputError, match='did not converge.*not moved'):
        register(truth, NOMINAL, sim.feeds, seen, sim.move, targets, 'pso',
                 pso=PSOSettings.source())
    assert np.array_equal(sim.pose, before)
