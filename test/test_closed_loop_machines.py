"""The closed loop on the gantry, the camera (simulated and real photos) and the hexapod:
the undeclared effect is named and recovered, clean data get nothing."""
import dataclasses
import json

import numpy as np
import pytest

from machine_alignment.cli import main as cli_main
from calib_core.closed_loop import LoopConfig, analyze
from hexapod_calib.core.geometry import nominal_geometry, write_geometry
from hexapod_calib.core.loop_models import HexapodLoopModel
from hexapod_calib.sim.hexapod import TALL_PAYLOAD_CENTRE, HexapodTruth, measure_random_poses
from printer_alignment.core.camera_calibration import views_from_images
from printer_alignment.core.loop_models import (
    CameraLoopModel, GantryData, GantryLoopModel, StageLoopModel)
from printer_alignment.sim.camera import tilted_plate_views
from printer_alignment.sim.gantry import GantryErrors, measure_random_positions

GANTRY_NOISE = 0.3e-6          # m per coordinate
CAMERA_NOISE = 0.05            # px per coordinate
CAMERA = np.array([[800.0, 0, 322], [0, 805, 236], [0, 0, 1]])


def _added(report):
    return {e['name']: e for e in report['effects_added']}


def test_gantry_backlash_screw_error_and_squareness_found():
    truth = GantryErrors()
    report = analyze(GantryLoopModel(measure_random_positions(truth, noise=GANTRY_NOISE, seed=1))).report
    effects = _added(report)
    assert set(effects) == {'squareness', 'reversal', 'periodic'}
    # Tolerance table: recovered against the simulation's truth.
    backlash = effects['reversal']['parameters']
    assert backlash['backlash_x'] == pytest.approx(truth.backlash_x, abs=0.3e-6)
    assert backlash['backlash_y'] == pytest.approx(truth.backlash_y, abs=0.3e-6)
    assert effects['squareness']['parameters']['gamma'] == pytest.approx(
        -truth.model.non_orthogonality, abs=5e-6)
    periodic = effects['periodic']['parameters']
    assert periodic['period_x'] == pytest.approx(0.016, abs=0.05e-3)   # one screw revolution
    assert periodic['period_y'] == pytest.approx(0.040, abs=0.2e-3)
    assert np.hypot(periodic['cos_x'], periodic['sin_x']) == pytest.approx(1.5e-6, abs=0.2e-6)
    floor = np.sqrt(2) * GANTRY_NOISE
    assert report['rms_before'] > 5 * floor
    assert report['rms_after'] < 1.3 * floor


def test_gantry_clean_data_get_nothing():
    for seed in range(5):
        report = analyze(GantryLoopModel(measure_random_positions(
            GantryErrors.ideal(), noise=GANTRY_NOISE, seed=10 + seed))).report
        assert report['effects_added'] == [] and report['unexplained'] == []


def test_gantry_screws_growing_with_the_shop_temperature_are_found_and_kept_out_of_force():
    """Screws of 11.5 ppm/K (steel) in a shop cycling by +-1 K over 30 min, 200 positions
    10 s apart with time and temperature logged: the loop adds the thermal expansion (the
    carriage runs ahead of the command by k dT x), not a drift in time, and says it
    describes the run, not the machine (it must not be put in force). On the same machine
    at a steady temperature it adds no drift."""
    from calib_core.closed_loop import why_not_in_force
    from printer_alignment.sim.gantry import MachineTemperature
    expansion = 11.5e-6
    truth = dataclasses.replace(GantryErrors.ideal(), screw_expansion=expansion)
    shop = MachineTemperature(cycle_amplitude=1.0, cycle_period=1800.0)
    report = analyze(GantryLoopModel(measure_random_positions(
        truth, noise=GANTRY_NOISE, seed=4, temperature=shop))).report
    effects = _added(report)
    assert set(effects) == {'drift_temperature'}
    fitted = effects['drift_temperature']
    for axis in ('x', 'y'):
        error = fitted['parameters'][f'expansion_{axis}'] - expansion
        assert abs(error) < 4 * fitted['std_devs'][f'expansion_{axis}'], fitted
    assert 'drift_temperature' in why_not_in_force(report['effects_added'])
    steady = analyze(GantryLoopModel(measure_random_positions(
        truth, noise=GANTRY_NOISE, seed=4, temperature=MachineTemperature()))).report
    assert steady['effects_added'] == []
    assert steady['skipped']['drift_temperature'] == 'temperature is constant in the data'
    assert why_not_in_force([{'name': 'reversal'}, {'name': 'periodic'}]) == ''


