"""The XY-Theta stage's calibration plan (printer_alignment.core.stage_planning): the stops
it chooses, its prediction against what the parametric calibration then does on simulated
stages, the plan file and its refusals."""
import numpy as np
import pytest

from calib_core.errors import InvalidInputError, OutOfTravelError
from calib_core.planning import Adaptive
from machine_alignment.cli import main
from printer_alignment.core.stage import NOMINAL_STAGE, STROKE, StageGeometry
from printer_alignment.core.stage_calibration import (
    StagePlan, calibrate_stage, mark_names, predict_marks, read_stage_plan, write_stage_plan)
from printer_alignment.core.stage_planning import (
    default_working, plan_stage, platform_marks, predict_stage_plan, visiting_directions)
from printer_alignment.core.stage_procedure import run_stage_calibration
from printer_alignment.sim.stage import (
    CALIBRATION_MARKS, TRUE_STAGE, StageSim, measure_marks, simulate_calibration_run)

# realised / predicted RMS over the repeated runs: the runs' own scatter (24 runs) and the
# first-order model at the nominal geometry, not the truth's
RATIO = (0.8, 1.25)


@pytest.fixture(scope='module')
def planned():
    return plan_stage(NOMINAL_STAGE, CALIBRATION_MARKS, 20)


def test_the_plan_keeps_the_sweeps_and_adds_chosen_stops_inside_the_stroke(planned):
    sweeps = StagePlan(sweep_points=3).sweeps()
    assert len(planned.targets) == len(sweeps) + 20 and planned.planned == 20
    np.testing.assert_array_equal(planned.targets[:len(sweeps)], sweeps)
    assert np.all(np.abs(planned.targets) <= STROKE)
    assert len(np.unique(planned.targets[len(sweeps):], axis=0)) == 20
    # more stops, a smaller predicted error; the sweeps alone, a larger one
    more = plan_stage(NOMINAL_STAGE, CALIBRATION_MARKS, 40)
    alone = predict_stage_plan(NOMINAL_STAGE, CALIBRATION_MARKS, sweeps)
    assert more.predicted_rms_m < planned.predicted_rms_m < alone.predicted_rms_m


def test_the_directions_are_those_the_stage_lands_with():
    """A chain that rose to a stop lands from below (+1), one that fell from above (-1),
    one that stood still keeps its last direction: as the simulated stage reports them."""
    targets = StagePlan(sweep_points=3, grid=(2, 2, 2)).targets()
    assert np.array_equal(visiting_directions(targets),
                          simulate_calibration_run(plan=StagePlan(stops=targets)).directions)


def test_platform_marks_are_the_taught_home_marks_through_the_nominal_stage():
    pose = NOMINAL_STAGE.stage_to_plate(NOMINAL_STAGE.forward(np.zeros((1, 3))))
    home = predict_marks(NOMINAL_STAGE, CALIBRATION_MARKS, np.zeros((1, 3)), np.ones((1, 3)))[0]
    assert pose.shape == (1, 3)
    np.testing.assert_allclose(platform_marks(home), CALIBRATION_MARKS, atol=1e-12)


def test_prediction_against_repeated_calibrations_of_a_simulated_stage(planned):
    """The planned run measured 24 times on the simulated stage (its true errors stated in
    TRUE_STAGE, landing 1.2 um, camera 0.3 um): the RMS over the runs of the parametric
    model's Mark error at working inputs no run measured is the predicted RMS within
    RATIO; the prediction comes from the nominal stage, before anything moved."""
    working = default_working(60, seed=5)
    up = np.ones_like(working)
    true = predict_marks(TRUE_STAGE, CALIBRATION_MARKS, working, up)
    squares = []
    for seed in range(24):
        data = simulate_calibration_run(TRUE_STAGE, StagePlan(stops=planned.targets), seed=seed)
        values = calibrate_stage(data)[1]['parametric']['parameters']
        marks = np.array([values[n] for n in mark_names()]).reshape(2, 2)
        found = predict_marks(StageGeometry.from_parameters(values), marks, working, up)
        squares.append(np.mean(np.sum((found - true) ** 2, axis=2)))
    predicted = predict_stage_plan(NOMINAL_STAGE, CALIBRATION_MARKS, planned.targets, working)
    ratio = np.sqrt(np.mean(squares)) / predicted.predicted_rms_m
    assert RATIO[0] < ratio < RATIO[1]


def test_plan_refusals():
    with pytest.raises(InvalidInputError, match='starts at home'):
        StagePlan(stops=[[1e-3, 0, 0], [0, 0, 0]])
    with pytest.raises(OutOfTravelError, match='outside the stroke'):
        StagePlan(stops=[[0, 0, 0], [6e-3, 0, 0]])
    for bad in ([[0, 0], [1e-3, 0]], [[0, 0, 0], [1e-3, 0]], [[0, 0, 0], ['a', 0, 0]], []):
        with pytest.raises(InvalidInputError, match=r'\[q1, q2, q3 \(m\)\] rows'):
            StagePlan(stops=bad)
    with pytest.raises(InvalidInputError, match='criterion'):
        plan_stage(NOMINAL_STAGE, CALIBRATION_MARKS, 5, criterion='A')
    with pytest.raises(InvalidInputError, match='at least one stop'):
        plan_stage(NOMINAL_STAGE, CALIBRATION_MARKS, 0)


