"""Datasets read in the units the instrument wrote them in: an ISO 230-2 run exported as
target (mm) and deviation (um), a gantry in mm, a rotary table's angles in degrees. Read
with their unit, they give what the same data in SI give; read as SI, they are refused
with the option that reads them named."""
import csv
import json

import numpy as np
import pytest

from calib_core.axis import AxisData
from calib_core.errors import InvalidInputError, UnitMistake
from calib_core.sim.axis import AxisTest, AxisTruth, simulate_axis_test
from machine_alignment.cli import main as cli_main
from printer_alignment.core.loop_models import GantryData


def _write(path, header, rows):
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)


@pytest.fixture
def axis_files(tmp_path):
    """One axis run with 4 um backlash: in m (the format), in mm, and as a laser's export
    of target in mm and deviation in um."""
    data = simulate_axis_test(AxisTruth(backlash=4e-6), AxisTest(targets=11, cycles=3), seed=5)
    error = data.measured - data.command
    files = {'m': tmp_path / 'axis_m.csv', 'mm': tmp_path / 'axis_mm.csv',
             'laser': tmp_path / 'axis_laser.csv'}
    _write(files['m'], ['command', 'measured', 'direction'],
           zip(data.command, data.measured, data.direction))
    _write(files['mm'], ['command', 'measured', 'direction'],
           zip(data.command * 1e3, data.measured * 1e3, data.direction))
    _write(files['laser'], ['command', 'error', 'direction'],
           zip(data.command * 1e3, error * 1e6, data.direction))
    return data, files


