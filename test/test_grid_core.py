"""Grid-plate self-calibration of one region without ROS (issue 21, first part): the
simulated stage error recovered from an imperfect plate at three placements, against the
simulation's truth; the source's literal scale sign fails; noise propagates at about
1:1; a plate 20x worse than the stage calibrates it as well as a perfect one; bad input."""
import numpy as np
import pytest

from grid_calib.core.model import Grid
from grid_calib.core.procedure import camera_in_stage_frame
from grid_calib.core.selfcal import Placement, self_calibrate
from grid_calib.errors import PlacementError
from grid_calib.sim.plate import GridTruth, default_truth, measure_placements

GRID = Grid(half=5, pitch=0.01)          # 11 x 11 marks, 10 mm pitch (the proposed default)
TOLERANCE = {'noise_free_relative': 1e-9, 'noise_ratio_max': 1.5, 'worse_plate_ratio': 1.15}


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_noise_free_stage_error_is_recovered_exactly(seed):
    truth = default_truth(GRID, seed)
    result = self_calibrate(GRID, measure_placements(GRID, truth, 0.0, seed))
    g = truth.stage_error(GRID)
    assert np.abs(result.stage_error - g).max() < TOLERANCE['noise_free_relative'] * np.abs(g).max()
    assert result.non_orthogonality == pytest.approx(truth.non_orthogonality, rel=1e-9)
    assert result.scale_difference == pytest.approx(truth.scale_difference, rel=1e-9)
    assert max(_rms(r) for r in result.residuals.values()) < 1e-15


def test_the_sources_literal_scale_sign_cannot_describe_a_scale_difference():
    truth = default_truth(GRID, 1)
    placements = measure_placements(GRID, truth, 0.0, 1)
    literal = self_calibrate(GRID, placements, scale_sign_y=+1.0)
    g = truth.stage_error(GRID)
    assert np.abs(literal.stage_error - g).max() > 0.1 * np.abs(g).max()
    assert max(_rms(r) for r in literal.residuals.values()) > 10e-9


@pytest.mark.parametrize('seed', [1, 2])
def test_the_reference_solver_agrees_and_the_sources_literal_transitivity_fails(seed):
    """The source's route (A eliminated by the symmetry and transitivity differences,
    solved by LSQR) recovers the same G noise-free; with the transitivity equations as the
    source prints them (U_0y in the x line, F_y(m+1) + F_y(m) and +U_0x in the y line) the
    equations cannot be met and G is wrong by more than its own size."""
    from grid_calib.core.reference import solve_by_differences
    truth = default_truth(GRID, seed)
    placements = measure_placements(GRID, truth, 0.0, seed)
    g = truth.stage_error(GRID)
    reference = solve_by_differences(GRID, placements)
    assert np.abs(reference.stage_error - g).max() < TOLERANCE['noise_free_relative'] * np.abs(g).max()
    assert reference.non_orthogonality == pytest.approx(truth.non_orthogonality, rel=1e-9)
    assert reference.residual_rms < 1e-15
    literal = solve_by_differences(GRID, placements, literal_transitivity=True)
    assert np.abs(literal.stage_error - g).max() > np.abs(g).max()
    assert literal.residual_rms > 100e-9


def _error_over_noise(truth_for_seed, sigma=20e-9, runs=40) -> float:
    ratios = []
    for seed in range(runs):
        truth = truth_for_seed(seed)
        result = self_calibrate(GRID, measure_placements(GRID, truth, sigma, seed))
        ratios.append(_rms(result.stage_error - truth.stage_error(GRID)) / sigma)
    return float(np.mean(ratios))


def test_noise_propagates_at_about_one_to_one_and_a_bad_plate_costs_nothing():
    """RMS(G estimated - true) over sigma, 40 seeded runs at 20 nm: about 1, as Ye (1997)
    and Qiao (2021) report; a plate with 20x the stage's error (3 um RMS against 0.15 um)
    gives the same ratio as a perfect plate."""
    perfect = _error_over_noise(lambda s: _with_plate(default_truth(GRID, s), 0.0))
    worse = _error_over_noise(lambda s: default_truth(GRID, s, plate_error=3e-6))
    assert 0.5 < perfect < TOLERANCE['noise_ratio_max']
    assert worse / perfect < TOLERANCE['worse_plate_ratio']