def test_plan_file_round_trip_and_mm_refused(tmp_path, planned):
    path = tmp_path / 'plan.csv'
    write_stage_plan(path, planned.targets)
    np.testing.assert_allclose(read_stage_plan(path).targets(), planned.targets, atol=1e-15)
    mm = tmp_path / 'mm.csv'
    write_stage_plan(mm, planned.targets * 1e3)
    with pytest.raises(InvalidInputError, match='mm'):
        read_stage_plan(mm)


def test_cli_plans_simulates_and_calibrates_a_planned_run(tmp_path, capsys):
    plan, data = tmp_path / 'plan.csv', tmp_path / 'run.csv'
    assert main(['plan', 'stage', '--stops', '12', '--out', str(plan)]) == 0
    out = capsys.readouterr().out
    assert '31 stops' in out and 'predicted before anything moves' in out
    assert main(['simulate', 'stage', '--plan', str(plan), '--out', str(data)]) == 0
    assert main(['calibrate', 'stage', '--data', str(data)]) == 0
    assert 'Traceback' not in capsys.readouterr().err


def _adaptive_run(target: float, max_stops: int, seed: int = 3):
    """A planned 12-stop run on the simulated stage, then adaptive rounds of 8 stops."""
    stage = StageSim(seed=seed)
    rng = np.random.default_rng(seed)

    def move(q):
        stage.move(q)
        return stage.q.copy(), stage.directions.copy()
    home = stage.true_points(CALIBRATION_MARKS)
    first = plan_stage(NOMINAL_STAGE, CALIBRATION_MARKS, 12)
    rounds = Adaptive(target, max_stops, 8)
    data, _, report = run_stage_calibration(
        StagePlan(stops=first.targets), home, move,
        lambda expected: measure_marks(stage, CALIBRATION_MARKS, 0.3e-6, rng), adaptive=rounds)
    return data, report


def test_adaptive_stage_adds_stops_until_the_predicted_error_meets_the_target():
    """From 31 stops (12 planned) to a predicted 0.45 um: rounds of 8 stops about the
    calibration so far, each predicting less, the last at or below the target; the
    stage back at home and every stop in the data."""
    data, report = _adaptive_run(0.45e-6, 100)
    adaptive = report['adaptive']
    assert adaptive['stopped'] == 'target met'
    counts = [r['stops'] for r in adaptive['rounds']]
    assert counts == list(range(31, len(data) + 1, 8)) and len(counts) > 1
    predicted = [r['predicted_rms_m'] for r in adaptive['rounds']]
    assert all(b < a for a, b in zip(predicted, predicted[1:]))
    assert predicted[-1] <= 0.45e-6 < predicted[-2]


def test_adaptive_stage_says_when_the_limits_cannot_meet_the_target():
    data, report = _adaptive_run(0.2e-6, 60)
    adaptive = report['adaptive']
    assert adaptive['stopped'].startswith('target cannot be met within max_stops = 60')
    assert adaptive['rounds'][-1]['best_at_max_stops_m'] > 0.2e-6 and len(data) == 31


def test_the_prediction_carries_both_noises_and_its_maximum_is_over_the_working_inputs(
        planned):
    """Both noise terms count: the camera's alone and the landings' alone each predict an
    error, and together their squares add (the errors are linear in the noise, first
    order); the maximum is the largest Mark's over the working inputs, so it is at least
    the RMS and at most the RMS times the square root of their count."""
    from printer_alignment.core.stage_planning import CAMERA_NOISE, LANDING_SIGMA
    working = default_working(60, seed=5)
    targets = planned.targets

    def predicted(landing, camera):
        return predict_stage_plan(NOMINAL_STAGE, CALIBRATION_MARKS, targets, working,
                                  landing_sigma=landing, camera_noise=camera)
    both = predicted(LANDING_SIGMA, CAMERA_NOISE)
    camera = predicted(0.0, CAMERA_NOISE)
    landing = predicted(LANDING_SIGMA, 0.0)
    assert camera.predicted_rms_m > 0 and landing.predicted_rms_m > 0
    assert both.predicted_rms_m ** 2 == pytest.approx(
        camera.predicted_rms_m ** 2 + landing.predicted_rms_m ** 2, rel=1e-6)
    assert both.predicted_rms_m <= both.predicted_max_m <= both.predicted_rms_m * np.sqrt(
        2 * len(working))


def test_the_predicted_maximum_is_the_worst_marks_displacement(planned):
    """The maximum worked here Mark by Mark: for each working input and each Mark, the
    1-sigma displacement sqrt(trace(G C G^T)) with G that Mark's two rows of the Jacobian
    (x and y) and C the plan's parameter covariance; the largest of them."""
    from calib_core.planning import sandwich_covariance
    from printer_alignment.core.stage_planning import (
        free_parameters, mark_jacobian, stop_noise)
    working = default_working(60, seed=5)
    targets = planned.targets
    parameters = free_parameters(NOMINAL_STAGE, CALIBRATION_MARKS)
    directions = visiting_directions(targets)
    covariance = sandwich_covariance(mark_jacobian(parameters, targets, directions),
                                     stop_noise(parameters, targets, directions))
    rows = mark_jacobian(parameters, working, np.ones_like(working))     # (W, 4, p)
    worst = max(np.sqrt(np.trace(rows[w, 2 * m:2 * m + 2] @ covariance
                                 @ rows[w, 2 * m:2 * m + 2].T))
                for w in range(len(working)) for m in range(2))
    design = predict_stage_plan(NOMINAL_STAGE, CALIBRATION_MARKS, targets, working)
    assert design.predicted_max_m == pytest.approx(worst, rel=1e-9)