def test_gantry_directions_from_row_order(tmp_path):
    data = measure_random_positions(GantryErrors(), 40, GANTRY_NOISE, seed=3)
    path = tmp_path / 'gantry.csv'
    lines = ['command_x,command_y,measured_x,measured_y']
    lines += [','.join(f'{v:.12g}' for v in (*c, *m)) for c, m in zip(data.command, data.measured)]
    path.write_text('\n'.join(lines) + '\n')
    np.testing.assert_array_equal(GantryData.from_csv(path).direction, data.direction)


def test_camera_radial_distortion_found():
    views = tilted_plate_views(CAMERA, (-0.25, 0.08, 0, 0), noise_px=CAMERA_NOISE, seed=4)
    report = analyze(CameraLoopModel(views, (640, 480))).report
    effects = _added(report)
    assert list(effects) == ['radial_distortion']
    assert effects['radial_distortion']['parameters']['k1'] == pytest.approx(-0.25, abs=0.01)
    assert effects['radial_distortion']['parameters']['k2'] == pytest.approx(0.08, abs=0.03)
    floor = np.sqrt(2) * CAMERA_NOISE
    assert report['rms_before'] > 10 * floor
    assert report['rms_after'] < 1.3 * floor
    assert report['base_parameters']['after']['fx'] == pytest.approx(800, abs=2)


def test_camera_sixth_order_distortion_found_after_k1_k2():
    """A lens with k3 = 1.0 beside k1, k2: the loop adds radial_distortion, then its sixth
    order (tried only once k1, k2 are in; 0.025 px RMS beyond what they take), each within
    3 sigma of the truth; the lens without k3 gets none (test above). At k3 = 0.3 these
    views, the plate over 70 % of the width, leave k3 0.008 px beyond what k2 takes:
    below the minimum effect, and not added."""
    views = tilted_plate_views(CAMERA, (-0.25, 0.08, 0, 0, 1.0), noise_px=CAMERA_NOISE,
                               seed=7)
    effects = _added(analyze(CameraLoopModel(views, (640, 480))).report)
    assert list(effects) == ['radial_distortion', 'radial_distortion_k3'], list(effects)
    for name, truth in (('radial_distortion', {'k1': -0.25, 'k2': 0.08}),
                        ('radial_distortion_k3', {'k3': 1.0})):
        for parameter, value in truth.items():
            found = effects[name]['parameters'][parameter]
            assert abs(found - value) < 3 * effects[name]['std_devs'][parameter], parameter


def test_camera_two_effects_and_clean_views():
    views = tilted_plate_views(CAMERA, (-0.25, 0.08, 1e-3, -8e-4), noise_px=CAMERA_NOISE, seed=5)
    effects = _added(analyze(CameraLoopModel(views, (640, 480))).report)
    assert set(effects) == {'radial_distortion', 'tangential_distortion'}
    assert effects['tangential_distortion']['parameters']['p1'] == pytest.approx(1e-3, abs=2e-4)
    assert effects['tangential_distortion']['parameters']['p2'] == pytest.approx(-8e-4, abs=2e-4)
    clean = tilted_plate_views(CAMERA, (0, 0, 0, 0), noise_px=CAMERA_NOISE, seed=6)
    report = analyze(CameraLoopModel(clean)).report
    assert report['effects_added'] == [] and report['unexplained'] == []


def test_real_chessboard_photos_start_without_distortion(real_data):
    photos = sorted((real_data / 'boofcv_mono' / 'Sony_DSC-HX5V_Chess').glob('*.jpg'))
    views, size, _ = views_from_images(photos, 'chessboard', 4, 6, 0.03)
    report = analyze(CameraLoopModel(views, size)).report
    effects = _added(report)
    assert 'radial_distortion' in effects
    # BoofCV's own calibration of these photos: k1 = -0.2556.
    assert effects['radial_distortion']['parameters']['k1'] == pytest.approx(-0.2556, abs=0.02)
    assert report['rms_after'] < 0.3 < report['rms_before']


def test_hexapod_joint_play_found():
    truth = dataclasses.replace(HexapodTruth.default(seed=2), payload_centre=TALL_PAYLOAD_CENTRE)
    nominal = nominal_geometry()
    data, forces = measure_random_poses(truth, 200, seed=3)
    report = analyze(HexapodLoopModel(data, nominal, forces)).report
    effects = _added(report)
    assert list(effects) == ['leg_play']
    play = np.array(list(effects['leg_play']['parameters'].values()))
    # The model sees the nominal force at the commanded pose; the sim closes the play by
    # the true force at the true pose, and by the last move below 5 N. Near that closing
    # force the two disagree, which biases single legs by up to about 2 um.
    np.testing.assert_allclose(play, truth.leg_play, atol=2.0e-6)
    assert np.mean(play) == pytest.approx(np.mean(truth.leg_play), abs=0.6e-6)
    assert effects['leg_play']['force_to_close_play_N'] == 5.0
    clean = dataclasses.replace(truth, leg_play=np.zeros(6))
    clean_data, clean_forces = measure_random_poses(clean, 200, seed=3)
    clean_report = analyze(HexapodLoopModel(clean_data, nominal, clean_forces)).report
    assert clean_report['effects_added'] == []
    floor = clean_report['rms_after']
    assert report['rms_before'] > 2 * floor
    assert report['rms_after'] < 1.3 * floor


