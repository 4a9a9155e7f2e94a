"""The committed calibration bag: decodes with two readers and replays to the same result."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from calib_core.bags import BagWriter, decode_bag, read_bag
from machine_alignment.cli import main as cli_main
from calib_core.errors import BagError, InvalidInputError
from printer_alignment.core.vision_procedure import (
    calibrate_from_observations, observation_from_message)

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'vision_calibration_run'


def test_bag_layout_is_rosbag2_mcap():
    assert (BAG / 'metadata.yaml').exists() and (BAG / 'vision_calibration_run_0.mcap').exists()
    assert 'version: 9' in (BAG / 'metadata.yaml').read_text()


def test_replay_gives_the_recorded_result():
    observations, recorded = [], None
    for topic, _, msg in decode_bag(BAG):
        if topic == '/vision_calibrator/observations':
            observations.append(observation_from_message(msg))
        else:
            recorded = msg
    assert len(observations) == 20 and recorded.success
    replay = calibrate_from_observations(observations, 0.5e-3)
    live = dict(zip(recorded.names, recorded.values))
    for name, value in replay.gantry.as_dict().items():
        assert value == pytest.approx(live[name], rel=1e-9, abs=1e-12), name
    assert replay.camera2plate.pixel_size == pytest.approx(live['pixel_size'], rel=1e-9)


def test_bag_decodes_with_mcap_ros2_support():
    from mcap_ros2.reader import read_ros2_messages
    decoded = list(read_ros2_messages(str(BAG / 'vision_calibration_run_0.mcap')))
    observations = [m for m in decoded if m.channel.topic == '/vision_calibrator/observations']
    assert len(observations) == 20
    first = observations[0].ros_msg
    assert len(first.marks.marks) > 100 and np.isfinite(first.marks.marks[0].u)
    assert decoded[-1].schema.name == 'alignment_msgs/msg/CalibrationResult'


def test_cli_replays_the_bag(tmp_path):
    out = tmp_path / 'replay.json'
    assert cli_main(['calibrate', 'vision', '--bag', str(BAG), '--json', str(out)]) == 0
    report = json.loads(out.read_text())
    assert max(report['max_difference_to_live'].values()) < 1e-12


def test_truncated_bag_is_a_clear_error(tmp_path):
    damaged = tmp_path / 'damaged'
    shutil.copytree(BAG, damaged)
    mcap = damaged / 'vision_calibration_run_0.mcap'
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 3])
    with pytest.raises(BagError, match='cannot read bag'):
        list(read_bag(damaged))
    assert cli_main(['calibrate', 'vision', '--bag', str(damaged)]) == 2


def test_foreign_and_missing_bags(tmp_path):
    with pytest.raises(BagError, match='no bag'):
        list(read_bag(tmp_path / 'nothing'))
    (tmp_path / 'foreign').mkdir()
    (tmp_path / 'foreign' / 'data.bin').write_bytes(b'not a bag')
    with pytest.raises(BagError, match='metadata.yaml is missing'):
        list(read_bag(tmp_path / 'foreign'))


def test_writer_never_overwrites_and_rejects_unknown_types(tmp_path):
    with BagWriter(tmp_path / 'b') as bag:
        with pytest.raises(BagError, match='unknown message type'):
            bag.add_topic('/x', 'nope_msgs/msg/Nothing')
    with pytest.raises(BagError, match='exists already'):
        BagWriter(tmp_path / 'b')


def test_observation_with_nan_is_refused():
    from types import SimpleNamespace as NS
    msg = NS(gantry=NS(x_rev=float('nan'), y_rev=0.0), marks=NS(marks=[NS(u=1.0, v=2.0)]))
    with pytest.raises(InvalidInputError, match='NaN'):
        observation_from_message(msg)
