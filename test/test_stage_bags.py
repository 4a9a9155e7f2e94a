"""The committed XY-Theta stage bags (one `make demo` run): the calibration run replays to
its recorded result, the alignment replays to its recorded chain inputs with the
calibration it recorded, and both decode with a second reader."""
import json
from pathlib import Path

import numpy as np

from calib_core.bags import decode_bag
from machine_alignment.cli import main as cli_main

BAGS = Path(__file__).resolve().parents[1] / 'bags'
CALIBRATION = BAGS / 'stage_calibration_run'
ALIGNMENT = BAGS / 'stage_alignment_run'


def _result(bag):
    return next(m for t, _, m in decode_bag(bag) if t == '/stage_calibrator/result')


def test_calibration_bag_replays_to_the_recorded_result(tmp_path):
    out = tmp_path / 'replay.json'
    assert cli_main(['calibrate', 'stage', '--bag', str(CALIBRATION), '--json', str(out)]) == 0
    report = json.loads(out.read_text())
    # Same to within a thousandth of each parameter's sigma (another numpy/scipy build
    # may stop the solver elsewhere along a weakly determined direction by ~1e-4 sigma).
    assert report['max_difference_to_live_sigma'] < 1e-3
    assert report['max_difference_to_live'] < 1e-6
    assert report['parametric']['residual_rms_m'] < 5e-6


def test_alignment_bag_replays_with_the_calibration_it_used(tmp_path):
    out = tmp_path / 'alignment.json'
    assert cli_main(['evaluate', 'alignment', '--bag', str(ALIGNMENT), '--json', str(out)]) == 0
    alignments = json.loads(out.read_text())['alignments']
    assert len(alignments) == 1 and alignments[0]['model'] == 'parametric'
    assert alignments[0]['max_difference_m'] < 1e-12
    assert alignments[0]['verification']['position_error_m'] < 12.3e-6
    # The calibration recorded with the alignment is the one the calibration run produced.
    used, produced = _result(ALIGNMENT), _result(CALIBRATION)
    assert used.version == produced.version and list(used.values) == list(produced.values)


def test_stage_bags_decode_with_mcap_ros2_support():
    from mcap_ros2.reader import read_ros2_messages
    decoded = list(read_ros2_messages(str(CALIBRATION / 'stage_calibration_run_0.mcap')))
    stops = [m.ros_msg for m in decoded if m.channel.topic == '/stage_calibrator/observations']
    assert len(stops) == 130
    assert all(len(s.q) == 3 and len(s.marks_x) == 2 for s in stops)
    assert np.all(np.isfinite([s.marks_x for s in stops]))
    assert decoded[-1].schema.name == 'alignment_msgs/msg/CalibrationResult'
    reports = [m.ros_msg for m in read_ros2_messages(str(ALIGNMENT / 'stage_alignment_run_0.mcap'))
               if m.channel.topic == '/aligner/report']
    assert len(reports) == 1 and json.loads(reports[0].data)['model'] == 'parametric'


def test_a_recorded_run_exports_to_the_csv_the_loop_reads(tmp_path, capsys):
    """The calibration bag as the analyze command's CSV: the same stops as the bag, a time
    column from the stops' stamps, and the loop on it finds the chains' backlash (the
    demo's stage has 3 / 4 / 2.5 um; each found positive and within 4 sigma). A bag of
    another machine is refused with what it holds."""
    from printer_alignment.core.records import stage_data_from_records, stage_record
    from printer_alignment.core.stage_calibration import StageData
    csv = tmp_path / 'stage.csv'
    assert cli_main(['export', 'stage', '--bag', str(CALIBRATION), '--out', str(csv)]) == 0
    exported = StageData.from_csv(csv)
    recorded = stage_data_from_records([stage_record(m) for t, _, m in decode_bag(CALIBRATION)
                                        if t == '/stage_calibrator/observations'])
    np.testing.assert_allclose(exported.marks, recorded.marks, atol=1e-12)
    np.testing.assert_array_equal(exported.directions, recorded.directions)
    time = exported.covariates['time']
    assert time[0] == 0 and np.all(np.diff(time) >= 0) and time[-1] > 0
    report_path = tmp_path / 'loop.json'
    assert cli_main(['analyze', 'stage', '--data', str(csv), '--json', str(report_path)]) == 0
    effects = json.loads(report_path.read_text())['effects_added']
    assert [e['name'] for e in effects] == ['reversal']
    for chain, true in zip(('chain1', 'chain2', 'chain3'), (3e-6, 4e-6, 2.5e-6)):
        value = effects[0]['parameters'][f'backlash_{chain}']
        assert value > 0 and abs(value - true) < 4 * effects[0]['std_devs'][f'backlash_{chain}']
    capsys.readouterr()
    assert cli_main(['export', 'platform', '--bag', str(CALIBRATION),
                     '--out', str(tmp_path / 'p.csv')]) == 2
    assert 'holds no platform measurements' in capsys.readouterr().err
    assert not (tmp_path / 'p.csv').exists()
