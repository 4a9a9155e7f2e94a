"""Compensation a controller loads, read back as the controller reads it (issue 33):
LinuxCNC's axis compensation file (COMP_FILE_TYPE = 1, triplets nominal / forward trim /
reverse trim in machine units, no header, at most 256 lines) from the closed loop on a
simulated ISO 230-2 test; applied as LinuxCNC applies it (the trim of the direction of
travel, linear between entries, added to the command), the axis then lands within its
repeatability where it missed by several um."""
import numpy as np
import pytest

from calib_core.axis import AxisModel, iso230_2_before_after
from calib_core.closed_loop import analyze
from calib_core.controller_formats import (
    linuxcnc_trim, read_gcode_moves, read_linuxcnc_comp, write_gcode_path, write_linuxcnc_comp)
from calib_core.errors import InvalidInputError
from calib_core.sim.axis import AxisTest, AxisTruth, simulate_axis_test

TRUTH = AxisTruth(backlash=6e-6, periodic_amplitude=2e-6, pitch=0.016)
# measured (mm): before 3.5 um (forward) and 9.1 um (reverse) RMS, after 0.09 and 0.10 um
TOLERANCE = {'after_rms_m': 0.5e-6, 'before_over_after': 5.0}


def _true_error(x, direction):
    """The simulated axis's true position error (m) at commands x (m), the noise aside."""
    t = TRUTH
    return (t.offset + t.scale * x - t.backlash / 2 * direction
            + t.periodic_amplitude * np.sin(2 * np.pi * x / t.pitch + t.periodic_phase))


@pytest.mark.parametrize('units, per_m', [('mm', 1e3), ('inch', 1 / 0.0254)])
def test_linuxcnc_file_compensates_the_axis_as_linuxcnc_applies_it(tmp_path, units, per_m):
    data = simulate_axis_test(TRUTH, AxisTest(), seed=3)
    model = AxisModel(data)
    table = iso230_2_before_after(model, analyze(model).fit)['compensation_table']
    path = tmp_path / 'x.comp'
    assert write_linuxcnc_comp(path, table, units) == len(table) <= 256
    text = path.read_text().splitlines()
    assert all(len(line.split()) == 3 for line in text)        # no header: it would end the read
    entries = read_linuxcnc_comp(path)
    assert len(entries) == len(table)
    x = np.random.default_rng(0).uniform(0.0, AxisTest().travel, 400)
    for direction, forward in ((1.0, True), (-1.0, False)):
        command = x + linuxcnc_trim(entries, x * per_m, forward) / per_m
        before = _true_error(x, direction)
        after = command + _true_error(command, direction) - x
        assert np.sqrt(np.mean(after ** 2)) < TOLERANCE['after_rms_m']
        assert np.sqrt(np.mean(before ** 2)) > TOLERANCE['before_over_after'] * np.sqrt(np.mean(after ** 2))


def test_type_zero_positions_read_as_trims_and_limits_are_refused(tmp_path):
    path = tmp_path / 'type0.comp'
    path.write_text('1.00 1.01 0.99\n2.00 2.00 2.02\nnot a triplet\n3.0 3.0 3.0\n')
    entries = read_linuxcnc_comp(path, comp_type=0)
    # LinuxCNC's reader: trim = nominal - position, and it stops at the first bad line.
    np.testing.assert_allclose(entries, [[1.0, -0.01, 0.01], [2.0, 0.0, -0.02]], atol=1e-12)
    with pytest.raises(InvalidInputError, match='at most 256'):
        write_linuxcnc_comp(path, [(i * 1e-3, 0.0, 0.0) for i in range(300)])
    with pytest.raises(InvalidInputError, match='machine units'):
        write_linuxcnc_comp(path, [(0.0, 0.0, 0.0)], 'furlong')