def test_an_axis_read_in_mm_or_as_target_and_deviation_is_the_axis_in_metres(axis_files):
    data, files = axis_files
    for read in (AxisData.from_csv(files['mm'], length_unit='mm'),
                 AxisData.from_csv(files['laser'], length_unit='mm', error_unit='um')):
        np.testing.assert_allclose(read.command, data.command, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(read.measured - read.command, data.measured - data.command,
                                   rtol=1e-9, atol=1e-15)
        assert 'error' not in read.covariates
    with pytest.raises(InvalidInputError, match='look like mm'):
        AxisData.from_csv(files['mm'])
    with pytest.raises(InvalidInputError, match="unit 'feet'"):
        AxisData.from_csv(files['mm'], length_unit='feet')


def test_the_loop_on_an_axis_in_mm_says_what_it_says_in_metres(axis_files, tmp_path, capsys):
    _, files = axis_files
    reports = {}
    for name, options in (('m', []), ('laser', ['--length-unit', 'mm', '--error-unit', 'um'])):
        out = tmp_path / f'{name}.json'
        assert cli_main(['analyze', 'axis', '--data', str(files[name]), '--json', str(out),
                         *options]) == 0
        reports[name] = json.loads(out.read_text())
    metres, laser = reports['m'], reports['laser']
    assert [e['name'] for e in laser['effects_added']] == \
        [e['name'] for e in metres['effects_added']] == ['reversal']
    backlash = [e['parameters']['backlash_axis'] for e in (metres['effects_added'][0],
                                                            laser['effects_added'][0])]
    assert backlash[1] == pytest.approx(backlash[0], rel=1e-6)
    assert abs(backlash[0]) == pytest.approx(4e-6, abs=0.5e-6)
    assert laser['data_units'] == {'length': 'mm', 'error': 'um'}
    # Read as SI, the mm file is refused, naming the option that reads it.
    capsys.readouterr()
    assert cli_main(['analyze', 'axis', '--data', str(files['mm'])]) != 0
    assert '--length-unit mm' in capsys.readouterr().err


def test_the_command_lines_units_are_the_readers(tmp_path):
    from calib_core.description import LENGTH_UNITS
    from machine_alignment.cli.analyze import LENGTH_UNITS as OFFERED
    assert set(OFFERED) == set(LENGTH_UNITS)


def test_an_axis_file_with_both_measured_and_error_is_refused(tmp_path):
    path = tmp_path / 'both.csv'
    _write(path, ['command', 'measured', 'error', 'direction'], [(0.0, 0.0, 0.0, 1.0)])
    with pytest.raises(InvalidInputError, match='this one has both'):
        AxisData.from_csv(path)
    _write(path, ['command', 'direction'], [(0.0, 1.0)])
    with pytest.raises(InvalidInputError, match='this one has neither'):
        AxisData.from_csv(path)


def test_a_gantry_in_mm_and_a_rotary_table_in_degrees(tmp_path):
    rng = np.random.default_rng(3)
    command = rng.uniform(0, 0.2, (20, 2))
    measured = command + rng.normal(0, 2e-6, command.shape)
    metres, millimetres = tmp_path / 'gantry_m.csv', tmp_path / 'gantry_mm.csv'
    header = ['command_x', 'command_y', 'measured_x', 'measured_y']
    _write(metres, header, np.column_stack([command, measured]))
    _write(millimetres, header, np.column_stack([command, measured]) * 1e3)
    si, read = GantryData.from_csv(metres), GantryData.from_csv(millimetres, length_unit='mm')
    np.testing.assert_allclose(read.command, si.command, rtol=1e-12)
    np.testing.assert_allclose(read.measured - read.command, si.measured - si.command,
                               rtol=1e-8, atol=1e-15)
    with pytest.raises(InvalidInputError, match='look like mm'):
        GantryData.from_csv(millimetres)

    from dispenser_calib.core.target_poses import read_target_poses
    angles = np.column_stack([rng.uniform(-1.5, 1.5, 8), rng.uniform(-3, 3, 8)])
    pose = [0.1, 0.02, 0.3, 1.0, 0.0, 0.0, 0.0]
    radians, degrees = tmp_path / 'rotary_rad.csv', tmp_path / 'rotary_deg.csv'
    header = ['a', 'c', 'x', 'y', 'z', 'qw', 'qx', 'qy', 'qz']
    _write(radians, header, [[*row, *pose] for row in angles])
    _write(degrees, header, [[*np.degrees(row), *pose] for row in angles])
    si, read = read_target_poses(radians), read_target_poses(degrees, angle_unit='deg')
    np.testing.assert_allclose([read.a, read.c], [si.a, si.c], rtol=1e-12)
    with pytest.raises(UnitMistake, match='degrees given') as refused:
        read_target_poses(degrees)
    assert (refused.value.quantity, refused.value.likely_unit) == ('angle', 'deg')


def test_the_unit_a_refusal_names_travels_with_it_and_only_its_own_option_is_offered(
        tmp_path, capsys):
    """A refusal carries the unit the values look like (UnitMistake), and the command
    line offers the option that reads that quantity in it: mm for a length, not for a
    temperature in degrees Celsius, for which no machine description or unit option is
    the answer (the grid's calibrate had offered one)."""
    from calib_core.schema import Column
    with pytest.raises(UnitMistake) as refused:
        Column('x', 'm', -1.0, 1.0, 'reading').check([0.1, 40.0], 'f.csv')
    assert (refused.value.quantity, refused.value.likely_unit) == ('length', 'mm')
    with pytest.raises(UnitMistake) as refused:
        Column('temperature', 'K', 200.0, 400.0, 'temperature').check([21.5], 'f.csv')
    assert (refused.value.quantity, refused.value.likely_unit) == ('temperature', 'degC')
    with pytest.raises(InvalidInputError) as refused:
        Column('feed1', 'm', -0.01, 0.05, 'feed reading').check([0.01, -0.6], 'f.csv')
    assert not isinstance(refused.value, UnitMistake)    # in m from another zero, not mm

    marks = tmp_path / 'marks_celsius.csv'
    _write(marks, ['region', 'placement', 'i', 'j', 'x', 'y', 'temperature'],
           [[0, placement, i, j, 0.01 * i + shift, 0.01 * j, 21.5]
            for placement, shift in (('initial', 0.0), ('shifted', 0.01))
            for i in range(-2, 3) for j in range(-2, 3)])
    capsys.readouterr()
    assert cli_main(['calibrate', 'grid', '--data', str(marks), '--pitch', '0.01']) != 0
    said = capsys.readouterr().err
    assert 'degrees Celsius' in said and '--description' not in said, said
    gantry = tmp_path / 'gantry_mm.csv'
    _write(gantry, ['command_x', 'command_y', 'measured_x', 'measured_y'],
           [[100.0 * k, 50.0, 100.0 * k + 0.002, 50.0] for k in range(12)])
    assert cli_main(['analyze', 'gantry', '--data', str(gantry)]) != 0
    assert '--length-unit mm' in capsys.readouterr().err


def test_a_direction_written_as_a_word_reads_as_its_sign(axis_files, tmp_path):
    """A laser system's export may write the direction of approach as "+" / "-" or
    "forward" / "reverse": read as +1 / -1, the run is the same run; a word that is no
    direction is refused, naming what is read."""
    data, files = axis_files
    words = {1.0: ['+', 'Forward'], -1.0: ['-', 'reverse']}
    for k in range(2):
        path = tmp_path / f'words_{k}.csv'
        _write(path, ['command', 'measured', 'direction'],
               [(c, m, words[d][k]) for c, m, d in zip(data.command, data.measured,
                                                         data.direction)])
        read = AxisData.from_csv(path)
        np.testing.assert_array_equal(read.direction, data.direction)
        np.testing.assert_array_equal(read.measured, data.measured)
    path = tmp_path / 'sideways.csv'
    _write(path, ['command', 'measured', 'direction'], [(0.0, 0.0, 'sideways')])
    with pytest.raises(InvalidInputError, match=r"direction='sideways' is not a number nor a "
                                                r"direction \(\+1 / -1, \+ / -"):
        AxisData.from_csv(path)


def test_a_spreadsheets_or_an_instruments_csv_reads_as_the_plain_one(axis_files, tmp_path):
    """What spreadsheets and instruments write around the numbers: a byte-order mark (Excel's
    "CSV UTF-8"), semicolons with decimal commas (a European locale), tabs, CRLF line ends
    and '#' notes above and between the rows; numpy.savetxt's header, written as a note.
    Each reads as the plain file."""
    from calib_core.files import read_csv_rows
    data, files = axis_files
    plain = files['m'].read_text()
    lines = plain.splitlines()
    variants = {
        'bom': ('\ufeff' + plain, 'utf-8'),
        'semicolons': ('\n'.join([lines[0].replace(',', ';')] + [
            line.replace(',', ';').replace('.', ',') for line in lines[1:]]) + '\n', 'utf-8'),
        'tabs': (plain.replace(',', '\t').replace('\n', '\r\n'), 'utf-8'),
        'notes': ('# laser export, target and deviation\n# units: m\n' + '\n'.join(
            lines[:5] + ['# cycle 2'] + lines[5:]) + '\n', 'utf-8')}
    saved = tmp_path / 'savetxt.csv'
    np.savetxt(saved, np.column_stack([data.command, data.measured, data.direction]),
               delimiter=',', header='command,measured,direction')
    variants['numpy.savetxt'] = (saved.read_text(), 'utf-8')
    for name, (text, encoding) in variants.items():
        path = tmp_path / f'{name}.csv'
        path.write_bytes(text.encode(encoding))
        read = AxisData.from_csv(path)
        np.testing.assert_array_equal(read.command, data.command, err_msg=name)
        np.testing.assert_array_equal(read.measured, data.measured, err_msg=name)
        np.testing.assert_array_equal(read.direction, data.direction, err_msg=name)
        rows = read_csv_rows(path, 'an axis CSV', ('command', 'measured', 'direction'))
        assert len(rows) == len(data.command) and set(rows[0]) == {'command', 'measured',
                                                                    'direction'}, name


def test_analyze_names_the_machine_description_for_actuators_read_in_mm(tmp_path, capsys):
    """Legs written in mm to a hexapod's pose file, read as SI: analyze, like calibrate,
    says that a machine description declares the actuators' unit."""
    assert cli_main(['simulate', 'hexapod', '--out', str(tmp_path / 'hx'), '--poses', '20']) == 0
    rows = list(csv.DictReader(open(tmp_path / 'hx' / 'calibration.csv')))
    legs = [f'l{i}' for i in range(1, 7)]
    assert all(name in rows[0] for name in legs)
    for row in rows:
        row.update({name: str(float(row[name]) * 1e3) for name in legs})
    path = tmp_path / 'legs_mm.csv'
    _write(path, list(rows[0]), [list(row.values()) for row in rows])
    capsys.readouterr()
    for command in ('analyze', 'calibrate'):
        assert cli_main([command, 'hexapod', '--data', str(path), '--geometry',
                         str(tmp_path / 'hx' / 'nominal.yaml')]) != 0
        said = capsys.readouterr().err
        assert 'look like mm' in said and '--description' in said, (command, said)


def test_a_cameras_target_in_mm_is_the_target_in_metres(tmp_path, capsys):
    """Correspondences whose target points are written in mm: read with --length-unit mm,
    the loop and the calibration say what they say of the file in metres; read as SI, they
    are refused with the option named."""
    metres, millimetres = tmp_path / 'camera_m.csv', tmp_path / 'camera_mm.csv'
    assert cli_main(['simulate', 'camera', '--out', str(metres), '--views', '6']) == 0
    rows = list(csv.DictReader(open(metres)))
    for row in rows:
        row.update({k: str(float(row[k]) * 1e3) for k in ('model_x', 'model_y')})
    _write(millimetres, list(rows[0]), [list(row.values()) for row in rows])
    reports = {}
    for name, path, options in (('m', metres, []), ('mm', millimetres, ['--length-unit', 'mm'])):
        out = tmp_path / f'{name}.json'
        assert cli_main(['analyze', 'camera', '--data', str(path), '--json', str(out),
                         *options]) == 0
        reports[name] = json.loads(out.read_text())
        out = tmp_path / f'{name}_calibration.json'
        assert cli_main(['calibrate', 'camera', '--data', str(path), '--json', str(out),
                         *options]) == 0
        reports[name + ' calibration'] = json.loads(out.read_text())
    # The same to a hundredth of each parameter's standard deviation: the points in mm
    # times 1e-3 are not the file's metres to the last bit.
    added = {name: {e['name']: e for e in reports[name]['effects_added']} for name in ('m', 'mm')}
    assert list(added['mm']) == list(added['m']) == ['radial_distortion']
    si, read = added['m']['radial_distortion'], added['mm']['radial_distortion']
    for key, sigma in si['std_devs'].items():
        assert abs(read['parameters'][key] - si['parameters'][key]) < 0.01 * sigma, key
    assert reports['mm']['rms_after'] == pytest.approx(reports['m']['rms_after'], rel=1e-3)
    si, read = reports['m calibration'], reports['mm calibration']
    for key, sigma in si['std_devs'].items():
        assert abs(read['parameters'][key] - si['parameters'][key]) < 0.01 * sigma, key
    capsys.readouterr()
    for command in ('analyze', 'calibrate'):
        assert cli_main([command, 'camera', '--data', str(millimetres)]) != 0
        assert '--length-unit mm' in capsys.readouterr().err, command
