"""Reading the printer's recorded runs into core values. Live messages and messages
decoded from a bag have the same fields, so the nodes and the offline tools read a run with
the same code and neither needs the message types. The topic names are the contract
between the nodes that record a run and the tools that replay it."""
from __future__ import annotations

import dataclasses

import numpy as np

from calib_core.errors import InvalidInputError
from calib_core.temperature import run_covariates, stamp_seconds
from printer_alignment.core.stage_calibration import StageData

VISION_OBSERVATIONS_TOPIC = '/vision_calibrator/observations'
VISION_RESULT_TOPIC = '/vision_calibrator/result'
INTRINSICS_RESULT_TOPIC = '/vision_calibrator/intrinsics'
STAGE_OBSERVATIONS_TOPIC = '/stage_calibrator/observations'
STAGE_RESULT_TOPIC = '/stage_calibrator/result'
ALIGNER_REPORT_TOPIC = '/aligner/report'


def stage_record(msg) -> tuple:
    """(q (3,), direction (3,), marks (2, 2)) from a StageObservation."""
    if len(msg.q) != 3 or len(msg.direction) != 3 or len(msg.marks_x) != 2 \
            or len(msg.marks_y) != 2:
        raise InvalidInputError('a stage observation needs 3 inputs, 3 directions, 2 Marks')
    return (np.array(msg.q, dtype=float), np.array(msg.direction, dtype=float),
            np.column_stack([msg.marks_x, msg.marks_y]))


def stage_data_from_records(records) -> StageData:
    """The StageData of a run's records (as :func:`stage_record` returns them)."""
    q, directions, marks = zip(*records)
    return StageData(np.array(q), np.array(directions), np.array(marks))


def stage_data_from_messages(messages, temperatures=None) -> tuple[StageData, str]:
    """The StageData of a run's StageObservation messages for the closed loop: each stop
    with its ``time`` (from the message's stamp) and, where a temperature log
    (calib_core.temperature.temperature_log) covers it, its ``temperature``; and why there
    is no temperature ('' where there is, or no log was given)."""
    data = stage_data_from_records([stage_record(msg) for msg in messages])
    covariates, why = run_covariates([stamp_seconds(msg) for msg in messages], temperatures)
    return dataclasses.replace(data, covariates=covariates), why
