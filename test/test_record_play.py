"""player replays the committed bag over DDS while recorder records it: same messages."""
import os
import time
from pathlib import Path

import pytest

from calib_core.bags import decode_bag
from machine_alignment.launcher import Graph, NodeSpec

BAG = Path(__file__).resolve().parents[1] / 'bags' / 'vision_calibration_run'
TOPIC = '/vision_calibrator/observations'


def test_play_and_record_round_trip(tmp_path):
    domain = str(10 + os.getpid() % 30)   # below test_multi_host (42), test_launcher (60-65)
    recorded = tmp_path / 'recorded'
    recorder = NodeSpec('calib_core.nodes.recorder', {'topics': [TOPIC], 'output': str(recorded)})
    player = NodeSpec('calib_core.nodes.player', {'bag': str(BAG), 'rate': 10.0,
                                                  'topics': [TOPIC], 'start_delay_s': 3.0})
    with Graph([recorder], env={'ROS_DOMAIN_ID': domain}, log_dir=str(tmp_path)) as rec:
        with Graph([player], env={'ROS_DOMAIN_ID': domain}, log_dir=str(tmp_path)) as play:
            deadline = time.monotonic() + 40
            while time.monotonic() < deadline and play.alive()[0]:
                time.sleep(0.2)
            assert not play.alive()[0], 'player did not finish'
        assert rec.alive()[0]
    original = [m for _, _, m in decode_bag(BAG, [TOPIC])]
    copy = [m for _, _, m in decode_bag(recorded, [TOPIC])]
    assert len(copy) == len(original) == 20, (tmp_path / 'recorder.log').read_text()
    assert [m.marks.marks[0].u for m in copy] == pytest.approx([m.marks.marks[0].u for m in original])
