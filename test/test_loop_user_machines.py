"""The closed loop on machines shaped like those users bring, simulated here independently
of the suite's own simulators (issue 56): a 0.8 m hexapod measured by motion capture with
its legs read in motor revolutions, one leg's lead 6 % off; an ISO 230-2 acceptance run
that drifts; a leg growing with temperature over a short stroke. Each states its truth and
checks what the loop recovered; the clean twins must get nothing."""
import numpy as np
import pytest

from calib_core.axis import AxisModel
from calib_core.closed_loop import LoopConfig, analyze, format_report
from hexapod_calib.core.loop_models import HexapodLoopModel
from machine_alignment.bench.user_machines import (
    LEAD_RATIO, NOMINAL, growing_leg, hexapod_day, independent_fit, iso_run)


def _legs(effect):
    return {p.rsplit('_', 1)[-1]: v for p, v in effect['parameters'].items()}


def test_a_hexapod_leg_read_with_a_wrong_lead_is_named_with_its_scale():
    """Leg 3's lead is 6 % off: the loop adds scale, on leg 3 within 1 % of the truth, any
    other leg it names within 3 sigma of its own (under 1 %) lead error; the held-out error
    reaches within 10 % of the same machine's with every lead right (its floor)."""
    data = hexapod_day(seed=5, count=80)
    report = analyze(HexapodLoopModel(data, NOMINAL), LoopConfig(seed=0)).report
    effects = {e['name']: e for e in report['effects_added']}
    assert set(effects) == {'scale'}, format_report(report)
    scale = effects['scale']
    values = _legs(scale)
    assert abs(values['leg3'] - (LEAD_RATIO[2] - 1)) < 0.01
    for name, value in values.items():
        leg = int(name[-1]) - 1
        sigma = scale['std_devs'][f'scale_{name}']
        assert abs(value - (LEAD_RATIO[leg] - 1)) < max(3 * sigma, 0.01), (name, value, sigma)
    floor = analyze(HexapodLoopModel(hexapod_day(seed=5, count=80, lead_ratio=np.ones(6)),
                                     NOMINAL), LoopConfig(seed=0)).report
    assert floor['effects_added'] == [] and floor['unexplained'] == [], format_report(floor)
    assert report['rms_before'] > 1.3 * floor['rms_after']
    assert report['rms_after'] < 1.1 * floor['rms_after']


def test_one_leg_growing_with_temperature_on_a_short_stroke_is_told_as_its_growth():
    """Leg 2 grows 12 ppm/K of its 0.64 m over a logged 3 K cycle (7.7 um/K), the legs move
    +-5 mm, poses measured to 2 um and 10 urad: drift_temperature is added on leg 2 alone,
    its growth at the mean length within 3 sigma of the truth, and the expansion, which
    +-5 mm cannot tell from the growth, is flagged as not determined and not printed as a
    value."""
    growth = 12e-6 * 0.64
    data = growing_leg(seed=0, growth=growth)
    report = analyze(HexapodLoopModel(data, NOMINAL), LoopConfig(seed=0)).report
    effects = {e['name']: e for e in report['effects_added']}
    assert set(effects) == {'drift_temperature'}, format_report(report)
    thermal = effects['drift_temperature']
    assert set(_legs(thermal)) == {'leg2'}
    sigma = thermal['std_devs']['growth_leg2']
    assert abs(thermal['parameters']['growth_leg2'] - growth) < 3 * sigma
    assert 'expansion_leg2' in thermal['parameters_not_determined']
    printed = format_report(report)
    assert 'expansion_leg2 not determined' in printed
    assert f'expansion_leg2 {thermal["parameters"]["expansion_leg2"]:.4g}' not in printed


@pytest.mark.parametrize('seed', [0, 14])
def test_a_drifting_iso_230_2_run_names_the_drift(seed):
    """-15.8 um over the run: the loop adds a drift over the run by approach number within 3
    sigma of the truth beside the backlash, and nothing else, though the run order makes a
    step per cycle plus a reversal varying with position span the same (seeds 0 and 14
    claimed those); without the drift, nothing of the run."""
    report = analyze(AxisModel(iso_run(seed, -15.8e-6)), LoopConfig(seed=seed)).report
    effects = {e['name']: e for e in report['effects_added']}
    assert set(effects) == {'drift_sequence', 'reversal'}, format_report(report)
    rate = effects['drift_sequence']['parameters']['rate_axis']
    assert abs(rate - (-15.8e-6 / 49)) < 3 * effects['drift_sequence']['std_devs']['rate_axis']
    quiet = analyze(AxisModel(iso_run(seed, 0.0)), LoopConfig(seed=seed)).report
    assert not {'drift_sequence', 'block_step', 'warm_up'} & {
        e['name'] for e in quiet['effects_added']}, format_report(quiet)


