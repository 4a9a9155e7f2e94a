"""A travel calibrated region by region and stitched (issue 21): noise-free recovery in
every region by both stitching routes, error growth of chained against joint stitching,
the isotropic scale from a certified pitch, and placements the readings show to be wrong
(a turn other than 90 degrees, a shift other than one pitch, an uneven pitch, an even N,
regions that do not overlap), each refused with a message that names it."""
import numpy as np
import pytest

from grid_calib.core.data import Region, read_marks, region_from_readings, write_marks
from grid_calib.core.model import Grid, site_of, without_similarity
from grid_calib.core.travel import calibrate_travel
from grid_calib.errors import PlacementError
from grid_calib.sim.plate import default_travel, measure_travel

GRID = Grid(half=5, pitch=0.01)
TOLERANCE = {'noise_free_relative': 1e-9, 'joint_over_sigma': 1.5, 'chained_over_joint': 2.0}


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _regions(truth, noise=0.0, seed=0) -> dict:
    return {r: Region(truth.origins[r], p)
            for r, p in measure_travel(GRID, truth, noise, seed).items()}


def _true_error(truth, calibration, keep_scale=False):
    positions = calibration.stitched.site_positions
    return without_similarity(positions, truth.error_at(positions), keep_scale)


@pytest.mark.parametrize('method', ['joint', 'chained'])
def test_noise_free_travel_is_recovered_in_every_region(method):
    """3 x 3 regions sharing one row and column: the stitched G matches the truth (in the
    same gauge) to 1e-9 of its size at every region's sites."""
    truth = default_travel(GRID, 3, 3, seed=1)
    calibration = calibrate_travel(GRID, _regions(truth), method)
    g = _true_error(truth, calibration)
    where = {tuple(s): k for k, s in enumerate(calibration.stitched.sites)}
    for r, origin in truth.origins.items():
        rows = [where[tuple(s)] for s in GRID.sites + origin]
        error = calibration.stitched.stage_error[rows] - g[rows]
        assert np.abs(error).max() < TOLERANCE['noise_free_relative'] * np.abs(g).max(), r
    assert calibration.stitched.overlap_rms < 1e-15


def test_chained_stitching_grows_the_error_joint_stitching_does_not():
    """With 20 nm noise over 3 x 3 regions (8 seeds): joint stitching keeps RMS(G - true)
    near sigma; chaining pairwise lets it grow to several sigma."""
    sigma, joint, chained = 20e-9, [], []
    for seed in range(8):
        truth = default_travel(GRID, 3, 3, seed=seed)
        regions = _regions(truth, sigma, seed)
        for method, out in (('joint', joint), ('chained', chained)):
            calibration = calibrate_travel(GRID, regions, method)
            out.append(_rms(calibration.stitched.stage_error - _true_error(truth, calibration)))
    assert np.mean(joint) / sigma < TOLERANCE['joint_over_sigma']
    assert np.mean(chained) / np.mean(joint) > TOLERANCE['chained_over_joint']


def test_a_certified_pitch_fixes_the_isotropic_scale():
    """Stage isotropic scale 5 ppm, plate pitch 3 ppm short: without an external length the
    scale is undetermined (None, G holds none); with the plate's certified mean pitch the
    stage's 5 ppm is recovered and G matches the truth including it."""
    truth = default_travel(GRID, 2, 1, seed=2, isotropic_scale=5e-6, plate_scale=-3e-6)
    regions = _regions(truth)
    assert calibrate_travel(GRID, regions).isotropic_scale is None
    calibration = calibrate_travel(GRID, regions, certified_pitch=truth.mean_pitch(GRID))
    assert calibration.isotropic_scale == pytest.approx(5e-6, rel=1e-6)
    g = _true_error(truth, calibration, keep_scale=True)
    assert np.abs(calibration.stitched.stage_error - g).max() < 1e-9 * np.abs(g).max()
    with pytest.raises(PlacementError, match='certified pitch'):
        calibrate_travel(GRID, regions, certified_pitch=0.0101)


def test_regions_that_do_not_overlap_are_refused():
    truth = default_travel(GRID, 2, 1, seed=3)
    regions = _regions(truth)
    far = regions[1]
    regions[1] = Region((far.origin[0] + 12, far.origin[1]), far.placements)
    with pytest.raises(PlacementError, match=r'region\(s\) \[1\] share no sites'):
        calibrate_travel(GRID, regions)


def _readings(seed=4) -> dict:
    """One region's raw readings, placement -> (marks, readings m)."""
    truth = default_travel(GRID, 1, 1, seed=seed)
    placements = measure_travel(GRID, truth, 20e-9, seed)[0]
    return {p.name: (p.marks, site_of(p.marks, p.name) * GRID.pitch + p.deviation)
            for p in placements}


