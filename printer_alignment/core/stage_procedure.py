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

from calib_core.planning import Adaptive
from printer_alignment.core.stage import (
    NOMINAL_STAGE, STROKE, StageGeometry, landing_path, platform_points_in_plate)
from printer_alignment.core.stage_calibration import StageData, StagePlan, calibrate_stage
from printer_alignment.core.stage_planning import (
    extend_stage, identified, platform_marks, predict_stage_run, route)


def expected_marks(q, home_marks, nominal: StageGeometry = NOMINAL_STAGE) -> np.ndarray:
    """Where the ``nominal`` kinematics puts the calibration Marks at inputs ``q`` (m,
    (3,)), given where they are with the stage at home (plate frame, m, (2, 2)). The Marks
    are searched for there: the stage's errors are far smaller than the image."""
    pose = nominal.stage_to_plate(nominal.forward(np.asarray(q, dtype=float)[None]))
    return platform_points_in_plate(pose, platform_marks(home_marks, nominal))[0]


def _visit(targets, home, move: Callable, measure_marks: Callable, progress, record,
           first: int = 0, total: int | None = None, nominal: StageGeometry = NOMINAL_STAGE,
           stroke: float = STROKE) -> tuple[np.ndarray, list]:
    """Land on each of ``targets`` in turn and measure the Marks where the nominal
    kinematics expects them from ``home``; the stops (q, direction, marks) and ``home``,
    replaced by the first stop's Marks when ``first`` is 0 (the run's home stop)."""
    q_now, direction = move(targets[0])
    stops = []
    for k, q in enumerate(targets):
        for waypoint in landing_path(q_now, q, direction, stroke=stroke):
            q_now, direction = move(waypoint)
        marks = measure_marks(expected_marks(q, home, nominal))
        if first + k == 0:
            home = marks
        stops.append((np.asarray(q_now, dtype=float), np.asarray(direction, dtype=float),
                      np.asarray(marks, dtype=float)))
        if record is not None:
            record(*stops[-1])
        if progress is not None:
            count = total or first + len(targets)
            progress(first + k + 1, count + 1, f'stop {first + k + 1}/{count}: q = '
                     + ', '.join(f'{v * 1e3:+.3f}' for v in q) + ' mm')
    move(np.zeros(3))
    return home, stops


def _data(stops: list) -> StageData:
    q, directions, marks = (np.array(column) for column in zip(*stops))
    return StageData(q, directions, marks)


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
    _, stops = _visit(plan.targets(), np.asarray(home_marks, dtype=float), move,
                      measure_marks, progress, record, stroke=plan.stroke)
    return _data(stops)


def run_stage_calibration(plan: StagePlan, home_marks, move: Callable,
                          measure_marks: Callable, progress: Callable | None = None,
                          record: Callable | None = None,
                          adaptive: Adaptive | None = None,
                          nominal: StageGeometry = NOMINAL_STAGE,
                          **noise) -> tuple[StageData, dict, dict]:
    """:func:`measure_stage_run`, then the stepwise and the parametric calibration:
    (the measurements, the models by name, the report). ``nominal`` is the stage as drawn
    (a machine description's, :meth:`~printer_alignment.core.stage_description.
    StageDescription.nominal`): where the Marks are searched for and where the stepwise
    calibration starts; ``noise`` (``landing_sigma``, ``camera_noise``, m) what the
    adaptive rounds predict with.

    With ``adaptive`` (its target an RMS error of the Marks at the working inputs, m), the
    rounds follow: the error predicted about the parametric calibration so far; while it
    is above the target, the stops that lower it most are measured (nearest first from
    home) and both calibrations run again on every stop (``report['adaptive']``)."""
    targets = plan.targets()
    stroke = plan.stroke
    home, stops = _visit(targets, np.asarray(home_marks, dtype=float), move, measure_marks,
                         progress, record, nominal=nominal, stroke=stroke)
    data = _data(stops)
    models, report = calibrate_stage(data, nominal.d)
    while adaptive is not None:
        geometry, marks = identified(report)
        now = predict_stage_run(geometry, marks, data.q, data.directions, stroke=stroke,
                                **noise)

        def extend(room, geometry=geometry, marks=marks, data=data):
            chosen, best = extend_stage(geometry, marks, data.q, data.directions, room,
                                        stroke=stroke, **noise)
            return chosen, best.predicted_rms_m
        more = adaptive.more(now.predicted_rms_m, len(data), extend)
        if more is None:
            report['adaptive'] = adaptive.report()
            break
        _, added = _visit(route(more, np.zeros(3)), home, move, measure_marks, progress,
                          record, first=len(stops), nominal=nominal, stroke=stroke)
        stops += added
        data = _data(stops)
        models, report = calibrate_stage(data, nominal.d)
    return data, models, report