def _hexapod_run(force_to_close_play: float, play: bool, seed: int) -> dict:
    truth = dataclasses.replace(HexapodTruth.default(seed=2), payload_centre=TALL_PAYLOAD_CENTRE,
                                force_to_close_play=force_to_close_play)
    if not play:
        truth = dataclasses.replace(truth, leg_play=np.zeros(6))
    data, forces = measure_random_poses(truth, 200, seed=seed)
    return analyze(HexapodLoopModel(data, nominal_geometry(), forces)).report


def test_hexapod_play_closed_by_load_sign_alone():
    # No low-force regime: the play sits where the static force puts it, whatever the last
    # move. Near zero force the engineer's force (nominal geometry, commanded pose) has the
    # wrong sign on a few rows; before the sign test they switched the threshold to 1 N,
    # and leg 6 (force sign changes 6 times in 200 poses) got no play at all: 1.67x floor.
    report = _hexapod_run(0.0, True, seed=7)
    effects = _added(report)
    assert list(effects) == ['leg_play']
    assert effects['leg_play']['force_to_close_play_N'] == 0.0
    assert effects['leg_play']['legs_with_mean_play'] == ['leg6']
    floor = _hexapod_run(0.0, False, seed=7)
    assert floor['effects_added'] == []
    assert report['rms_after'] < 1.3 * floor['rms_after']


def test_hexapod_play_fits_held_on_splits_that_cannot_determine_them():
    # 2 N closing force, seed 11: on one hold-out split leg 6's play side never changes in
    # the fitting rows; fitted freely there, play and actuator offset drifted together to
    # 0.33 m and the play was rejected as making the held-out error worse (17.8 mm RMS).
    report = _hexapod_run(2.0, True, seed=11)
    effects = _added(report)
    assert 'leg_play' not in report['rejected']
    assert effects['leg_play']['force_to_close_play_N'] == 2.0
    assert report['rms_after'] < 0.5 * report['rms_before']


def test_hexapod_without_forces_skips_play_and_says_why():
    truth = dataclasses.replace(HexapodTruth.default(seed=2), payload_centre=TALL_PAYLOAD_CENTRE)
    nominal = nominal_geometry()
    data, _ = measure_random_poses(truth, 60, seed=4)
    report = analyze(HexapodLoopModel(data, nominal)).report
    assert 'load' in report['skipped']['leg_play']
    assert 'load' in report['skipped']['compliance']


def test_cli_analyze_writes_report_and_plot(tmp_path):
    data = tmp_path / 'axis.csv'
    assert cli_main(['simulate', 'axis', '--out', str(data), '--backlash', '4e-6']) == 0
    out = tmp_path / 'axis.json'
    assert cli_main(['analyze', 'axis', '--data', str(data), '--json', str(out)]) == 0
    report = json.loads(out.read_text())
    assert [e['name'] for e in report['effects_added']] == ['reversal']
    for key in ('rms_before', 'rms_after', 'max_before', 'max_after', 'unexplained'):
        assert key in report
    assert out.with_suffix('.png').stat().st_size > 10000


def test_cli_analyze_hexapod_with_payload(tmp_path):
    truth = dataclasses.replace(HexapodTruth.default(seed=2), payload_centre=TALL_PAYLOAD_CENTRE)
    nominal = nominal_geometry()
    data, _ = measure_random_poses(truth, 120, seed=5)
    data.to_csv(tmp_path / 'poses.csv')
    write_geometry(tmp_path / 'nominal.yaml', nominal)
    out = tmp_path / 'hexapod.json'
    assert cli_main(['analyze', 'hexapod', '--data', str(tmp_path / 'poses.csv'),
                     '--geometry', str(tmp_path / 'nominal.yaml'), '--payload',
                     str(truth.payload_mass), *map(str, TALL_PAYLOAD_CENTRE), '--json', str(out)]) == 0
    assert 'leg_play' in [e['name'] for e in json.loads(out.read_text())['effects_added']]


