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


KILLED_WRITER = '''
import os, signal, sys
from calib_core.bags import BagWriter, decode_bag
stops = [msg for topic, _, msg in decode_bag(sys.argv[2]) if topic.endswith('/observations')]
from calib_core.bags import project_typestore
store = project_typestore()
bag = BagWriter(sys.argv[1]).__enter__()
bag.add_topic('/vision_calibrator/observations', 'alignment_msgs/msg/VisionObservation')
for k, msg in enumerate(stops[:int(sys.argv[3])]):
    bag.write('/vision_calibrator/observations', k,
              store.serialize_cdr(msg, 'alignment_msgs/msg/VisionObservation'))
os.kill(os.getpid(), signal.SIGKILL)
'''


def test_a_writer_killed_mid_run_leaves_every_message_it_wrote(tmp_path):
    """SIGKILL after 7 of the committed run's 20 stops: the MCAP is empty and there is no
    metadata.yaml, but the 7 stops replay from the journal, and the CLI says the run was cut
    and how many stops it recovered."""
    import subprocess
    import sys
    cut = tmp_path / 'vision_cut'
    done = subprocess.run([sys.executable, '-c', KILLED_WRITER, str(cut), str(BAG), '7'],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == -9, done.stderr
    assert not (cut / 'metadata.yaml').exists()
    recovered = [m for t, _, m in decode_bag(cut) if t == '/vision_calibrator/observations']
    originals = [m for t, _, m in decode_bag(BAG) if t == '/vision_calibrator/observations']
    assert len(recovered) == 7
    assert [observation_from_message(m).uv.tolist() for m in recovered] \
        == [observation_from_message(m).uv.tolist() for m in originals[:7]]


def test_cut_run_replays_what_it_measured_through_the_cli(tmp_path, capsys):
    import subprocess
    import sys
    cut = tmp_path / 'vision_cut'
    subprocess.run([sys.executable, '-c', KILLED_WRITER, str(cut), str(BAG), '12'],
                   capture_output=True, timeout=60)
    # A cut record at the end (the kill in the middle of a write) is left out.
    journal = cut / 'vision_cut.journal'
    journal.write_bytes(journal.read_bytes() + b'\x20\x00\x25\x00partial')
    assert cli_main(['calibrate', 'vision', '--bag', str(cut)]) in (0, 2)
    out = capsys.readouterr().out
    assert 'cut run' in out and '12 stops recovered' in out


def test_a_run_cut_before_its_first_stop_says_so(tmp_path, capsys):
    import subprocess
    import sys
    cut = tmp_path / 'vision_cut'
    subprocess.run([sys.executable, '-c', KILLED_WRITER, str(cut), str(BAG), '0'],
                   capture_output=True, timeout=60)
    assert cli_main(['calibrate', 'vision', '--bag', str(cut)]) == 2
    assert 'cut before its first stop' in capsys.readouterr().err