def test_a_bowed_gantry_gets_a_smooth_map_and_its_compensation_grid(tmp_path):
    """A 3 um bow over the gantry's travel (guides not straight), which no effect but the
    2-D map describes: smooth_map is added at degree 2 with its coefficients within 3 sigma
    of the bow's (Legendre: 3 um v^2 = 2 um P2(v) + 1 um), the held-out RMS falls to within
    10 % of the same gantry without the bow, and `analyze gantry` writes the compensation
    grid, whose correction at a point is minus the bow there (less what the rigid-body
    model takes) to within 0.3 um."""
    from machine_alignment.bench.user_machines import bow
    from machine_alignment.cli import main as cli_main
    from printer_alignment.core.loop_models import GantryData, GantryLoopModel
    from printer_alignment.sim.gantry import GantryErrors, measure_random_positions
    clean = measure_random_positions(GantryErrors.ideal(), seed=4)
    bowed = GantryData(clean.command, clean.measured + bow(clean.command, 3e-6),
                       clean.direction, clean.covariates)
    report = analyze(GantryLoopModel(bowed), LoopConfig(seed=4)).report
    assert [e['name'] for e in report['effects_added']] == ['smooth_map'], format_report(report)
    effect = report['effects_added'][0]
    assert effect['map_degree'] == 2
    truth = {'map02_x': 2e-6, 'map20_y': 1.4e-6, 'map11_y': -2.1e-6}
    for name, value in effect['parameters'].items():
        assert abs(value - truth.get(name, 0.0)) < 3 * effect['std_devs'][name], name
    floor = analyze(GantryLoopModel(clean), LoopConfig(seed=4)).report
    assert floor['effects_added'] == [] and floor['unexplained'] == []
    assert report['rms_after'] < 1.1 * floor['rms_after']
    csv = tmp_path / 'bowed.csv'
    bowed.to_csv(csv)
    json_path = tmp_path / 'loop.json'
    assert cli_main(['analyze', 'gantry', '--data', str(csv), '--json', str(json_path)]) == 0
    grid = np.genfromtxt(tmp_path / 'loop_map.csv', delimiter=',', names=True)
    assert len(np.unique(grid['y'])) == 11 and len(grid) == 11 * len(np.unique(grid['x']))
    # at the travel's centre the bow is zero and the map's P2 terms are -1/2 of their
    # coefficients: the correction there is +1 um in x (the constant is the offset's)
    centre = np.argmin(np.hypot(grid['x'] - np.median(grid['x']), grid['y'] - np.median(grid['y'])))
    edge = np.argmax(grid['y'])
    assert (grid['correction_x'][edge] - grid['correction_x'][centre]) == pytest.approx(
        -3e-6, abs=0.3e-6)


def test_the_lead_error_found_holds_on_a_check_day_with_the_legs_homed_again():
    """Calibration day (80 poses) and a check day (60 other poses, every leg homed again,
    its reading shifted by up to 3 mm): with only the leg offsets fitted again on the check
    day, as re-homing asks, the loop's model (42 parameters and the scale it named) leaves
    the check day's leg lengths within 10 % of an independent 48-parameter fit's, and
    clearly below the 42-parameter model's."""
    from calib_core.closed_loop import evaluate
    calibration = hexapod_day(seed=5, count=80)
    check = hexapod_day(seed=6, count=60,
                        rehome=np.array([1.2, -0.8, 3.0, 0.4, -2.1, 1.7]) * 1e-3)
    result = analyze(HexapodLoopModel(calibration, NOMINAL), LoopConfig(seed=0))
    assert 'scale' in result.fit.names()
    on_check = evaluate(HexapodLoopModel(check, NOMINAL), result.fit, np.arange(len(check)))

    def rehomed_rms(r):
        r = np.asarray(r).reshape(len(check), 6)
        return float(np.sqrt(np.mean((r - r.mean(axis=0)) ** 2)))
    loop = rehomed_rms(on_check)
    floors = {}
    for with_scale in (True, False):
        x, residuals = independent_fit(calibration, with_scale)
        floors[with_scale] = rehomed_rms(residuals(x, check.measured, check.leg_lengths))
    assert loop < 1.1 * floors[True], (loop, floors)
    assert floors[False] > 1.2 * floors[True], floors