def _with_plate(truth: GridTruth, scale: float) -> GridTruth:
    return GridTruth(truth.non_orthogonality, truth.scale_difference, truth.residual_field,
                     truth.mark_errors * scale, truth.misalignments)


def test_bad_placements_are_refused():
    placements = measure_placements(GRID, default_truth(GRID, 1), 0.0, 1)
    with pytest.raises(PlacementError, match='missing'):
        self_calibrate(GRID, placements[:2])
    doubled = Placement('rotated', np.vstack([placements[1].marks[:-1], placements[1].marks[:1]]),
                        placements[1].deviation)
    with pytest.raises(PlacementError, match='measured twice'):
        self_calibrate(GRID, [placements[0], doubled, placements[2]])
    short = Placement('shifted', placements[2].marks[:-3], placements[2].deviation[:-3])
    with pytest.raises(PlacementError, match='3 of the plate'):
        self_calibrate(GRID, [placements[0], placements[1], short])
    nan = Placement('initial', placements[0].marks, placements[0].deviation * np.nan)
    with pytest.raises(PlacementError, match='finite'):
        self_calibrate(GRID, [nan, placements[1], placements[2]])
    with pytest.raises(PlacementError, match='odd N'):
        Grid(half=2.5, pitch=0.01)


def test_command_line_contract(tmp_path, capsys):
    """`machine-align simulate grid` writes the marks CSV of the contract and `calibrate
    grid` reads it back to the true O and R (noise-free), with the sites, the gauge and the
    plate errors in the JSON and the plot beside it; a missing placement is one clear
    error."""
    import json

    from grid_calib.sim.plate import default_travel
    from machine_alignment.cli import main
    marks, out = tmp_path / 'marks.csv', tmp_path / 'grid.json'
    assert main(['simulate', 'grid', '--out', str(marks), '--noise', '0', '--seed', '4']) == 0
    assert marks.read_text().splitlines()[0] == 'region,placement,i,j,x,y,time,temperature'
    assert main(['calibrate', 'grid', '--data', str(marks), '--pitch', '0.01',
                 '--json', str(out)]) == 0
    report = json.loads(out.read_text())
    truth = default_travel(GRID, 1, 1, 4)
    assert report['non_orthogonality_rad'] == pytest.approx(truth.non_orthogonality, rel=1e-9)
    assert report['scale_difference'] == pytest.approx(truth.scale_difference, rel=1e-9)
    assert len(report['sites']) == 11 * 12 and set(report['sites'][0]) == {
        'x', 'y', 'error_x', 'error_y', 'sigma_x', 'sigma_y'}
    assert 'undetermined' in report['gauge']['isotropic_scale']
    assert report['isotropic_scale'] is None and len(report['plate_errors']) == 121
    assert set(report['regions']['0']) >= {'misalignments', 'uncertainty_m', 'residual_rms_m'}
    assert out.with_suffix('.png').exists()
    lines = marks.read_text().splitlines()
    partial = tmp_path / 'partial.csv'
    partial.write_text('\n'.join(line for line in lines if ',shifted,' not in line) + '\n')
    capsys.readouterr()
    assert main(['calibrate', 'grid', '--data', str(partial), '--pitch', '0.01']) == 2
    assert "placement(s) ['shifted'] missing" in capsys.readouterr().err


def test_per_site_uncertainty_matches_the_spread_over_runs():
    """The propagated 1-sigma of G at each site against the Monte-Carlo spread of the
    estimate over 100 seeded runs at 20 nm; the noise itself is estimated from the
    residuals."""
    sigma, errors, estimated = 20e-9, [], []
    for seed in range(100):
        truth = default_truth(GRID, seed)
        result = self_calibrate(GRID, measure_placements(GRID, truth, sigma, seed))
        errors.append(result.stage_error - truth.stage_error(GRID))
        estimated.append(result.noise)
    spread = np.std(errors, axis=0)
    predicted = result.noise_gain * sigma
    assert 0.9 < np.mean(spread / predicted) < 1.1
    assert abs(np.mean(estimated) / sigma - 1) < 0.05