@pytest.mark.parametrize('turn, shown', [((0, 1, -1, 0), '-90.00'),
                                         ((-1, 0, 0, -1), '-?180.00'),
                                         ((1, 0, 0, 1), '-?0.00')])
def test_a_turn_other_than_90_degrees_counter_clockwise_is_detected(turn, shown):
    """The 'rotated' placement turned clockwise, by 180 degrees or not at all: the readings
    show the angle, and it is named."""
    readings = _readings()
    marks, reading = readings['rotated']
    sites = marks @ np.array(turn).reshape(2, 2).T            # where the marks really were
    g = reading - site_of(marks, 'rotated') * GRID.pitch
    readings['rotated'] = (marks, sites * GRID.pitch + g)
    with pytest.raises(PlacementError, match=f'rotated: the readings show the plate turned by '
                                             f'{shown}'):
        region_from_readings(GRID, readings)


def test_a_turn_within_the_small_angle_model_passes_and_one_beyond_it_is_refused():
    readings = _readings()
    for angle, passes in ((150e-6, True), (1e-3, False)):
        changed = dict(readings)
        marks, reading = readings['rotated']
        c, s = np.cos(angle), np.sin(angle)
        changed['rotated'] = (marks, reading @ np.array([[c, s], [-s, c]]))
        if passes:
            region_from_readings(GRID, changed)
        else:
            with pytest.raises(PlacementError, match='small-angle model'):
                region_from_readings(GRID, changed)


def test_a_shift_along_y_or_of_two_pitches_is_refused():
    readings = _readings()
    for move, shown in (((-1, 1), r'\(0.00, 1.00\) pitches'), ((1, 0), r'\(2.00, 0.00\)')):
        changed = dict(readings)
        marks, reading = readings['shifted']
        changed['shifted'] = (marks, reading + np.array(move) * GRID.pitch)
        with pytest.raises(PlacementError, match=shown + '.*one pitch along \\+x'):
            region_from_readings(GRID, changed)


def test_an_uneven_or_wrong_pitch_is_refused():
    readings = _readings()
    marks, reading = readings['initial']
    wrong = dict(readings, initial=(marks, reading * 1.01))
    with pytest.raises(PlacementError, match='pitch of 10.1 mm, not the given 10 mm'):
        region_from_readings(GRID, wrong)
    bent = reading.copy()
    bent[7] += [0.4e-3, 0.0]
    with pytest.raises(PlacementError, match='off a regular grid'):
        region_from_readings(GRID, dict(readings, initial=(marks, bent)))


def test_marks_csv_faults_are_named(tmp_path):
    """An even N (indices 0..9), a doubled mark, and the two-region file read back."""
    truth = default_travel(GRID, 2, 1, seed=5)
    path = tmp_path / 'marks.csv'
    write_marks(path, GRID, _regions(truth))
    grid, regions = read_marks(path, GRID.pitch)
    assert grid == GRID and {r: reg.origin for r, reg in regions.items()} == truth.origins
    lines = path.read_text().splitlines()
    doubled = tmp_path / 'doubled.csv'
    doubled.write_text('\n'.join(lines + [lines[5]]) + '\n')
    _, regions = read_marks(doubled, GRID.pitch)
    with pytest.raises(PlacementError, match='measured twice'):
        calibrate_travel(GRID, regions)
    even = tmp_path / 'even.csv'
    even.write_text('region,placement,i,j,x,y\n' + '\n'.join(
        f'0,initial,{i},{j},{i * 0.01},{j * 0.01}' for i in range(10) for j in range(10)) + '\n')
    with pytest.raises(PlacementError, match='centred, -K..K, for an odd N'):
        read_marks(even, GRID.pitch)


def _reading_messages(truth) -> list:
    """The readings of ``truth``'s regions as GridMarkReading-shaped messages, in order."""
    from types import SimpleNamespace
    messages = []
    for r, region in _regions(truth).items():
        for p in region.placements:
            reading = (site_of(p.marks, p.name) + region.origin) * GRID.pitch + p.deviation
            messages += [SimpleNamespace(region=r, placement=p.name, i=i, j=j, x=x, y=y)
                         for (i, j), (x, y) in zip(p.marks, reading)]
    return messages


