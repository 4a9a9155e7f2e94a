"""The committed hexapod calibration bag: decodes with two readers and replays through the
identification to the recorded result."""
import json
from pathlib import Path

import numpy as np

from calib_core.bags import decode_bag
from machine_alignment.cli import main as cli_main
from hexapod_calib.core.geometry import HexapodGeometry, read_geometry
from hexapod_calib.core.procedure import identify_from_records
from hexapod_calib.core.records import measurement_record

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'hexapod_calibration_run'


def _read():
    records, result = [], None
    for topic, _, msg in decode_bag(BAG):
        if topic == '/hexapod_calibrator/measurements':
            records.append(measurement_record(msg))
        elif topic == '/hexapod_calibrator/result':
            result = msg
    return records, result


def test_replay_gives_the_recorded_geometry():
    records, result = _read()
    assert len(records) == 120 and result.success and len(result.names) == 42
    report = json.loads(result.report_json)
    nominal = HexapodGeometry.from_dict(report['nominal_geometry'])
    identification, history = identify_from_records(records, nominal)
    assert len(history) == 2
    live = dict(zip(result.names, result.values))
    replayed = identification.geometry.parameters().as_dict()
    assert max(abs(replayed[n] - v) for n, v in live.items()) < 1e-12


def test_bag_decodes_with_mcap_ros2_support():
    from mcap_ros2.reader import read_ros2_messages
    decoded = list(read_ros2_messages(str(BAG / 'hexapod_calibration_run_0.mcap')))
    stops = [m.ros_msg for m in decoded if m.channel.topic == '/hexapod_calibrator/measurements']
    assert len(stops) == 120
    assert len(stops[0].leg_lengths) == 6 and np.all(np.isfinite(stops[0].leg_lengths))
    assert {s.phase for s in stops} == {'identify_0', 'identify_1', 'evaluate_nominal',
                                        'evaluate_calibrated'}
    assert decoded[-1].schema.name == 'alignment_msgs/msg/CalibrationResult'


def test_cli_replays_the_bag(tmp_path):
    out = tmp_path / 'geometry.yaml'
    assert cli_main(['calibrate', 'hexapod', '--bag', str(BAG), '--out', str(out),
                     '--json', str(tmp_path / 'replay.json')]) == 0
    report = json.loads((tmp_path / 'replay.json').read_text())
    assert report['max_difference_to_live_m'] < 1e-12
    assert len(read_geometry(out).parameters().names) == 42


def test_the_run_exports_to_the_csv_the_loop_reads(tmp_path):
    """Every stop of the run, as analyze hexapod reads it: commanded and measured poses and
    leg lengths as recorded, and the time since the first stop."""
    from hexapod_calib.core.calibration import PoseData
    records, result = _read()
    csv = tmp_path / 'hexapod.csv'
    assert cli_main(['export', 'hexapod', '--bag', str(BAG), '--out', str(csv)]) == 0
    nominal = HexapodGeometry.from_dict(json.loads(result.report_json)['nominal_geometry'],
                                        'recorded nominal')
    data = PoseData.from_csv(csv, nominal)
    assert len(data) == len(records)
    np.testing.assert_allclose(data.leg_lengths, [r[2] for r in records], atol=1e-12)
    np.testing.assert_allclose(data.measured, [r[3] for r in records], atol=1e-12)
    assert np.all(np.diff(data.covariates['time']) >= 0)