def test_sampled_uncertainty_agrees_with_the_exact_one(monkeypatch):
    """The sampled route (noise drawn through the solve, what grids beyond N = 21 take)
    against the exact propagation on the same region: each site's sigma within 20 % (256
    draws know a sigma to 4.4 %), the median within 5 %; the report says which route."""
    from grid_calib.core import selfcal
    placements = measure_placements(GRID, default_truth(GRID, 2), 20e-9, 2)
    exact = self_calibrate(GRID, placements)
    monkeypatch.setattr(selfcal, 'MAX_PROPAGATED', 0)
    sampled = self_calibrate(GRID, placements)
    assert exact.uncertainty_method == 'exact' and sampled.uncertainty_method.startswith('sampled')
    ratio = sampled.noise_gain / exact.noise_gain
    assert abs(np.median(ratio) - 1) < 0.05 and np.all((ratio > 0.8) & (ratio < 1.2))
    assert sampled.report()['uncertainty_method'].startswith('sampled: 256 draws')


def test_compensation_subtracts_the_stage_error_and_does_not_extrapolate():
    from calib_core.errors import OutOfTravelError
    from grid_calib.core.compensation import StageErrorMap
    sigma = 20e-9
    truth = default_truth(GRID, 5)
    result = self_calibrate(GRID, measure_placements(GRID, truth, sigma, 5))
    true_positions = result.site_positions
    readings = true_positions + truth.stage_error(GRID)
    stage_map = StageErrorMap(result.sites, result.stage_error, GRID.pitch)
    after = stage_map.true_position(readings) - true_positions
    literal = readings + stage_map.error_at(readings) - true_positions   # the source's c' + G
    size = _rms(truth.stage_error(GRID))
    assert _rms(after) < 3 * sigma < 0.1 * size
    assert _rms(literal) > 1.8 * size
    with pytest.raises(OutOfTravelError):
        stage_map.error_at([[1.0, 0.0]])


def test_the_camera_angle_for_grid_readings_is_to_the_stage_axes():
    """The vision calibration's camera angle is to its dot plate, and its gantry axis angle
    is the X axis's in that plate's frame: the readings need their difference (a plate
    turned by 0.57 mrad on the printer made every grid placement look turned by it)."""
    camera = camera_in_stage_frame({'pixel_size': 12.3e-6, 'camera_angle': 2.0e-3,
                                    'axis_angle': 0.57e-3, 'lead_x': 0.016})
    assert camera == pytest.approx((12.3e-6, 1.43e-3), abs=1e-15)
    assert camera_in_stage_frame({'pixel_size': 12.3e-6}) is None


def test_the_bordered_factor_solves_as_superlu_on_the_whole_system():
    """The sparse block factored alone with the dense columns and gauge rows as a border
    (grid_calib.core.bordered) gives SuperLU's solution of the whole KKT system, for one
    right-hand side and for a block of them; a singular sparse block falls back to the
    whole system."""
    from scipy import sparse

    from grid_calib.core.bordered import (
        BorderedFactor, dense_columns, factor_kkt, factor_whole_kkt, kkt_matrix)
    from grid_calib.core.selfcal import linear_system

    grid = Grid(6, 0.01)
    placements = measure_placements(grid, default_truth(grid, 4), 20e-9, 4)
    system = linear_system(grid, {p.name: p for p in placements})
    design, gauge = system.design, system.gauge
    # O, R and the three placements' shift and turn: every reading of a placement.
    assert list(dense_columns(design)) == [system.o_col, system.o_col + 1] \
        + list(range(system.e0, system.e0 + 9))
    factor = factor_kkt(design, gauge)
    assert isinstance(factor, BorderedFactor)
    whole = factor_whole_kkt(design, gauge)
    rng = np.random.default_rng(0)
    for right in (rng.standard_normal(factor.shape[0]),
                  rng.standard_normal((factor.shape[0], 5))):
        expected = whole.solve(right)
        assert np.allclose(factor.solve(right), expected, rtol=0,
                           atol=1e-9 * np.abs(expected).max())
    # A mark column no reading touches makes the sparse block singular.
    unread = sparse.hstack([design, sparse.csr_matrix((design.shape[0], 1))]).tocsr()
    gauge_unread = sparse.hstack([gauge, sparse.csr_matrix((gauge.shape[0], 1))]).tocsr()
    border = np.concatenate([dense_columns(unread), unread.shape[1] + np.arange(gauge.shape[0])])
    with pytest.raises(RuntimeError):
        BorderedFactor(kkt_matrix(unread, gauge_unread), border, 'MMD_AT_PLUS_A')
