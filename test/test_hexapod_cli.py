"""machine-align simulate / calibrate / evaluate hexapod, and bad input to them."""
import json

import numpy as np
import pytest

from machine_alignment.cli import main
from hexapod_calib.core.geometry import read_geometry


@pytest.fixture(scope='module')
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp('hexapod_cli')
    assert main(['simulate', 'hexapod', '--out', str(out), '--poses', '25',
                 '--evaluation', '20', '--seed', '2']) == 0
    return out


def test_calibrate_then_evaluate_on_separate_poses(dataset, capsys):
    out = dataset
    assert main(['calibrate', 'hexapod', '--data', str(out / 'calibration.csv'), '--geometry',
                 str(out / 'nominal.yaml'), '--out', str(out / 'calibrated.yaml'),
                 '--json', str(out / 'report.json')]) == 0
    report = json.loads((out / 'report.json').read_text())
    assert len(report['parameters']) == 42 and report['num_poses'] == 25
    calibrated = read_geometry(out / 'calibrated.yaml')
    truth = read_geometry(out / 'truth.yaml')
    z = [(calibrated.parameters()[k] - v) / report['std_devs'][k]
         for k, v in truth.parameters().as_dict().items()]
    assert np.mean(np.abs(z) < 3) >= 0.85
    assert main(['evaluate', 'hexapod', '--data', str(out / 'evaluation.csv'), '--geometry',
                 str(out / 'calibrated.yaml'), '--json', str(out / 'evaluation.json')]) == 0
    evaluation = json.loads((out / 'evaluation.json').read_text())
    assert evaluation['commanded_vs_measured']['max_displacement_m'] > 0.2e-3
    assert evaluation['model_vs_measured']['max_displacement_m'] < 12.1e-6
    assert evaluation['model_vs_measured']['max_angle_rad'] < 1.1e-3
    assert 'model vs measured' in capsys.readouterr().out


def _rewrite(source, target, edit):
    lines = source.read_text().splitlines()
    target.write_text('\n'.join(edit(lines)) + '\n')


@pytest.mark.parametrize('case, message', [
    ('missing_column', 'lacks column(s) meas_z'),
    ('nan', 'NaN'),
    ('too_few', '5 poses give 30 equations for 42 parameters'),
    ('some_legs', 'needs all of l1..l6'),
])
def test_bad_pose_files_are_refused_and_nothing_written(dataset, tmp_path, capsys, case, message):
    source, bad = dataset / 'calibration.csv', tmp_path / 'bad.csv'
    if case == 'missing_column':
        _rewrite(source, bad, lambda lines: [line.replace('meas_z', 'meas_zz', 1) for line in lines])
    elif case == 'nan':
        def put_nan(lines):
            fields = lines[3].split(',')
            fields[7] = 'nan'
            return lines[:3] + [','.join(fields)] + lines[4:]
        _rewrite(source, bad, put_nan)
    elif case == 'too_few':
        _rewrite(source, bad, lambda lines: lines[:6])
    else:
        _rewrite(source, bad, lambda lines: [','.join(line.split(',')[:-2]) for line in lines])
    out = tmp_path / 'calibrated.yaml'
    code = main(['calibrate', 'hexapod', '--data', str(bad), '--geometry',
                 str(dataset / 'nominal.yaml'), '--out', str(out), '--json', str(tmp_path / 'r.json')])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / 'r.json').exists()


def test_malformed_geometry_yaml_is_refused(dataset, tmp_path, capsys):
    geometry = tmp_path / 'nominal.yaml'
    geometry.write_text('base_joints: [[0, 0, 0]]\n')
    code = main(['calibrate', 'hexapod', '--data', str(dataset / 'calibration.csv'),
                 '--geometry', str(geometry), '--out', str(tmp_path / 'c.yaml')])
    assert code == 2 and 'lacks platform_joints' in capsys.readouterr().err
