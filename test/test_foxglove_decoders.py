"""The shipped recorded runs (bags/) open in Foxglove: its own decoders read every channel
and every message as this suite does. The DDS test modules check the bags their runs
write the same way (calibrations, analyses, the five-axis sweep)."""
from pathlib import Path

import pytest

from foxglove import assert_foxglove_reads, foxglove_decode

BAGS = Path(__file__).resolve().parents[1] / 'bags'


def test_the_shipped_runs_decode_in_foxglove():
    seen = assert_foxglove_reads(sorted(BAGS.iterdir()))
    assert seen['hexapod_calibration_run']['/hexapod_calibrator/measurements'] == 120
    assert seen['vision_calibration_run']['/vision_calibrator/result'] == 1


def test_a_cut_bag_and_a_wrong_schema_are_reported(tmp_path):
    """The check can fail: a bag cut short, and one whose CalibrationResult schema says
    float32 where the messages hold float64 (Foxglove then misreads what follows)."""
    import shutil
    source = next((BAGS / 'hexapod_calibration_run').glob('*.mcap')).read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(source[:len(source) // 2])
    [result] = foxglove_decode([cut])
    assert any('footer' in e or 'Error' in e for e in result['errors']), result['errors']
    wrong = tmp_path / 'wrong_schema'
    shutil.copytree(BAGS / 'hexapod_calibration_run', wrong)
    assert source.count(b'float64 rms_residual') >= 1
    next(wrong.glob('*.mcap')).write_bytes(
        source.replace(b'float64 rms_residual', b'float32 rms_residual'))
    with pytest.raises(AssertionError, match='CalibrationResult on channel'):
        assert_foxglove_reads([wrong])