def test_cli_analyze_bad_input(tmp_path, capsys):
    bad = tmp_path / 'axis.csv'
    bad.write_text('command,measured,direction,temperature\n0,0,1,nan\n0.1,0.1,-1,20\n')
    assert cli_main(['analyze', 'axis', '--data', str(bad)]) == 2
    assert 'too few' in capsys.readouterr().err
    constant = tmp_path / 'constant.csv'
    rows = [f'{x:.4f},{x:.4f},{d},20.0' for x in np.linspace(0, 0.1, 30) for d in (1, -1)]
    constant.write_text('command,measured,direction,temperature\n' + '\n'.join(rows) + '\n')
    assert cli_main(['analyze', 'axis', '--data', str(constant)]) == 0
    assert 'temperature is constant' in capsys.readouterr().out


def test_stage_chain_backlash_found_and_clean_stage_gets_nothing():
    from printer_alignment.sim.stage import TRUE_STAGE, simulate_calibration_run
    clean_stage = dataclasses.replace(TRUE_STAGE, backlash=(0.0, 0.0, 0.0))
    report = analyze(StageLoopModel(simulate_calibration_run(seed=2))).report
    effects = _added(report)
    assert set(effects) == {'reversal'}
    # Tolerance table: 1.2 um landing scatter per chain, about 40 reversals per chain.
    for chain, true_backlash in enumerate(TRUE_STAGE.backlash, start=1):
        assert effects['reversal']['parameters'][f'backlash_chain{chain}'] == pytest.approx(
            true_backlash, abs=0.8e-6)
    floor = analyze(StageLoopModel(simulate_calibration_run(clean_stage, seed=2))).report
    assert floor['effects_added'] == [] and floor['unexplained'] == []
    assert report['rms_before'] > 1.3 * floor['rms_after']
    assert report['rms_after'] < 1.1 * floor['rms_after']
    for seed in range(3):
        clean = analyze(StageLoopModel(simulate_calibration_run(clean_stage, seed=20 + seed)),
                        LoopConfig(seed=seed)).report
        assert clean['effects_added'] == [] and clean['unexplained'] == []


@pytest.mark.parametrize('backlash', [False, True])
def test_stage_screw_error_on_one_chain_is_found_there_with_its_aliases(backlash):
    """A 1.5 um once-per-turn screw error on chain 2 only (the model does not declare it),
    with and without the chains' backlash. The plan's targets lie every 1.19 mm, so the 2 mm
    lead is beyond their Nyquist period: the loop finds the error on chain 2 alone at a
    period that takes the same values at every target, and names the aliases, one of
    which is the true lead within 3 sigma; the amplitude is the true one within 3 sigma.
    On seed 1 the loop does not add it, nor on seed 0 with backlash since the plate-frame
    map joined the stage's candidates (one more candidate in the round's Bonferroni count:
    chosen in 2 of 5 splits, 3 of 5 without the map; 17 of 20 seeds either way in
    bench_results/closed_loop.md): chosen on chain 2 in some splits, it is reported as seen
    there and nowhere else."""
    from printer_alignment.sim.stage import TRUE_STAGE, simulate_calibration_run
    truth = TRUE_STAGE if backlash else dataclasses.replace(TRUE_STAGE, backlash=(0.0, 0.0, 0.0))
    lead = TRUE_STAGE.lead[1]
    for seed in ((2, 3) if backlash else (0, 2)):
        report = analyze(StageLoopModel(simulate_calibration_run(
            truth, seed=seed, screw=(0.0, 1.5e-6, 0.0)))).report
        effects = _added(report)
        assert set(effects) == ({'reversal', 'periodic'} if backlash else {'periodic'})
        periodic = effects['periodic']
        assert set(periodic['parameters']) == {'cos_chain2', 'sin_chain2', 'period_chain2'}
        period, sigma = (periodic['parameters']['period_chain2'],
                         periodic['std_devs']['period_chain2'])
        candidates = [period] + periodic['aliases_m']['chain2']
        # An alias's sigma scales with the square of its ratio to the fitted period.
        assert min(abs(p - lead) / ((p / period) ** 2 * sigma) for p in candidates) < 3
        amplitude = np.hypot(periodic['parameters']['cos_chain2'], periodic['parameters']['sin_chain2'])
        spread = max(periodic['std_devs']['cos_chain2'], periodic['std_devs']['sin_chain2'])
        assert abs(amplitude - 1.5e-6) < 3 * spread
    for seed in ((0, 1) if backlash else (1,)):
        quiet = analyze(StageLoopModel(simulate_calibration_run(
            truth, seed=seed, screw=(0.0, 1.5e-6, 0.0)))).report
        assert 'periodic' not in _added(quiet)
        assert all(item['component'] == 'residual_chain2' for item in quiet['unexplained'])
