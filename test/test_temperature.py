"""A run's temperature log and each measurement's time and temperature
(calib_core.temperature): linear between the samples, held at the ends, refused with the
reason where the log cannot give it."""
from types import SimpleNamespace

import numpy as np
import pytest

from calib_core.errors import InvalidInputError
from calib_core.temperature import run_covariates, temperature_log, temperatures_at

LOG = (np.array([100.0, 110.0, 120.0]), np.array([293.0, 294.0, 293.5]))   # s, K


def _sample(seconds, celsius):
    stamp = SimpleNamespace(sec=int(seconds), nanosec=int(round(seconds % 1 * 1e9)))
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), temperature=celsius)


def test_each_measurement_takes_the_temperature_between_the_samples_around_it():
    kelvin, why = temperatures_at([105.0, 115.0, 90.0, 150.0], LOG)
    assert why == ''
    np.testing.assert_allclose(kelvin, [293.5, 293.75, 293.0, 293.5], atol=1e-12)
    # One sample: every measurement within reach takes it.
    kelvin, _ = temperatures_at([60.0, 150.0], (np.array([100.0]), np.array([290.0])))
    np.testing.assert_array_equal(kelvin, [290.0, 290.0])


@pytest.mark.parametrize('stamps, log, reason', [
    ([105.0, 181.0], LOG, '1 measurement(s) lie more than 60 s'),    # the sensor stopped
    ([39.0, 105.0], LOG, '1 measurement(s) lie more than 60 s'),     # it started late
    ([105.0, np.nan], LOG, 'has no time stamp'),
    ([105.0], (np.zeros(0), np.zeros(0)), 'no temperature logged')])
def test_a_log_that_cannot_give_the_temperature_gives_none_and_why(stamps, log, reason):
    kelvin, why = temperatures_at(stamps, log)
    assert kelvin is None and reason in why


def test_the_log_in_kelvin_in_time_order_and_refused_in_the_wrong_unit():
    stamps, kelvin = temperature_log([_sample(12.5, 21.0), _sample(10.0, 20.0)])
    np.testing.assert_allclose(stamps, [10.0, 12.5])
    np.testing.assert_allclose(kelvin, [293.15, 294.15])
    with pytest.raises(InvalidInputError, match='kelvin where degrees Celsius'):
        temperature_log([_sample(10.0, 293.15)])
    with pytest.raises(InvalidInputError, match='NaN'):
        temperature_log([_sample(10.0, float('nan'))])


def test_a_runs_covariates_are_its_time_and_where_logged_its_temperature():
    covariates, why = run_covariates([110.0, 105.0, 120.0], LOG)
    assert why == ''
    np.testing.assert_allclose(covariates['time'], [5.0, 0.0, 15.0])
    np.testing.assert_allclose(covariates['temperature'], [294.0, 293.5, 293.5])
    covariates, why = run_covariates([110.0, 105.0])
    assert set(covariates) == {'time'} and why == ''
    covariates, why = run_covariates([110.0, 200.0], LOG)
    assert set(covariates) == {'time'} and 'more than 60 s' in why
    assert run_covariates([110.0, np.nan], LOG) == ({}, 'no time: a measurement has no '
                                                        'time stamp')


def test_a_slowly_logging_sensor_still_gives_every_measurement_its_temperature():
    """Samples 100 s apart: a measurement 20 s after one and 80 s before the next is 20 s
    from the log (the nearer sample), within the 60 s allowed; interpolated between them."""
    log = (np.array([0.0, 100.0, 200.0]), np.array([293.0, 294.0, 293.0]))
    kelvin, why = temperatures_at([20.0, 180.0], log)
    assert why == ''
    np.testing.assert_allclose(kelvin, [293.2, 293.2], atol=1e-12)
