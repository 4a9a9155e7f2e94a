"""Self-calibration of the XY-Theta stage with the machine's own camera.

Data: at each commanded input vector q the camera measures two calibration Marks on the
platform (plate frame, m). The plan moves the stage along the paper's trajectories: an X
sweep (q1 alone), a Y sweep (q2 = q3), an attitude sweep (q3 - q2 at q1 = 0, q2 = -q3)
and a grid over the workspace; sweeps go up and then down so both directions of approach
occur on every chain.

Two methods use the same measurements:

- :func:`stepwise_calibration`, the paper's: moving-platform frame (home pose, X direction,
  rotation centre of the attitude sweep), transmission ratios R1..R3 and the distance
  d3 - d2, axis skew alpha1, an attitude table over q3 - q2, and the measured workspace
  poses for interpolation of the remaining input error over triangles (tetrahedra in
  x, y, theta).
- :func:`parametric_calibration`: least squares on the whole error model of
  :class:`~printer_alignment.core.stage.StageGeometry` including backlash, started from
  the stepwise result.

Both return a model with ``forward(q)`` (plate-frame platform pose) and ``inverse(pose)``
(inputs for a plate-frame platform pose, approached from below on every chain).

Modules: ``data`` (measurements and plan), ``models`` (what the aligner uses),
``stepwise``, ``parametric``, ``both`` (:func:`calibrate_stage`).
"""
from printer_alignment.core.stage_calibration.both import calibrate_stage, check_stage_calibration
from printer_alignment.core.stage_calibration.data import (
    STAGE_COLUMNS, STAGE_DIRECTIONS, StageData, StagePlan, read_stage_plan, relative_motions,
    write_stage_plan)
from printer_alignment.core.stage_calibration.models import (
    ParametricModel, StageModel, StepwiseModel, models_as_dict, models_from_dict)
from printer_alignment.core.stage_calibration.parametric import PARAMETRIC_GAUGE, mark_names, parametric_calibration, predict_marks
from printer_alignment.core.stage_calibration.stepwise import stepwise_calibration

__all__ = ['PARAMETRIC_GAUGE', 'STAGE_COLUMNS', 'STAGE_DIRECTIONS', 'ParametricModel', 'StageData',
           'StageModel', 'StagePlan', 'StepwiseModel', 'calibrate_stage',
           'check_stage_calibration', 'mark_names',
           'models_as_dict', 'models_from_dict', 'parametric_calibration', 'predict_marks',
           'read_stage_plan', 'relative_motions', 'stepwise_calibration', 'write_stage_plan']
