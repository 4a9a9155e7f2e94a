"""Every gate limit pinned from both sides (issue 53): a result just inside passes, just
outside is refused with the message naming the figure and the limit. Reports are built
here around the limit, so moving a limit (10x, a unit) or dropping a check fails."""
from types import SimpleNamespace

import numpy as np
import pytest

from calib_core.errors import CalibrationError
from calib_core.sanity import SanityGate
from dispenser_calib.core.calibration import (
    MAX_AXIS_SCALE_ERROR, MAX_REPROJECTION_RMS_PX, check_calibration)
from platform_calib.core.geometry import nominal_geometry
from platform_calib.core.identification import MAX_CLOSURE_RMS_M, check_identification
from printer_alignment.core.stage import NOMINAL_LEAD
from printer_alignment.core.stage_calibration.both import (
    MAX_LEAD_CHANGE, MAX_MARK_RESIDUAL_RMS_M, MAX_SKEW_RAD, check_stage_calibration)

INSIDE, OUTSIDE = 1 - 1e-6, 1 + 1e-6


def test_the_limits_are_the_documented_figures():
    """The values the docs and messages state: a 10x or unit slip fails here first."""
    assert MAX_CLOSURE_RMS_M == 100e-6
    assert MAX_REPROJECTION_RMS_PX == 3.0
    assert MAX_SKEW_RAD == 0.1
    assert MAX_MARK_RESIDUAL_RMS_M == 50e-6
    assert MAX_LEAD_CHANGE == 0.10 and NOMINAL_LEAD == 2e-3
    assert MAX_AXIS_SCALE_ERROR == 0.05


@pytest.mark.parametrize('sigma', [np.inf, -np.inf, np.nan])
def test_a_standard_deviation_that_is_not_finite_is_refused(sigma):
    gate = SanityGate('a result')
    gate.finite_std_devs({'a': 1e-6, 'b': sigma})
    with pytest.raises(CalibrationError, match='no finite standard deviation for b'):
        gate.enforce()
    gate = SanityGate('a result')
    gate.finite_std_devs({'a': 1e-6, 'b': 0.0})
    gate.enforce()


def _platform(rms: float):
    nominal = nominal_geometry()
    return SimpleNamespace(geometry=nominal, report=lambda: {
        'residual_rms_m': rms, 'std_devs': {'x_A1': 1e-6}}), nominal


def test_platform_closure_limit_from_both_sides():
    check_identification(*_platform(MAX_CLOSURE_RMS_M * INSIDE))
    with pytest.raises(CalibrationError, match=r'residual RMS 100 um, above the 100 um'):
        check_identification(*_platform(MAX_CLOSURE_RMS_M * OUTSIDE))


def _five_axis(rms_px: float, scale: float = 1.0):
    model = SimpleNamespace(affine=np.hstack([scale * np.eye(3), np.zeros((3, 1))]))
    return model, {'rms_reprojection_px': rms_px, 'std_devs': {'f': 0.1}}


def test_five_axis_reprojection_and_scale_limits_from_both_sides():
    check_calibration(*_five_axis(MAX_REPROJECTION_RMS_PX * INSIDE))
    with pytest.raises(CalibrationError, match=r'residual RMS 3 px, above the 3 px'):
        check_calibration(*_five_axis(MAX_REPROJECTION_RMS_PX * OUTSIDE))
    check_calibration(*_five_axis(0.1, 1 + MAX_AXIS_SCALE_ERROR * INSIDE))
    with pytest.raises(CalibrationError, match='linear-axis scale 1'):
        check_calibration(*_five_axis(0.1, 1 + MAX_AXIS_SCALE_ERROR * OUTSIDE))
    with pytest.raises(CalibrationError, match='0.001 means mm'):
        check_calibration(*_five_axis(0.1, 1e-3))


def _stage(rms=5e-6, lead=NOMINAL_LEAD, alpha1=np.pi / 2):
    return {'stepwise': {'R1': lead, 'R2': NOMINAL_LEAD, 'R3': NOMINAL_LEAD, 'alpha1': alpha1},
            'parametric': {'residual_rms_m': rms, 'std_devs': {'R1': 1e-9}, 'fixed': []}}


def test_stage_skew_lead_and_residual_limits_from_both_sides():
    for skew in (-1, 1):
        check_stage_calibration(_stage(alpha1=np.pi / 2 + skew * MAX_SKEW_RAD * INSIDE))
        with pytest.raises(CalibrationError,
                           match=r'stepwise alpha1 .*\(within 0.1 rad of square\)'):
            check_stage_calibration(_stage(alpha1=np.pi / 2 + skew * MAX_SKEW_RAD * OUTSIDE))
        check_stage_calibration(_stage(lead=NOMINAL_LEAD * (1 + skew * MAX_LEAD_CHANGE * INSIDE)))
        with pytest.raises(CalibrationError,
                           match=r'stepwise R1 .*\(within 10% of the nominal lead\)'):
            check_stage_calibration(
                _stage(lead=NOMINAL_LEAD * (1 + skew * MAX_LEAD_CHANGE * OUTSIDE)))
    check_stage_calibration(_stage(rms=MAX_MARK_RESIDUAL_RMS_M * INSIDE))
    with pytest.raises(CalibrationError, match=r'residual RMS 50 um, above the 50 um'):
        check_stage_calibration(_stage(rms=MAX_MARK_RESIDUAL_RMS_M * OUTSIDE))
