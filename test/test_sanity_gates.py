"""Nothing wrong goes into force (issue 31): the declared column ranges refuse data in the
wrong unit with the column, the value and the likely mistake; the sanity gate refuses a fit
that cannot be the machine (nothing written); numeric options are range-checked when
parsed."""
import csv
import json

import numpy as np
import pytest

from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.schema import Column
from dispenser_calib.core.calibration import calibrate, check_calibration
from dispenser_calib.core.data import Image, read_observations
from machine_alignment.cli import main


def _rewrite(source, target, change):
    rows = list(csv.DictReader(open(source)))
    for row in rows:
        change(row)
    with open(target, 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


@pytest.fixture(scope='module')
def platform_poses(tmp_path_factory):
    folder = tmp_path_factory.mktemp('platform')
    assert main(['simulate', 'platform', '--out', str(folder / 'poses.csv'), '--poses', '20']) == 0
    return folder / 'poses.csv'


def test_column_names_the_likely_mistake():
    feed = Column('feed1', 'm', -0.01, 0.05, 'feed 1 reading')
    with pytest.raises(InvalidInputError, match='look like mm'):
        feed.check([0.01, 40.0], 'f.csv')                 # 40 mm written as 40
    with pytest.raises(InvalidInputError, match='another zero'):
        feed.check([0.01, -0.6], 'f.csv')                 # in m, from another zero
    angle = Column('theta', 'rad', -0.785, 0.785, 'platform angle')
    with pytest.raises(InvalidInputError, match=r'theta .* -5 rad in row 2.*degrees'):
        angle.check([0.01, -5.0], 'f.csv')
    angle.check([0.5, -0.5], 'f.csv')                     # inside: nothing said
    temperature = Column('temperature', 'K', 200.0, 400.0, 'temperature (kelvin)')
    with pytest.raises(InvalidInputError, match='look like degrees Celsius; the format is kelvin'):
        temperature.check([293.15, 21.5], 'f.csv')
    with pytest.raises(InvalidInputError, match='look like kelvin where degrees Celsius'):
        temperature.check([566.3], 'the temperature log')  # 293.15 K sent as degrees Celsius
    with pytest.raises(InvalidInputError, match='another zero'):
        temperature.check([1500.0], 'f.csv')


@pytest.mark.parametrize('change, expected', [
    (lambda r: r.update(theta=str(np.degrees(float(r['theta'])))), 'look like degrees'),
    (lambda r: r.update(feed1=str(float(r['feed1']) - 0.6)), 'column feed1'),
])
def test_platform_data_in_the_wrong_unit_are_refused(platform_poses, tmp_path, capsys,
                                                     change, expected):
    bad = tmp_path / 'bad.csv'
    _rewrite(platform_poses, bad, change)
    out = tmp_path / 'geometry.yaml'
    for command in (['calibrate', 'platform', '--data', str(bad), '--out', str(out)],
                    ['analyze', 'platform', '--data', str(bad)]):
        assert main(command) == 2
        assert expected in capsys.readouterr().err
    assert not out.exists()


def test_analyze_refuses_the_poses_calibrate_refuses(platform_poses, tmp_path, capsys):
    """Every row the same pose: calibrate refused it; analyze fitted it to 1e-4 um and
    reported 'added nothing' with exit 0."""
    first = next(csv.DictReader(open(platform_poses)))
    same = tmp_path / 'same.csv'
    _rewrite(platform_poses, same, lambda row: row.update(first))
    for command in ('calibrate', 'analyze'):
        assert main([command, 'platform', '--data', str(same)]) == 2
        assert 'the poses do not determine chain 1' in capsys.readouterr().err


def test_an_exactly_determined_platform_is_not_written(tmp_path, capsys):
    """6 poses for 18 parameters: every chain exactly determined, no standard deviation;
    the identification is printed but not written (it was put in force before)."""
    data = tmp_path / 'six.csv'
    assert main(['simulate', 'platform', '--out', str(data), '--poses', '6']) == 0
    out = tmp_path / 'six.yaml'
    assert main(['calibrate', 'platform', '--data', str(data), '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'failed its sanity checks' in err and 'no finite standard deviation' in err
    assert not out.exists()


def test_a_sound_platform_identification_passes(platform_poses, tmp_path):
    out = tmp_path / 'geometry.yaml'
    assert main(['calibrate', 'platform', '--data', str(platform_poses), '--out', str(out)]) == 0
    assert out.exists()


@pytest.fixture(scope='module')
def five_axis_images(tmp_path_factory):
    path = tmp_path_factory.mktemp('five_axis') / 'obs.csv'
    assert main(['simulate', 'five-axis', '--out', str(path)]) == 0
    return path


def test_five_axis_angles_in_degrees_are_refused(five_axis_images, tmp_path, capsys):
    bad = tmp_path / 'degrees.csv'
    _rewrite(five_axis_images, bad, lambda r: r.update(a=str(np.degrees(float(r['a']))),
                                                       c=str(np.degrees(float(r['c'])))))
    out = tmp_path / 'model.yaml'
    assert main(['calibrate', 'five-axis', '--data', str(bad), '--out', str(out)]) == 2
    assert 'look like degrees' in capsys.readouterr().err
    assert not out.exists()


def test_five_axis_in_mm_is_caught_by_the_gate_where_the_range_cannot(five_axis_images):
    """Linear moves of a few mm written in mm stay inside any plausible range, and the
    model absorbs the factor 1000 into M at 0.1 px: only M's scale shows it."""
    images = read_observations(five_axis_images)
    in_mm = [Image(im.name, np.concatenate([im.pose[:3] * 1000, im.pose[3:]]), im.indices,
                   im.pixels) for im in images]
    _, result = calibrate(in_mm, (2448, 2048))
    with pytest.raises(CalibrationError, match=r'linear-axis scale .* 0\.001'):
        check_calibration(result.model, result.report(in_mm))
    _, sound = calibrate(images, (2448, 2048))
    check_calibration(sound.model, sound.report(images))


@pytest.mark.parametrize('command', [
    ['simulate', 'gantry', '--out', 'x.csv', '--count', '0'],
    ['compensate', 'platform', '--count', '-3'],
    ['compensate', 'platform', '--iterations', '-1'],
    ['simulate', 'platform', '--out', 'x.csv', '--poses', '-5'],
    ['simulate', 'five-axis', '--out', 'x.csv', '--bad-fraction', '2'],
    ['simulate', 'five-axis', '--out', 'x.csv', '--noise', '-1'],
    ['simulate', 'platform', '--out', 'x.csv', '--scale', '-1'],
    ['simulate', 'grid', '--out', 'x.csv', '--half', '150'],
    ['analyze', 'rotary', '--data', 'x.csv', '--lever', '-0.1'],
    ['analyze', 'axis', '--data', 'x.csv', '--holdout', 'nan'],
    ['calibrate', 'grid', '--data', 'x.csv', '--pitch', '10'],
])
def test_numeric_options_out_of_range_are_refused_when_parsed(command, tmp_path, capsys,
                                                               monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(command)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert 'must be' in err or 'not a finite number' in err
    assert 'Traceback' not in err and not list(tmp_path.iterdir())


def test_hexapod_gate_refuses_a_geometry_far_from_the_machine(tmp_path, capsys):
    """The identification is fine; checked against another hexapod's drawing (every base
    joint 20 mm out) it is refused, and nothing is written."""
    import yaml
    folder = tmp_path / 'hx'
    assert main(['simulate', 'hexapod', '--out', str(folder), '--poses', '20']) == 0
    out = tmp_path / 'geometry.yaml'
    command = ['calibrate', 'hexapod', '--data', str(folder / 'calibration.csv'),
               '--geometry', str(folder / 'nominal.yaml'), '--out', str(out)]
    assert main(command) == 0 and out.exists()
    out.unlink()
    other = yaml.safe_load((folder / 'nominal.yaml').read_text())
    other['base_joints'] = (np.array(other['base_joints']) * 1.1).tolist()
    (folder / 'other.yaml').write_text(yaml.safe_dump(other))
    capsys.readouterr()
    assert main(command[:-3] + [str(folder / 'other.yaml'), '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'the hexapod identification failed its sanity checks' in err
    assert 'within 10 mm of the nominal' in err and not out.exists()


def test_stage_gate_refuses_marks_measured_with_a_wrong_pixel_size(tmp_path, capsys):
    """Marks 25 % too large (a camera calibration from another lens): the leads come out
    25 % long and the calibration is refused; the true data pass."""
    data = tmp_path / 'stage.csv'
    assert main(['simulate', 'stage', '--out', str(data)]) == 0
    assert main(['calibrate', 'stage', '--data', str(data)]) == 0
    scaled = tmp_path / 'scaled.csv'
    _rewrite(data, scaled, lambda row: row.update(
        {k: str(1.25 * float(v)) for k, v in row.items() if k.startswith('mark')}))
    capsys.readouterr()
    assert main(['calibrate', 'stage', '--data', str(scaled), '--json',
                 str(tmp_path / 'r.json')]) == 2
    err = capsys.readouterr().err
    assert 'the stage calibration failed its sanity checks' in err and 'stepwise R1' in err
    assert not (tmp_path / 'r.json').exists()


def test_vision_gate_checks_the_result_against_the_stated_camera_and_gantry():
    """The committed vision run passes; stated against a lens with 1.5x the pixel size or
    screws of twice the lead, the same result is refused with the parameter named."""
    from pathlib import Path

    from calib_core.bags import decode_bag
    from printer_alignment.core.geometry import CameraToPlate, GantryModel
    from printer_alignment.core.records import VISION_OBSERVATIONS_TOPIC
    from printer_alignment.core.vision_procedure import (
        calibrate_from_observations, check_vision_calibration, observation_from_message)
    bag = Path(__file__).resolve().parents[1] / 'bags' / 'vision_calibration_run'
    observations = [observation_from_message(m) for topic, _, m in decode_bag(bag)
                    if topic == VISION_OBSERVATIONS_TOPIC]
    report = calibrate_from_observations(observations, 0.5e-3).report
    camera, gantry = CameraToPlate(), GantryModel()
    check_vision_calibration(report, camera, gantry)
    with pytest.raises(CalibrationError, match=r'pixel_size = .*\(within 20% of the nominal\)'):
        check_vision_calibration(report, CameraToPlate(1.5 * camera.pixel_size), gantry)
    with pytest.raises(CalibrationError, match='lead_x = .*lead_y = '):
        check_vision_calibration(report, camera, GantryModel(2 * gantry.lead_x,
                                                             2 * gantry.lead_y))


def test_grid_gate_refuses_readings_no_rigid_plate_gives(tmp_path, capsys):
    """One placement's x readings stretched by 0.1 % (the plate slid while it was read):
    the fit leaves um residuals where the camera reads to tens of nm; refused, no report."""
    data = tmp_path / 'grid.csv'
    assert main(['simulate', 'grid', '--out', str(data), '--half', '2']) == 0
    assert main(['calibrate', 'grid', '--data', str(data), '--pitch', '0.01']) == 0
    stretched = tmp_path / 'stretched.csv'
    _rewrite(data, stretched, lambda row: row.update(
        x=str(float(row['x']) * 1.001)) if row['placement'] == 'rotated' else None)
    capsys.readouterr()
    report = tmp_path / 'report.json'
    assert main(['calibrate', 'grid', '--data', str(stretched), '--pitch', '0.01',
                 '--json', str(report)]) == 2
    err = capsys.readouterr().err
    assert 'the grid calibration failed its sanity checks' in err and 'rotated' in err
    assert not report.exists()


def test_a_gantry_with_other_screws_is_gated_by_its_own_nominal_leads():
    """The committed vision run as a gantry whose drive converts with 5 and 10 mm/rev
    screws would report it (its motor angles 3.2x and 4x the shipped ones): refused against
    the shipped 16 and 40 mm/rev (the fit, started there, does not reach the screws: 140 um
    of residual), accepted against its own, the same camera positions found; the report
    records the nominal it was held to, which the mark locator reads."""
    from pathlib import Path

    from calib_core.bags import decode_bag
    from printer_alignment.core.geometry import GantryModel
    from printer_alignment.core.records import VISION_OBSERVATIONS_TOPIC
    from printer_alignment.core.vision_calibration import GantryObservation
    from printer_alignment.core.vision_procedure import (
        calibrate_from_observations, observation_from_message)
    from printer_alignment.nodes.mark_locator import drive_leads
    bag = Path(__file__).resolve().parents[1] / 'bags' / 'vision_calibration_run'
    shipped = [observation_from_message(m) for topic, _, m in decode_bag(bag)
               if topic == VISION_OBSERVATIONS_TOPIC]
    ratio = np.array([0.016 / 0.005, 0.040 / 0.010])
    other = [GantryObservation(o.revs * ratio, o.uv) for o in shipped]
    with pytest.raises(CalibrationError, match='vision calibration failed its sanity checks'):
        calibrate_from_observations(other, 0.5e-3)
    own = calibrate_from_observations(other, 0.5e-3, nominal_gantry=GantryModel(0.005, 0.010))
    before = calibrate_from_observations(shipped, 0.5e-3)
    assert own.gantry.lead_x == pytest.approx(before.gantry.lead_x / ratio[0], rel=1e-6)
    assert own.report['nominal']['leads_m_per_rev'] == [0.005, 0.010]
    assert np.allclose(drive_leads(json.dumps(own.report)), [0.005, 0.010])
    assert np.allclose(drive_leads(''), [0.016, 0.040])
    with pytest.raises(InvalidInputError, match='not two positive values'):
        drive_leads(json.dumps({'nominal': {'leads_m_per_rev': [0.005, -1]}}))
