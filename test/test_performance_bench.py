"""The performance table's baselines do the same job as the suite's route on the same data
(else their times would not compare), and a measured row carries the time, the memory and
the ratio it is read for (machine_alignment/bench/performance.py)."""
import numpy as np
import pytest

from machine_alignment.bench import performance

TOLERANCE = {'parameters_relative': 1e-5, 'located_m': 1e-7, 'dots_px': 0.05}


def test_numerical_derivatives_reach_the_analytic_identification():
    work = performance._platform(20)
    analytic, numeric = work.job(), work.baseline()
    scale = np.maximum(np.abs(analytic.geometry.vector()), 1e-3)
    assert np.max(np.abs(analytic.geometry.vector() - numeric.geometry.vector()) / scale) \
        < TOLERANCE['parameters_relative']


def test_opencv_triangulation_locates_the_same_points():
    work = performance._localisation(4)
    ours, opencv = np.array(work.job()), np.array(work.baseline())
    assert np.abs(ours - opencv).max() < TOLERANCE['located_m']
    assert work.error(ours) == pytest.approx(work.error(opencv), rel=0.01)


def test_a_row_has_time_memory_ratio_and_both_errors():
    row = performance.measure('Mark detection, one frame', 9)
    assert row['seconds'] > 0 and row['baseline_seconds'] > 0
    assert row['ratio_to_baseline'] == pytest.approx(row['seconds'] / row['baseline_seconds'])
    assert row['peak_mib'] >= row['peak_mib_before'] > 0
    # Both detectors find the dots; ours within its Cramer-Rao-level error.
    assert row['error'] < TOLERANCE['dots_px'] and row['baseline_error'] < 1.0


@pytest.mark.parametrize('pixels', sorted(performance.FRAMES))
def test_both_detectors_find_the_dots_on_every_frame_size(pixels):
    """The frame-size job's frames (VGA, full HD, 5 MP) hold 9 dots both detectors find:
    ours to its Cramer-Rao-level error, the tuned blob detector to under a pixel."""
    work = performance._frame_size(pixels)
    ours, blobs = work.job(), work.baseline()
    assert len(ours) == len(blobs) == 9
    assert work.error(ours) < TOLERANCE['dots_px'] and work.error(blobs) < 1.0
