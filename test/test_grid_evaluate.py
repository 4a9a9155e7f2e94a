"""A grid self-calibration against an independent reference map (issue 33): the truth of
a simulated travel written by `simulate grid --truth`, compared in one gauge by `evaluate
grid`; the map's stated sigma checked against its real error; references in mm, with no
shared site, or a report of another kind refused with a clear message."""
import json

import numpy as np

from grid_calib.core.reference_map import read_reference
from machine_alignment.cli import main

TOLERANCE = {'map_over_stage_error': 0.1, 'sigma_rms': (0.6, 1.6)}   # measured: 0.02, 0.83-1.15


def test_the_map_matches_the_truth_within_its_stated_sigma(tmp_path, capsys):
    marks, truth, report, result = (tmp_path / n for n in ('marks.csv', 'truth.csv',
                                                           'grid.json', 'evaluation.json'))
    assert main(['simulate', 'grid', '--out', str(marks), '--truth', str(truth), '--regions',
                 '2', '2', '--half', '3', '--seed', '1']) == 0
    assert main(['calibrate', 'grid', '--data', str(marks), '--pitch', '0.01', '--json',
                 str(report)]) == 0
    assert main(['evaluate', 'grid', '--report', str(report), '--reference', str(truth),
                 '--json', str(result)]) == 0
    evaluation = json.loads(result.read_text())
    assert evaluation['sites_compared'] == evaluation['sites_in_map'] == 182
    assert evaluation['map_minus_reference_m']['rms'] < \
        TOLERANCE['map_over_stage_error'] * evaluation['stage_error_m']['rms']
    low, high = TOLERANCE['sigma_rms']
    assert low < evaluation['in_sigma']['rms'] < high
    assert 'in the map\'s stated sigma' in capsys.readouterr().out
    # The map as the 2-D table beside the JSON, read as a loader would (and as a reference).
    table = np.loadtxt(tmp_path / 'grid_map.csv', delimiter=',', skiprows=1)
    sites = json.loads(report.read_text())['sites']
    assert table.shape == (len(sites), 6)
    np.testing.assert_allclose(table[:, 2:4], [[s['error_x'], s['error_y']] for s in sites],
                               rtol=1e-9, atol=1e-18)
    positions, errors = read_reference(tmp_path / 'grid_map.csv')
    assert positions.shape == errors.shape == (len(sites), 2)


def test_bad_references_are_refused(tmp_path, capsys):
    marks, truth, report = (tmp_path / n for n in ('marks.csv', 'truth.csv', 'grid.json'))
    assert main(['simulate', 'grid', '--out', str(marks), '--truth', str(truth), '--half', '2']) == 0
    assert main(['calibrate', 'grid', '--data', str(marks), '--pitch', '0.01', '--json',
                 str(report)]) == 0
    capsys.readouterr()
    lines = truth.read_text().splitlines()
    in_mm = tmp_path / 'mm.csv'
    in_mm.write_text('\n'.join([lines[0]] + [','.join(str(float(v) * 1000) for v in row.split(','))
                                             for row in lines[1:]]) + '\n')
    elsewhere = tmp_path / 'elsewhere.csv'
    elsewhere.write_text('x,y,error_x,error_y\n0.5,0.5,0,0\n0.6,0.5,0,0\n0.7,0.5,0,0\n')
    for reference, expected in ((in_mm, 'look like mm'), (elsewhere, 'shares 0 sites')):
        assert main(['evaluate', 'grid', '--report', str(report), '--reference',
                     str(reference)]) == 2
        err = capsys.readouterr().err
        assert expected in err and 'Traceback' not in err
    assert main(['evaluate', 'grid', '--report', str(truth), '--reference', str(truth)]) == 2
    assert 'not the JSON report of calibrate grid' in capsys.readouterr().err
