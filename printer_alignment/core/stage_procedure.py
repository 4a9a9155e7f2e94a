"""The stage calibration run, independent of ROS: move through the plan with every chain
landing afresh at each stop, measure the two calibration Marks where the nominal
kinematics expects them, then both calibrations on the measurements.

The node injects its service calls as ``move`` and ``measure_marks``, as the vision and
hexapod calibrators do; a recorded run replays through
:func:`~printer_alignment.core.records.stage_data_from_records` and
:func:`~printer_alignment.core.stage_calibration.calibrate_stage` with the same result.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from printer_alignment.core.geometry import rotate_points
from printer_alignment.core.stage import NOMINAL_STAGE, landing_path
from printer_alignment.core.stage_calibration import StageData, StagePlan, calibrate_stage


def expected_marks(q, home_marks) -> np.ndarray:
    """Where the nominal kinematics puts the calibration Marks at inputs ``q`` (m, (3,)),
    given where they are with the stage at home (plate frame, m, (2, 2)). The Marks are
    searched for there: the stage's errors are far smaller than the image."""
    pose = NOMINAL_STAGE.forward(np.asarray(q, dtype=float)[None])[0]
    stage_home = NOMINAL_STAGE.stage2plate[:2]
    return rotate_points(pose[2], np.asarray(home_marks) - stage_home) + stage_home + pose[:2]


def measure_stage_run(plan: StagePlan, home_marks, move: Callable, measure_marks: Callable,
                      progress: Callable | None = None,
                      record: Callable | None = None) -> StageData:
    """Visit ``plan.targets()`` and measure the Marks at every stop; end at home.

    Parameters
    ----------
    home_marks : (2, 2)
        The Marks' plate positions (m) with the stage at home, as taught once; replaced by
        their measurement at the first stop (home).
    move : callable (3,) -> (q (3,), direction (3,))
        Commands the chain inputs (m); returns the inputs reached and each chain's last
        direction of travel (+1 / -1).
    measure_marks : callable (expected (2, 2)) -> (2, 2)
        The camera: the two Marks' plate positions (m), searched for near ``expected``.
    progress : callable (step, total, message), optional
        ``total`` counts the stops and the fit that follows them.
    record : callable (q, direction, marks), optional
        Called for every stop, e.g. to publish it and write it to a bag.
    """
    targets = plan.targets()
    home = np.asarray(home_marks, dtype=float)
    q_now, direction = move(targets[0])
    stops = []
    for k, q in enumerate(targets):
        for waypoint in landing_path(q_now, q, direction):
            q_now, direction = move(waypoint)
        marks = measure_marks(expected_marks(q, home))
        if k == 0:
            home = marks
        stops.append((np.asarray(q_now, dtype=float), np.asarray(direction, dtype=float),
                      np.asarray(marks, dtype=float)))
        if record is not None:
            record(*stops[-1])
        if progress is not None:
            progress(k + 1, len(targets) + 1, f'stop {k + 1}/{len(targets)}: q = '
                     + ', '.join(f'{v * 1e3:+.3f}' for v in q) + ' mm')
    move(np.zeros(3))
    q, directions, marks = (np.array(column) for column in zip(*stops))
    return StageData(q, directions, marks)


def run_stage_calibration(plan: StagePlan, home_marks, move: Callable,
                          measure_marks: Callable, progress: Callable | None = None,
                          record: Callable | None = None) -> tuple[StageData, dict, dict]:
    """:func:`measure_stage_run`, then the stepwise and the parametric calibration:
    (the measurements, the models by name, the report)."""
    data = measure_stage_run(plan, home_marks, move, measure_marks, progress, record)
    models, report = calibrate_stage(data)
    return data, models, report