@pytest.mark.parametrize('units', ['mm', 'inch'])
def test_gcode_path_reads_back_in_m_and_rad(tmp_path, units):
    """A five-axis path written as RS274/NGC (G21/G20, rotary axes in degrees) reads back
    as a controller reads it, to the 6 decimals written; the first move is a rapid, F is
    given on the first feed move."""
    rng = np.random.default_rng(4)
    poses = np.column_stack([rng.uniform(-0.05, 0.05, (7, 3)), rng.uniform(-0.5, 0.5, 7),
                             rng.uniform(-3.0, 3.0, 7)])
    path = tmp_path / 'path.ngc'
    assert write_gcode_path(path, poses, 'XYZAC', units, 250.0, 'test path') == 7
    lines = path.read_text().splitlines()
    assert lines[2].startswith('G21' if units == 'mm' else 'G20')
    assert lines[3].startswith('G0 ') and lines[4].startswith('G1 ') and lines[4].endswith('F250')
    per_m = 1e3 if units == 'mm' else 1 / 0.0254
    assert float(lines[3].split()[1][1:]) == pytest.approx(poses[0, 0] * per_m, abs=1e-6)
    assert float(lines[3].split()[4][1:]) == pytest.approx(np.degrees(poses[0, 3]), abs=1e-6)
    # 6 decimals: 1e-6 mm or inch, 1e-6 degree (17 nrad)
    np.testing.assert_allclose(read_gcode_moves(path), poses, atol=2e-8)


def test_gcode_reader_is_modal_and_refuses_what_a_controller_would(tmp_path):
    path = tmp_path / 'hand.ngc'
    path.write_text('G21 G90 (a comment X99)\nG0 X1 Y2 Z3 A0 C0\nG1 X4 F100 ; rest\nY5\n')
    np.testing.assert_allclose(read_gcode_moves(path) * [1e3, 1e3, 1e3, 1, 1],
                               [[1, 2, 3, 0, 0], [4, 2, 3, 0, 0], [4, 5, 3, 0, 0]])
    path.write_text('G1 X1\n')
    with pytest.raises(InvalidInputError, match='G20/G21'):
        read_gcode_moves(path)
    for bad in ({'feed': 0.0}, {'units': 'furlong'}, {'axes': 'XYZAA'}):
        with pytest.raises(InvalidInputError):
            write_gcode_path(path, np.zeros((2, 5)), **bad)
    with pytest.raises(InvalidInputError, match='finite'):
        write_gcode_path(path, [[0, 0, 0, 0, np.nan]])


def test_a_dense_scan_is_analysed_and_its_linuxcnc_table_resampled(tmp_path):
    """A dense scan (600 rows, every one at its own position; issue 52: a 100 Hz run of
    4,303 rows had ended the analysis): `analyze axis`
    writes its report and JSON, and the LinuxCNC file with 256 entries whose trims match
    the full table's to within what linear interpolation loses on a 0.2 mm period-free
    error (under 0.05 um here), and says it resampled."""
    import json
    from machine_alignment.cli import main as cli_main
    rng = np.random.default_rng(5)
    count = 600
    command = np.linspace(0.0, 0.2, count) + rng.normal(0, 1e-6, count)
    direction = np.where(np.arange(count) < count // 2, 1.0, -1.0)
    measured = command + 20e-6 * command - 1.5e-6 * direction + rng.normal(0, 0.3e-6, count)
    data = tmp_path / 'scan.csv'
    np.savetxt(data, np.column_stack([command, measured, direction]), delimiter=',',
               header='command,measured,direction', comments='')
    report_path = tmp_path / 'scan.json'
    assert cli_main(['analyze', 'axis', '--data', str(data), '--json', str(report_path)]) == 0
    report = json.loads(report_path.read_text())
    assert report['linuxcnc_comp_resampled'].startswith('699 entries resampled to 256')
    entries = read_linuxcnc_comp(report['linuxcnc_comp_file'])
    assert len(entries) == 256
    full = np.genfromtxt(report['compensation_table'], delimiter=',', names=True)
    forward = np.interp(entries[:, 0] / 1e3, full['position'], full['correction_up'])
    assert np.max(np.abs(entries[:, 1] / 1e3 - forward)) < 0.05e-6