def test_a_cut_run_replays_its_complete_regions_and_names_the_rest():
    """Readings as a run killed during region 1's shifted placement left them: region 0
    solves, region 1 is named as incomplete; a NaN reading is refused."""
    from grid_calib.core.records import regions_from_readings
    truth = default_travel(GRID, 2, 1, seed=6)
    messages = _reading_messages(truth)
    cut = messages[:-40]
    regions, left_out = regions_from_readings(GRID, cut)
    assert list(regions) == [0]
    assert left_out == ['region 1 left out: incomplete (initial 121/121, rotated 121/121, '
                        'shifted 81/121)']
    calibrate_travel(GRID, regions)
    cut[3].x = float('nan')
    with pytest.raises(PlacementError, match=r'mark \(.*NaN'):
        regions_from_readings(GRID, cut)


def _stamped(seconds):
    from types import SimpleNamespace
    return SimpleNamespace(stamp=SimpleNamespace(sec=int(seconds),
                                                 nanosec=int(round(seconds % 1 * 1e9))))


def test_the_logged_temperature_reaches_every_reading():
    """A run's readings, one every 2 s from t = 1000 s, and the machine's temperature
    logged every 0.5 s (degrees Celsius, as sensor_msgs/Temperature carries it), rising
    by 0.01 K/s: each reading gets its temperature in kelvin, linear between the samples.
    A log in kelvin is refused as such; a log that stops early leaves the run without a
    temperature (said why), its time kept."""
    from types import SimpleNamespace

    from calib_core.errors import InvalidInputError
    from calib_core.temperature import temperature_log
    from grid_calib.core.records import regions_from_readings
    truth = default_travel(GRID, 1, 1, seed=3)
    messages = _reading_messages(truth)
    start = 1000.0
    for k, msg in enumerate(messages):
        msg.header = _stamped(start + 2.0 * k)
    end = start + 2.0 * len(messages)
    samples = [SimpleNamespace(header=_stamped(t), temperature=20.0 + 0.01 * (t - start))
               for t in np.arange(start - 5.0, end + 5.0, 0.5)]
    regions, notes = regions_from_readings(GRID, messages, temperature_log(samples[::-1]))
    assert notes == []
    for p in regions[0].placements:
        expected = 293.15 + 0.01 * p.covariates['time']
        assert np.abs(p.covariates['temperature'] - expected).max() < 1e-9
    for sample in samples:
        sample.temperature += 273.15
    with pytest.raises(InvalidInputError, match='kelvin where degrees Celsius were due'):
        temperature_log(samples)
    early = [s for s in samples if s.header.stamp.sec < start + 10.0]
    for sample in early:
        sample.temperature -= 273.15
    regions, notes = regions_from_readings(GRID, messages, temperature_log(early))
    # The last sample is at 1009.5 s: 35 of the 363 readings lie within 60 s of it.
    assert notes == ['temperature not attached: 328 measurement(s) lie more than 60 s from '
                     'every sample of the log']
    assert all(set(p.covariates) == {'time'} for p in regions[0].placements)


def test_a_plate_centred_between_sites_is_refused():
    readings = _readings()
    moved = {name: (marks, reading + [0.3 * GRID.pitch, 0.0])
             for name, (marks, reading) in readings.items()}
    with pytest.raises(PlacementError, match=r'\(3.0\d\d, 0.0\d\d\) mm from the nearest site'):
        region_from_readings(GRID, moved)


@pytest.mark.parametrize('method', ['joint', 'chained'])
def test_stitched_uncertainty_matches_the_monte_carlo_spread(method):
    """The per-site sigma of the stitched map (each region's noise drawn through its solve
    and the stitching) against the spread of 100 repeated runs of 2 x 2 regions of 5 x 5
    sites at 20 nm: the median ratio within 15 % (60 runs know a spread to 9 %, the
    prediction averages 3 datasets' noise estimates), 90 % of the sites within 0.65-1.4
    (measured: medians 1.00 and 1.03, 99 and 100 % of the sites). The report gives each
    site's sigma_x, sigma_y."""
    grid = Grid(half=2, pitch=0.01)
    truth = default_travel(grid, 2, 2, seed=3)

    def run(seed):
        return calibrate_travel(grid, {r: Region(truth.origins[r], p) for r, p in measure_travel(
            grid, truth, 20e-9, seed).items()}, method)
    predicted = np.mean([run(seed).stitched.uncertainty for seed in range(3)], axis=0)
    spread = np.std([run(100 + seed).stitched.stage_error for seed in range(60)], axis=0)
    ratio = spread / predicted
    assert 0.85 < np.median(ratio) < 1.15
    assert np.mean((ratio > 0.65) & (ratio < 1.4)) >= 0.9
    report = run(0).report()
    assert {'sigma_x', 'sigma_y'} <= set(report['sites'][0])
    assert 'draws through each region' in report['uncertainty']