STAGE_BOW = (3e-6, 3e-6)     # m at the stroke: x bows with y, y with x (StageSim's ``bow``)


def _non_affine(xy: np.ndarray, error: np.ndarray) -> np.ndarray:
    """``error`` (n, 2) less its least-squares affine part in ``xy``: what the stage's base
    model (mounting, leads, angles) cannot take up, and so what a map can be held to."""
    design = np.column_stack([np.ones(len(xy)), xy])
    return error - design @ np.linalg.lstsq(design, error, rcond=None)[0]


@pytest.mark.parametrize('seed', [0, 1])
def test_a_stage_whose_guides_bow_gets_a_map_in_the_plate_frame(seed, tmp_path):
    """The XY-Theta stage's platform off by a 3 um bow over its travel in the plate frame
    (x with y squared, y with x squared), which no chain effect describes: the loop adds
    smooth_map with the backlash the stage also has, and the map's error at the rows
    matches the true bow's part the base model cannot take up (its non-affine part) to
    within 35 % RMS (8-25 % over seeds 0-5), the held-out RMS within 10 % of the same stage
    without the bow; `analyze stage --json` writes the plate-frame compensation grid."""
    from calib_core.effects.smooth_map import map_error
    from machine_alignment.cli import main as cli_main
    from printer_alignment.core.loop_models import StageLoopModel
    from printer_alignment.core.stage import STROKE, platform_points_in_plate
    from printer_alignment.sim.stage import (
        CALIBRATION_MARKS, TRUE_STAGE, simulate_calibration_run)
    data = simulate_calibration_run(seed=seed, bow=STAGE_BOW)
    report = analyze(StageLoopModel(data), LoopConfig(seed=seed)).report
    added = {e['name']: e for e in report['effects_added']}
    assert set(added) == {'smooth_map', 'reversal'}, format_report(report)
    effect = added['smooth_map']
    assert all(name.endswith(('_x', '_y')) for name in effect['parameters'])
    # The true bow at each row, from the Marks' true centroid (landing scatter aside).
    def centroid(q, directions):
        pose = TRUE_STAGE.stage_to_plate(TRUE_STAGE.forward(q, directions))
        return platform_points_in_plate(pose, CALIBRATION_MARKS.mean(axis=0)[None])[:, 0]
    home = centroid(np.zeros((1, 3)), np.ones((1, 3)))
    dx, dy = ((centroid(data.q, data.directions) - home) / STROKE).T
    true_bow = np.column_stack([STAGE_BOW[0] * dy ** 2, STAGE_BOW[1] * dx ** 2])
    xy = data.marks.mean(axis=1)
    low, high = (np.array(v) for v in effect['map_travel_m'])
    fitted = map_error(list(effect['parameters'].values()), effect['map_degree'], low, high, xy)
    truth, found = _non_affine(xy, true_bow), _non_affine(xy, fitted)
    assert np.sqrt(np.mean((found - truth) ** 2)) < 0.35 * np.sqrt(np.mean(truth ** 2))
    # Held out, the bowed stage ends within 10 % of its twin without the bow.
    twin = analyze(StageLoopModel(simulate_calibration_run(seed=seed)), LoopConfig(seed=seed))
    assert twin.report['effects_added'][0]['name'] == 'reversal'
    assert report['rms_after'] < 1.1 * twin.report['rms_after']
    if seed == 0:
        csv, json_path = tmp_path / 'stage.csv', tmp_path / 'loop.json'
        data.to_csv(csv)
        assert cli_main(['analyze', 'stage', '--data', str(csv), '--json', str(json_path)]) == 0
        grid = np.genfromtxt(tmp_path / 'loop_map.csv', delimiter=',', names=True)
        assert grid.dtype.names == ('x', 'y', 'correction_x', 'correction_y')
        assert len(np.unique(grid['y'])) == 11
        inside = (grid['x'] >= xy[:, 0].min()) & (grid['x'] <= xy[:, 0].max() + 1e-9)
        assert inside.all()
