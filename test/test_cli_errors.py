"""Bad input to the command line: every case ends in one line ``machine-align: error: ...``
naming the file or option and the cause, exit status 2, no traceback, and nothing is
computed for an output that cannot be written. The cases are the ones a tester found
ending in tracebacks (issue 19)."""
import csv
import os
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from machine_alignment.cli import main

BAGS = Path(__file__).resolve().parents[1] / 'bags'
REAL_POSES = Path(__file__).resolve().parent / 'data' / 'measured' / \
    'ric_two_axis_positioner' / 'positioner_poses.csv'


def _files(tmp_path: Path, rng) -> dict:
    binary = tmp_path / 'binary.csv'
    binary.write_bytes(rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
    latin1 = tmp_path / 'latin1.csv'
    latin1.write_bytes('command,measured,direction\n0.0,0.0,1\n# caf\xe9\n'.encode('latin-1'))
    nul = tmp_path / 'nul.yaml'
    nul.write_bytes(b'base:\x00\x00\x01')
    folder = tmp_path / 'a_folder'
    folder.mkdir()
    blocker = tmp_path / 'blocker.txt'
    blocker.write_text('a file where a folder is needed\n')
    axis = tmp_path / 'axis.csv'
    assert main(['simulate', 'axis', '--out', str(axis), '--targets', '8', '--cycles', '2']) == 0
    geometry = tmp_path / 'hx'
    assert main(['simulate', 'hexapod', '--out', str(geometry), '--poses', '13',
                 '--evaluation', '1']) == 0
    stage = tmp_path / 'stage.csv'
    assert main(['simulate', 'stage', '--out', str(stage)]) == 0
    camera = tmp_path / 'camera_mm.csv'
    camera.write_text('view,model_x,model_y,u,v\n' + ''.join(
        f'{k // 9},{30.0 * (k % 3)},{30.0 * (k // 3 % 3)},{100 + 40 * (k % 3)},{90 + 40 * (k // 3 % 3)}\n'
        for k in range(27)))
    mm = tmp_path / 'mm'
    mm.mkdir()
    _in_mm(axis, mm / 'axis.csv', ('command', 'measured'))
    _in_mm(stage, mm / 'stage.csv', ('q1', 'q2', 'q3', 'mark1_x', 'mark1_y', 'mark2_x', 'mark2_y'))
    _in_mm(geometry / 'calibration.csv', mm / 'poses.csv',
           ('x', 'y', 'z', 'meas_x', 'meas_y', 'meas_z', 'l1', 'l2', 'l3', 'l4', 'l5', 'l6'))
    nominal = yaml.safe_load((geometry / 'nominal.yaml').read_text())
    for key in ('base_joints', 'platform_joints'):
        nominal[key] = (np.array(nominal[key]) * 1e3).tolist()
    (mm / 'nominal.yaml').write_text(yaml.safe_dump(nominal))
    grid, platform, five_axis = tmp_path / 'grid.csv', tmp_path / 'platform.csv', \
        tmp_path / 'five_axis.csv'
    assert main(['simulate', 'grid', '--out', str(grid), '--half', '2']) == 0
    assert main(['simulate', 'platform', '--out', str(platform), '--poses', '20']) == 0
    assert main(['simulate', 'five-axis', '--out', str(five_axis), '--features',
                 str(tmp_path / 'views.csv'), '--needle', str(tmp_path / 'dots.csv')]) == 0
    from dispenser_calib.core.model import nominal_model, write_model
    write_model(tmp_path / 'five_axis_nominal.yaml', nominal_model())
    _in_mm(tmp_path / 'views_cad.csv', mm / 'cad.csv', ('x_m', 'y_m', 'z_m'))
    _in_mm(tmp_path / 'dots_dispensed.csv', mm / 'dispensed.csv', ('x_m', 'y_m', 'z_m'))
    _changed(grid, mm / 'grid_turned.csv', {'placement': lambda v, k: 'turned' if k == 0 else v})
    _changed(grid, mm / 'grid_301.csv',
             {'i': lambda v, k: {0: '150', 1: '-150'}.get(k, v)})
    _changed(platform, mm / 'platform_degrees.csv',
             {'theta': lambda v, k: str(float(np.degrees(float(v))))})
    _changed(platform, mm / 'platform_same.csv', {})
    _changed(five_axis, mm / 'five_axis_degrees.csv',
             {'a': lambda v, k: str(float(np.degrees(float(v)))),
              'c': lambda v, k: str(float(np.degrees(float(v))))})
    _changed(five_axis, mm / 'five_axis_mm.csv',
             {name: lambda v, k: repr(float(v) * 1e3) for name in 'xyz'})
    (mm / 'five_axis_plan.csv').write_text('stop,x_m,y_m,z_m,a_rad,c_rad\n'
                                           'linear_01,6.0,5.0,0.0,0.0,0.0\n')
    (mm / 'stage_plan.csv').write_text('q1,q2,q3\n0,0,0\n4.75,0,0\n')
    (mm / 'stage_plan_away.csv').write_text('q1,q2,q3\n0.001,0,0\n0,0,0\n')
    rotary = REAL_POSES.read_text().splitlines()
    (mm / 'rotary_degrees.csv').write_text('\n'.join([rotary[0]] + [
        ','.join(str(float(np.degrees(float(c)))) if j in (1, 2) else c
                 for j, c in enumerate(row.split(','))) for row in rotary[1:]]) + '\n')
    return {'binary': binary, 'latin1': latin1, 'nul': nul, 'folder': folder,
            'blocker': blocker, 'axis': axis, 'hx': geometry, 'mm': mm, 'camera_mm': camera,
            'grid': grid, 'platform': platform, 'five_axis': five_axis, 'dir': tmp_path}


def _changed(source: Path, target: Path, change: dict) -> None:
    """``source`` CSV with ``change[column](value, row number)`` applied; with no change,
    every row replaced by the first."""
    rows = list(csv.DictReader(open(source)))
    if not change:
        rows = [rows[0]] * len(rows)
    with open(target, 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        for k, row in enumerate(rows):
            writer.writerow({c: change[c](v, k) if c in change else v for c, v in row.items()})


def _in_mm(source: Path, target: Path, lengths) -> None:
    """``source`` CSV with the ``lengths`` columns written in mm instead of m."""
    rows = source.read_text().splitlines()
    header = rows[0].split(',')
    scaled = [header.index(name) for name in lengths if name in header]
    out = [rows[0]]
    for row in rows[1:]:
        cells = row.split(',')
        for j in scaled:
            cells[j] = repr(float(cells[j]) * 1e3)
        out.append(','.join(cells))
    target.write_text('\n'.join(out) + '\n')


CASES = {
    'binary CSV': (['analyze', 'axis', '--data', '{binary}'], 'not UTF-8 text'),
    'non-UTF-8 CSV': (['analyze', 'axis', '--data', '{latin1}'], 'not UTF-8 text'),
    'binary stage CSV': (['calibrate', 'stage', '--data', '{binary}'], 'binary.csv'),
    'folder as --data': (['analyze', 'axis', '--data', '{folder}'], 'is a directory'),
    'folder as --geometry': (['calibrate', 'hexapod', '--data', '{hx}/calibration.csv',
                              '--geometry', '{folder}'], 'is a directory'),
    'binary geometry': (['calibrate', 'hexapod', '--data', '{hx}/calibration.csv',
                         '--geometry', '{nul}'], 'NUL bytes'),
    'binary --markers': (['calibrate', 'camera', '--images', '{binary}', '--target', 'uchiya',
                          '--markers', '{binary}'], 'not UTF-8 text'),
    'vision bag as a stage run': (['calibrate', 'stage', '--bag',
                                   str(BAGS / 'vision_calibration_run')], 'another kind'),
    'stage bag as a vision run': (['calibrate', 'vision', '--bag',
                                   str(BAGS / 'stage_calibration_run')], 'another kind'),
    'hexapod bag as a camera run': (['calibrate', 'camera', '--bag',
                                     str(BAGS / 'hexapod_calibration_run')], 'another kind'),
    '--image-size 0x0': (['analyze', 'camera', '--data', '{axis}', '--image-size', '0x0'],
                         'must be positive'),
    '--json under a file': (['analyze', 'axis', '--data', '{axis}', '--json',
                             '{blocker}/report.json'], 'cannot create its folder'),
    '--json is a folder': (['analyze', 'axis', '--data', '{axis}', '--json', '{folder}'],
                           'is a folder'),
    '--payload nan': (['analyze', 'hexapod', '--data', '{hx}/calibration.csv', '--geometry',
                       '{hx}/nominal.yaml', '--payload', 'nan', '0', '0', '0.1'],
                      'positive and finite'),
    'negative payload': (['analyze', 'hexapod', '--data', '{hx}/calibration.csv', '--geometry',
                          '{hx}/nominal.yaml', '--payload', '-5', '0', '0', '0.1'],
                         'positive and finite'),
    'axis CSV in mm': (['analyze', 'axis', '--data', '{mm}/axis.csv'], 'look like mm'),
    'stage CSV in mm': (['calibrate', 'stage', '--data', '{mm}/stage.csv'], 'look like mm'),
    'pose CSV in mm': (['calibrate', 'hexapod', '--data', '{mm}/poses.csv', '--geometry',
                        '{hx}/nominal.yaml'], 'look like mm'),
    'geometry in mm': (['calibrate', 'hexapod', '--data', '{hx}/calibration.csv', '--geometry',
                        '{mm}/nominal.yaml'], 'look like mm'),
    'camera points in mm': (['calibrate', 'camera', '--data', '{camera_mm}'], 'look like mm'),
    'grid placement misspelt': (['calibrate', 'grid', '--data', '{mm}/grid_turned.csv',
                                 '--pitch', '0.01'], 'unknown placement(s) turned'),
    'grid plate of 301 x 301 marks': (['calibrate', 'grid', '--data', '{mm}/grid_301.csv',
                                       '--pitch', '0.01'], 'beyond the 101 x 101'),
    'grid --pitch in mm': (['calibrate', 'grid', '--data', '{grid}', '--pitch', '10'],
                           'the format is SI metres'),
    'platform theta in degrees': (['calibrate', 'platform', '--data',
                                   '{mm}/platform_degrees.csv'], 'look like degrees'),
    'platform theta in degrees, analyze': (['analyze', 'platform', '--data',
                                            '{mm}/platform_degrees.csv'], 'look like degrees'),
    'platform poses all equal': (['calibrate', 'platform', '--data',
                                  '{mm}/platform_same.csv'], 'do not determine chain 1'),
    'platform poses all equal, analyze': (['analyze', 'platform', '--data',
                                           '{mm}/platform_same.csv'],
                                          'do not determine chain 1'),
    'platform --poses 0': (['simulate', 'platform', '--out', '{folder}/p.csv', '--poses', '0'],
                           '--poses'),
    'five-axis angles in degrees': (['calibrate', 'five-axis', '--data',
                                     '{mm}/five_axis_degrees.csv'], 'look like degrees'),
    'five-axis x, y, z in mm': (['calibrate', 'five-axis', '--data', '{mm}/five_axis_mm.csv'],
                                'column x (commanded X axis)'),
    'five-axis plan in mm': (['simulate', 'five-axis', '--plan', '{mm}/five_axis_plan.csv',
                              '--out', '{folder}/f.csv'], 'column x (commanded X axis)'),
    'five-axis --plan with --sweep': (['simulate', 'five-axis', '--plan',
                                       '{mm}/five_axis_plan.csv', '--sweep', '--out',
                                       '{folder}/f.csv'], 'give one'),
    'five-axis plan for a tiny image': (['plan', 'five-axis', '--stops', '20', '--image-size',
                                         '100x100', '--out', '{folder}/plan.csv'],
                                        '0 candidates'),
    'rotary angles in degrees': (['analyze', 'rotary', '--data', '{mm}/rotary_degrees.csv',
                                  '--a-column', 'j1', '--c-column', 'j2'], 'degrees'),
    'part CAD in mm': (['locate', '--calibration', '{dir}/five_axis_nominal.yaml', '--data',
                        '{dir}/views.csv', '--cad', '{mm}/cad.csv'], 'was it written in mm'),
    'locate --path without --tip': (['locate', '--calibration', '{dir}/five_axis_nominal.yaml',
                                     '--data', '{dir}/views.csv', '--cad', '{dir}/views_cad.csv',
                                     '--path', '{dir}/views_path.csv'], 'needs --tip'),
    'needle dispensed poses in mm': (['needle', '--calibration', '{dir}/five_axis_nominal.yaml',
                                      '--data', '{dir}/dots.csv', '--dispensed',
                                      '{mm}/dispensed.csv'], 'column x (commanded X axis)'),
    'call --csv on a calibration': (['call', 'platform_calibrator/calibrate', '--csv',
                                     '{folder}/p.csv'], 'five_axis_calibrator/locate only'),
    'payload centre in mm': (['analyze', 'hexapod', '--data', '{hx}/calibration.csv',
                              '--geometry', '{hx}/nominal.yaml', '--payload', '25', '30',
                              '-20', '80'], 'look like mm'),
    'stage plan in mm': (['simulate', 'stage', '--plan', '{mm}/stage_plan.csv', '--out',
                          '{dir}/stage.csv'], 'mm'),
    'stage plan not from home': (['simulate', 'stage', '--plan', '{mm}/stage_plan_away.csv',
                                  '--out', '{dir}/stage.csv'], 'starts at home'),
    'plan stage --stops 0': (['plan', 'stage', '--stops', '0', '--out', '{dir}/plan.csv'],
                             '--stops'),
}


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    return _files(tmp_path_factory.mktemp('bad_input'), np.random.default_rng(19))


def _run(argv, capsys) -> tuple[int, str]:
    capsys.readouterr()
    try:
        status = main(argv)
    except SystemExit as exc:          # refused by argparse when parsed
        status = exc.code
    return status, capsys.readouterr().err


TABLE_START = '<!-- bad-input table: written by test/test_cli_errors.py -->'
TABLE_END = '<!-- end of the bad-input table -->'
ROBUSTNESS = Path(__file__).resolve().parents[1] / 'docs' / 'robustness.md'


def test_bad_input_is_one_clear_line_and_exit_2(files, capsys):
    """Every case: exit 2, one error line that says the expected words, no traceback, no
    numpy repr. The table of docs/robustness.md is this test's output: it fails when the
    two differ (MACHINE_ALIGN_WRITE_DOCS=1 rewrites it)."""
    rows, failures = [], []
    for case in sorted(CASES):
        argv, expected = CASES[case]
        status, err = _run([a.format(**files) for a in argv], capsys)
        lines = [line for line in err.splitlines()
                 if re.match(r'machine-align[\w -]*: error: ', line)]
        if not (status == 2 and len(lines) == 1 and expected in lines[0]
                and 'Traceback' not in err and not re.search(r'np\.\w+\(|array\(', err)):
            failures.append(f'{case}: exit {status}: {err}')
        message = lines[0].split(': error: ', 1)[1] if lines else err.strip()
        for name, path in sorted(files.items(), key=lambda item: -len(str(item[1]))):
            message = message.replace(str(path), f'{{{name}}}')
        row = (f'| {case} | `machine-align {" ".join(argv)}` | {status} | '
               f'{message.replace("|", "/")} |')
        rows.append(row.replace(f'{BAGS.parent}/', ''))    # the same wherever the clone is
    assert not failures, '\n'.join(failures)
    table = '\n'.join([
        TABLE_START,
        f'{len(CASES)} bad inputs, each refused with exit 2 and one line; 0 tracebacks, 0 '
        'internal errors (exit 3), 0 accepted. Files in braces are the test\'s '
        '(`test/test_cli_errors.py`).', '',
        '| case | command | exit | message |', '|---|---|---|---|', *rows, TABLE_END])
    text = ROBUSTNESS.read_text()
    before, rest = text.split(TABLE_START, 1)
    written = before + table + rest.split(TABLE_END, 1)[1]
    if os.environ.get('MACHINE_ALIGN_WRITE_DOCS'):
        ROBUSTNESS.write_text(written)
    assert written == text, 'docs/robustness.md differs from the bad-input table: run ' \
        'MACHINE_ALIGN_WRITE_DOCS=1 pytest test/test_cli_errors.py -k bad_input'


def test_output_that_cannot_be_written_fails_before_the_work(files, capsys, monkeypatch):
    from machine_alignment.cli import analyze_run as analyze
    ran = []
    monkeypatch.setattr(analyze, 'analyze', lambda *a, **k: ran.append(1))
    assert main(['analyze', 'axis', '--data', str(files['axis']), '--json',
                 str(files['blocker'] / 'report.json')]) == 2
    assert ran == []


def test_detect_on_a_missing_image_is_exit_2_without_an_opencv_warning(tmp_path, capfd):
    assert main(['detect', str(tmp_path / 'missing.png')]) == 2
    out, err = capfd.readouterr()
    assert 'no such file' in out and 'WARN' not in err and 'machine-align: error:' in err


def test_sigterm_to_the_launcher_stops_every_node(tmp_path):
    """`machine-align launch` stopped by SIGTERM (kill, a service manager) stops its nodes
    and waits for them: none is left running."""
    import os
    import signal
    import subprocess
    import sys
    import time
    launcher = subprocess.Popen(
        [sys.executable, '-m', 'machine_alignment.cli', 'launch', 'hexapod', '--output-dir',
         str(tmp_path / 'calibration'), '--record-dir', str(tmp_path / 'runs')],
        stdout=subprocess.PIPE, text=True,
        env={**os.environ, 'ROS_DOMAIN_ID': str(210 + os.getpid() % 20)})
    children_file = Path(f'/proc/{launcher.pid}/task/{launcher.pid}/children')
    deadline, children = time.monotonic() + 30, []
    while time.monotonic() < deadline and len(children) < 3:
        children = children_file.read_text().split() if children_file.exists() else []
        time.sleep(0.2)
    assert len(children) == 3, 'the three hexapod nodes did not start'
    assert 'running' in launcher.stdout.readline()
    launcher.send_signal(signal.SIGTERM)
    assert launcher.wait(30) == 0
    assert not [pid for pid in children if Path(f'/proc/{pid}').exists()]
