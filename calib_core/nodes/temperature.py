"""The machine's temperature during a calibrator's runs: the samples its sensor publishes
(sensor_msgs/Temperature, degrees Celsius), kept for the run and recorded in its bag, so
the closed loop on a live run and on its replay read the same temperatures."""
from __future__ import annotations

import threading

from sensor_msgs.msg import Temperature

from calib_core.errors import MachineAlignmentError
from calib_core.temperature import TEMPERATURE_TOPIC, run_covariates, temperature_log

# Samples kept between runs: the last one is the run's first (a minute at 10 Hz).
KEPT_BETWEEN_RUNS = 600


class TemperatureLog:
    """The temperature samples a node receives on ``topic`` ('' for no sensor).

    At a run's start call :meth:`start`; between measurements, from the run's thread,
    :meth:`record` (the samples received since, into the run's bag on TEMPERATURE_TOPIC
    where a run is given: a bag has one writer); at its end :meth:`log`."""

    def __init__(self, node, topic: str, callback_group=None):
        self.topic = topic
        self._lock = threading.Lock()
        self._new, self._run = [], []
        if topic:
            node.create_subscription(Temperature, topic, self._on_sample, 10,
                                     callback_group=callback_group)

    def _on_sample(self, msg) -> None:
        with self._lock:
            self._new = self._new[-KEPT_BETWEEN_RUNS:] + [msg]

    def start(self) -> None:
        """A new run: its log starts with the last sample received before it."""
        with self._lock:
            self._new = self._new[-1:]
        self._run = []

    def record(self, run=None) -> None:
        """The samples received since the last call join the run's log, and its bag if
        ``run`` (a RecordedRun declaring TEMPERATURE_TOPIC) is given."""
        with self._lock:
            samples, self._new = self._new, []
        if run is not None:
            for msg in samples:
                run.record(TEMPERATURE_TOPIC, msg)
        self._run += samples

    def log(self) -> tuple[tuple | None, str]:
        """The run's log (calib_core.temperature.temperature_log) and a sentence saying
        where it came from; None and why where there is none or the sensor's values make
        no sense (a bad temperature costs the loop its temperature, never the run)."""
        if not self.topic:
            return None, 'no temperature sensor (temperature_topic is empty)'
        try:
            log = temperature_log(self._run)
        except MachineAlignmentError as exc:
            return None, f'temperature not used: {exc}'
        if not len(log[1]):
            return None, f'no temperature received on {self.topic}'
        return log, (f'{len(log[1])} samples on {self.topic}, '
                     f'{log[1].min():.3f}..{log[1].max():.3f} K')

    def covariates(self, stamps) -> tuple[dict, str]:
        """The run's covariates per measurement (calib_core.temperature.run_covariates:
        its time and, where the log covers it, its temperature) from the stamps (s) of the
        messages that recorded them, and a sentence on the temperature."""
        log, sentence = self.log()
        covariates, why = run_covariates(stamps, log)
        return covariates, why or sentence
