"""The closed loop on single-axis (ISO 230-2) data: effects the base model (offset +
scale) lacks are found with their true values; clean data get nothing."""
import numpy as np
import pytest

from calib_core.axis import AxisData, AxisModel
from calib_core.closed_loop import LoopConfig, analyze
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.sim.axis import AxisTest, AxisTruth, simulate_axis_test

NOISE = AxisTruth().noise


def _added(report):
    return {e['name']: e for e in report['effects_added']}


def test_reversal_found_with_its_backlash():
    truth = AxisTruth(backlash=4e-6)
    report = analyze(AxisModel(simulate_axis_test(truth, seed=11))).report
    effects = _added(report)
    assert list(effects) == ['reversal']
    backlash = effects['reversal']['parameters']['backlash_axis']
    sigma = effects['reversal']['std_devs']['backlash_axis']
    assert abs(backlash - truth.backlash) < max(3 * sigma, 0.1e-6)
    assert report['rms_before'] > 5 * NOISE
    assert report['rms_after'] < 1.3 * NOISE
    assert report['unexplained'] == []


@pytest.mark.parametrize('seed', [13, 17, 18])
def test_a_constant_backlash_is_not_called_position_dependent(seed):
    """On these seeds the general effect (reversal changing along the travel) lowered the
    cross-validated error more than the constant one by a 1.1-1.6 sigma slope and was
    added in its place (bench_results/closed_loop.md, before the nested-terms rule): the
    constant backlash is what is claimed, at its true 4 um within 3 sigma."""
    data = simulate_axis_test(AxisTruth(backlash=4e-6), seed=seed)
    report = analyze(AxisModel(data), LoopConfig(seed=seed)).report
    assert [e['name'] for e in report['effects_added']] == ['reversal']
    effect = report['effects_added'][0]
    assert abs(effect['parameters']['backlash_axis'] - 4e-6) < 3 * effect['std_devs'][
        'backlash_axis']


def test_periodic_error_found_with_its_pitch():
    truth = AxisTruth(periodic_amplitude=1.5e-6, pitch=0.016)
    report = analyze(AxisModel(simulate_axis_test(truth, seed=12))).report
    effect = _added(report)['periodic']
    p = effect['parameters']
    assert p['period_axis'] == pytest.approx(truth.pitch, abs=0.05e-3)
    assert np.hypot(p['cos_axis'], p['sin_axis']) == pytest.approx(1.5e-6, abs=0.15e-6)
    # sin(x + phase) = cos(phase) sin x + sin(phase) cos x
    assert np.arctan2(p['cos_axis'], p['sin_axis']) == pytest.approx(truth.periodic_phase, abs=0.1)
    assert report['rms_after'] < 1.3 * NOISE


def test_two_effects_at_once():
    truth = AxisTruth(backlash=3e-6, periodic_amplitude=1.0e-6, pitch=0.010)
    report = analyze(AxisModel(simulate_axis_test(truth, AxisTest(targets=61), seed=13))).report
    effects = _added(report)
    assert set(effects) == {'reversal', 'periodic'}
    assert effects['reversal']['parameters']['backlash_axis'] == pytest.approx(3e-6, abs=0.2e-6)
    assert effects['periodic']['parameters']['period_axis'] == pytest.approx(0.010, abs=0.05e-3)
    assert report['rms_after'] < 1.3 * NOISE < report['rms_before']


def test_thermal_expansion_found_and_told_from_time_drift():
    truth = AxisTruth(expansion=11.5e-6, temperature_rise=1.0)
    report = analyze(AxisModel(simulate_axis_test(truth, seed=14))).report
    effect = _added(report)['drift_temperature']
    assert effect['parameters']['expansion_axis'] == pytest.approx(11.5e-6, abs=1.5e-6)
    assert 'drift_time' not in _added(report)
    assert report['rms_after'] < 1.3 * NOISE


def test_clean_data_get_nothing_over_many_seeds():
    false_positives = 0
    for seed in range(60):
        data = simulate_axis_test(AxisTruth(temperature_rise=0.5), seed=seed)
        report = analyze(AxisModel(data), LoopConfig(seed=seed)).report
        false_positives += bool(report['effects_added']) + bool(report['unexplained'])
    # alpha = 1e-3 per round: expect no false positive in 60 runs.
    assert false_positives <= 1


def test_structure_no_candidate_explains_is_reported():
    class OnlyReversal(AxisModel):
        candidates = ('reversal',)

    truth = AxisTruth(periodic_amplitude=2e-6, pitch=0.016)
    report = analyze(OnlyReversal(simulate_axis_test(truth, seed=15))).report
    assert report['effects_added'] == []
    kinds = {(u['covariate'], u['kind']) for u in report['unexplained']}
    assert ('position_axis', 'periodic') in kinds


def test_one_direction_only_skips_reversal_and_says_why():
    data = simulate_axis_test(AxisTruth(backlash=4e-6), seed=16, bidirectional=False)
    report = analyze(AxisModel(data)).report
    assert 'reversal' in report['skipped']
    assert 'both directions' in report['skipped']['reversal']
    assert 'temperature is constant' in report['skipped']['drift_temperature']


def test_missing_covariate_skips_its_effects():
    data = simulate_axis_test(AxisTruth(), seed=17)
    bare = AxisData(data.command, data.measured, data.direction)
    report = analyze(AxisModel(bare)).report
    assert 'time' in report['skipped']['drift_time']
    assert 'temperature' in report['skipped']['drift_temperature']


def test_too_little_data_is_refused_or_skipped():
    data = simulate_axis_test(AxisTruth(), AxisTest(targets=3, cycles=1), seed=18)
    with pytest.raises(CalibrationError, match='too few'):
        analyze(AxisModel(data))
    data = simulate_axis_test(AxisTruth(), AxisTest(targets=9, cycles=1), seed=18)
    report = analyze(AxisModel(data)).report
    assert 'too few to find a period' in report['skipped']['periodic']


def test_bad_axis_data_is_refused(tmp_path):
    with pytest.raises(InvalidInputError, match='direction'):
        AxisData([0.0, 0.1], [0.0, 0.1], [1.0, 0.0])
    with pytest.raises(InvalidInputError, match='NaN'):
        AxisData([0.0, np.nan], [0.0, 0.1], [1.0, -1.0])
    path = tmp_path / 'axis.csv'
    path.write_text('command,measured\n0,0\n')
    with pytest.raises(InvalidInputError, match='direction'):
        AxisData.from_csv(path)
