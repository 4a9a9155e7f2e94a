"""A machine's temperature during a run, for the closed loop: the log its sensor publishes
(sensor_msgs/Temperature, in degrees Celsius as that message defines it) in kelvin, and
each measurement's temperature at its time stamp. Messages are read by their fields only,
so live messages and messages decoded from a bag go through the same code."""
from __future__ import annotations

import numpy as np

from calib_core.schema import CELSIUS_ZERO_K, Column

# A machine's temperature on the live graph, as the simulated machines publish it and the
# calibrators log and record it.
TEMPERATURE_TOPIC = '/machine/temperature'
TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'
TEMPERATURE = Column('temperature', 'K', 200.0, 400.0, 'temperature (kelvin)')
# A measurement takes the temperature interpolated between the log's samples around it; one
# further than this from every sample (a sensor that stopped) leaves the whole run without
# a temperature.
MAX_TEMPERATURE_GAP_S = 60.0


def stamp_seconds(msg) -> float:
    """A message's header stamp (s), NaN for a message without one."""
    header = getattr(msg, 'header', None)
    return np.nan if header is None else header.stamp.sec + 1e-9 * header.stamp.nanosec


def temperature_log(messages) -> tuple[np.ndarray, np.ndarray]:
    """The stamps (s) and temperatures (K) of sensor_msgs/Temperature messages (degrees
    Celsius), in time order.

    Raises
    ------
    InvalidInputError
        A temperature NaN or beyond what a machine reaches, with the likely mistake
        (kelvin sent as degrees Celsius)."""
    stamps = np.array([stamp_seconds(msg) for msg in messages], dtype=float)
    kelvin = np.array([msg.temperature for msg in messages], dtype=float) + CELSIUS_ZERO_K
    TEMPERATURE.check(kelvin, f'the temperature log ({TEMPERATURE_TOPIC})')
    order = np.argsort(stamps, kind='stable')
    return stamps[order], kelvin[order]


def temperatures_at(stamps, log) -> tuple[np.ndarray | None, str]:
    """The temperature (K) at each measurement's stamp (s), linear between the samples of
    a ``temperature_log``, and ''; or None and why not: the log is empty, a stamp is
    missing, or a measurement lies further than MAX_TEMPERATURE_GAP_S from every sample."""
    sample_stamps, kelvin = log
    stamps = np.asarray(stamps, dtype=float)
    if not len(kelvin):
        return None, 'no temperature logged'
    if not (np.all(np.isfinite(stamps)) and np.all(np.isfinite(sample_stamps))):
        return None, 'temperature not attached: a measurement or a sample has no time stamp'
    # The samples on either side of each measurement (the one sample at either end).
    right = np.searchsorted(sample_stamps, stamps).clip(0, len(kelvin) - 1)
    left = (right - 1).clip(0)
    gap = np.minimum(np.abs(stamps - sample_stamps[left]), np.abs(stamps - sample_stamps[right]))
    far = int(np.count_nonzero(gap > MAX_TEMPERATURE_GAP_S))
    if far:
        return None, (f'temperature not attached: {far} measurement(s) lie more than '
                      f'{MAX_TEMPERATURE_GAP_S:.0f} s from every sample of the log')
    return np.interp(stamps, sample_stamps, kelvin), ''


def run_covariates(stamps, log=None) -> tuple[dict, str]:
    """A run's covariates for the closed loop, per measurement: ``time`` (s since the
    first, from the stamps (s) of the messages that recorded them) and, where a
    ``temperature_log`` covers them, ``temperature`` (K); and why there is no temperature
    ('' where there is, or no log was given). No time where a stamp is missing."""
    stamps = np.asarray(stamps, dtype=float)
    if not len(stamps) or not np.all(np.isfinite(stamps)):
        return {}, 'no time: a measurement has no time stamp'
    covariates = {'time': stamps - stamps.min()}
    if log is None:
        return covariates, ''
    kelvin, why = temperatures_at(stamps, log)
    if kelvin is not None:
        covariates['temperature'] = kelvin
    return covariates, why
