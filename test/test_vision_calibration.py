"""Vision system calibration on the simulated gantry: recovered parameters against truth."""
import re

import numpy as np
import pytest

from calib_core.errors import CalibrationError, InvalidInputError, OutOfTravelError
from calib_core.storage import read_calibration, write_calibration
from printer_alignment.core.geometry import NOMINAL_LEAD_X, NOMINAL_LEADS
from calib_core.marks import detect_marks
from printer_alignment.core.vision_calibration import (
    GantryObservation, calibrate_gantry, calibrate_pixel_size)
from printer_alignment.core.vision_procedure import VisionPlan, run_vision_calibration
from printer_alignment.sim.camera import CameraSim
from printer_alignment.sim.gantry import GantrySim
from printer_alignment.sim.scenes import make_scene



def _run(gantry, camera, plan):
    return run_vision_calibration(
        plan, lambda x, y: gantry.move(x, y) / NOMINAL_LEADS,
        lambda: np.array([[m.u, m.v] for m in detect_marks(
            camera.capture(gantry.true_camera_position())).marks]))


@pytest.fixture(scope='module')
def calibrated():
    gantry = GantrySim()
    camera = CameraSim(make_scene('dot_plate'), seed=7)
    observations, result = _run(gantry, camera, VisionPlan(nx=4, ny=3))
    return gantry, camera, observations, result


def test_parameters_recovered_within_tolerance(calibrated):
    gantry, camera, _, result = calibrated
    truth = gantry.errors.model
    std = result.report['gantry']['std_devs']
    # Tolerances: the unmodelled periodic screw error (1.5-2 um) dominates the noise.
    tolerance = {'lead_x': 0.3e-6, 'lead_y': 0.5e-6, 'axis_angle': 15e-6,
                 'non_orthogonality': 20e-6}
    for name, tol in tolerance.items():
        error = getattr(result.gantry, name) - getattr(truth, name)
        assert abs(error) < tol, (name, error)
        assert std[name] > 0
    assert result.camera2plate.pixel_size == pytest.approx(
        camera.optics.camera2plate.pixel_size, rel=2e-5)
    assert result.camera2plate.angle == pytest.approx(camera.optics.camera2plate.angle, abs=2e-5)


def test_nominal_model_would_be_far_worse(calibrated):
    _, _, _, result = calibrated
    leads_error = abs(result.gantry.lead_x - NOMINAL_LEAD_X) * (0.2 / NOMINAL_LEAD_X)
    assert leads_error > 20e-6  # the calibration corrects > 20 um over the X travel


def test_clean_gantry_recovers_nominal():
    from printer_alignment.sim.gantry import GantryErrors
    gantry = GantrySim(GantryErrors.ideal())
    camera = CameraSim(make_scene('dot_plate'), seed=3)
    _, result = _run(gantry, camera, VisionPlan(nx=3, ny=3))
    assert result.gantry.lead_x == pytest.approx(NOMINAL_LEAD_X, abs=0.05e-6)
    assert abs(result.gantry.non_orthogonality) < 5e-6


def test_too_few_positions_and_immobile_axis(calibrated):
    _, _, observations, result = calibrated
    with pytest.raises(CalibrationError, match='at least 4'):
        calibrate_gantry(observations[:3], result.camera2plate, 0.5e-3)
    frozen = [GantryObservation(np.array([o.revs[0], 1.0]), o.uv) for o in observations]
    with pytest.raises(CalibrationError, match='Y axis never moved'):
        calibrate_gantry(frozen, result.camera2plate, 0.5e-3)


def test_pixel_size_bad_input():
    with pytest.raises(InvalidInputError, match='NaN'):
        calibrate_pixel_size([np.array([[1.0, np.nan]] * 10)], 0.5e-3)
    with pytest.raises(CalibrationError, match='at least 9'):
        calibrate_pixel_size([np.zeros((3, 2))], 0.5e-3)
    with pytest.raises(InvalidInputError, match='pitch'):
        calibrate_pixel_size([np.zeros((30, 2))], -1.0)


def test_gantry_refuses_targets_outside_travel():
    gantry = GantrySim()
    gantry.move(0.05, 0.05)
    with pytest.raises(OutOfTravelError, match='outside the travel'):
        gantry.move(0.25, 0.05)
    assert np.allclose(gantry.axis_position, [0.05, 0.05])
    with pytest.raises(InvalidInputError):
        gantry.move(float('nan'), 0.0)


def test_gantry_landing_scatters_the_true_position_by_its_sigma():
    """A move lands ``landing_sigma`` (1 sigma per axis) off the model's position, drawn
    again only when the gantry moves; a negative or non-finite sigma is refused."""
    exact, scattered = GantrySim(), GantrySim(landing_sigma=0.5e-6, seed=4)
    offsets = []
    for x in np.linspace(0.01, 0.19, 400):
        exact.move(x, 0.05)
        scattered.move(x, 0.05)
        offsets.append(scattered.true_camera_position() - exact.true_camera_position())
    offsets = np.array(offsets)
    assert np.allclose(offsets.std(axis=0), 0.5e-6, rtol=0.12)
    assert np.all(np.abs(offsets.mean(axis=0)) < 0.1e-6)
    still = scattered.true_camera_position()
    scattered.move(*scattered.axis_position)          # no motion: the carriage stays put
    assert np.array_equal(scattered.true_camera_position(), still)
    for sigma in (-1e-6, np.nan):
        with pytest.raises(InvalidInputError, match='landing_sigma'):
            GantrySim(landing_sigma=sigma)


def test_calibration_files_are_versioned(tmp_path):
    first, v1 = write_calibration(tmp_path, 'vision', {'a': 1})
    second, v2 = write_calibration(tmp_path, 'vision', {'a': 2})
    assert (v1, v2) == (1, 2) and first.exists() and second.exists()
    assert read_calibration(tmp_path, 'vision')['a'] == 2
    assert not list(tmp_path.glob('*.tmp'))
    # Readable by the machine's other users (the drivers that load them), not 0600.
    assert {p.stat().st_mode & 0o777 for p in tmp_path.glob('vision*.yaml')} == {0o644}


def test_gantry_model_inverse_puts_the_camera_where_asked():
    from printer_alignment.core.geometry import GantryModel
    model = GantryModel(lead_x=2.0031e-3, lead_y=1.9987e-3, axis_angle=2e-3,
                        non_orthogonality=-1e-3, offset_x=-1.8e-3, offset_y=1.2e-3)
    positions = np.random.default_rng(3).uniform(0, 0.2, (20, 2))
    revs = model.revs_for(positions)
    np.testing.assert_allclose(model.camera_position(revs), positions, atol=1e-12)
    # the offsets matter: the nominal command would miss by them
    assert np.abs(revs * NOMINAL_LEADS - positions).max() > 1e-3


def _dot_views(distortion, positions, seed=3):
    from printer_alignment.core.camera_calibration import dot_grid_view
    from printer_alignment.sim.camera import CameraOptics
    camera = CameraSim(make_scene('dot_plate'), CameraOptics(distortion=distortion), seed=seed)
    return [dot_grid_view([[m.u, m.v] for m in detect_marks(camera.capture(np.array(p))).marks],
                          0.5e-3, 0.5e-3 / 12.5e-6) for p in positions]


def test_lens_distortion_from_square_on_dot_plate_views():
    from printer_alignment.core.camera_calibration import calibrate_intrinsics
    positions = [(0.05, 0.05), (0.0512, 0.0509), (0.0527, 0.0503), (0.0504, 0.0531)]
    # True: k1 0.5 on coordinates normalised by 2000 px (4.8 px at the image corner).
    report = calibrate_intrinsics(_dot_views((0.5, 0, 0, 0), positions), (640, 480),
                                  focal_px=2000.0).report()
    p = report['parameters']
    assert p['k1'] == pytest.approx(0.5, abs=0.01) and abs(p['k2']) < 0.1
    assert abs(p['p1']) < 2e-3 and abs(p['p2']) < 2e-3
    assert report['rms_reprojection_px'] < 0.05
    assert set(report['fixed']) == {'fx', 'fy', 'cx', 'cy', 'k3'}
    clean = calibrate_intrinsics(_dot_views((0, 0, 0, 0), positions[:3]), (640, 480),
                                 focal_px=2000.0).report()['parameters']
    assert abs(clean['k1']) < 0.01


def test_dot_grid_view_refuses_a_wrong_pitch():
    from printer_alignment.core.camera_calibration import dot_grid_view
    dots = np.array([[i * 40.0 + 100, j * 40.0 + 100] for i in range(4) for j in range(3)])
    np.testing.assert_allclose(np.ptp(dot_grid_view(dots, 0.5e-3, 40.0).model, axis=0),
                               [1.5e-3, 1.0e-3])
    with pytest.raises(CalibrationError, match='pitch'):
        dot_grid_view(dots, 0.5e-3, 60.0)
    with pytest.raises(CalibrationError, match='at least 6'):
        dot_grid_view(dots[:4], 0.5e-3, 40.0)


def _tilted_grid(rng, tilt_rad, cols=10, rows=8, pitch=0.025, dot_radius=0.0075):
    """A 10 x 8 dot grid seen through a homography (the plate turned by ``tilt_rad`` about
    its x axis): each dot rendered as the ellipse the homography's local affine map
    makes of it. Returns the image and the ellipse centres (px) in target_points order."""
    from printer_alignment.core.camera_calibration import target_points
    from calib_core.sim.render import MarkShape, render
    model = target_points('circles', cols, rows, pitch) - [pitch * (cols - 1) / 2, pitch * (rows - 1) / 2]
    focal, distance = 500.0, 0.45
    c, s = np.cos(tilt_rad), np.sin(tilt_rad)

    def project(xy):
        x, y = xy[..., 0], xy[..., 1]
        depth = distance + s * y
        return np.stack([320 + focal * x / depth, 240 + focal * c * y / depth], -1)

    centres = project(model)
    marks = []
    for point, centre in zip(model, centres):
        step = 1e-6
        jac = np.column_stack([(project(point + [step, 0]) - project(point - [step, 0])),
                               (project(point + [0, step]) - project(point - [0, step]))]) / (2 * step)
        axes, vectors = np.linalg.svd(jac * dot_radius)[0:2]
        marks.append(MarkShape('circle', *centre, float(np.sqrt(vectors[0] * vectors[1])),
                               angle=float(np.arctan2(axes[1, 0], axes[0, 0])),
                               aspect=float(vectors[0] / vectors[1])))
    image = render(marks, 640, 480, 0.8, 200.0, -150.0) + rng.normal(0, 2.0, (480, 640))
    return image, np.array([(m.u, m.v) for m in marks])


@pytest.mark.parametrize('tilt_deg', [0.0, 50.0])
def test_circle_grid_points_are_our_marks_in_grid_order(rng, tilt_deg):
    """find_target on a circle grid returns our detector's centres (ellipses on the
    tilted plate, up to aspect 1.6 here) in OpenCV's grid order: every point within
    0.03 px of its dot, in target_points order (or turned by 180 degrees, which a
    symmetric grid cannot tell apart)."""
    from printer_alignment.core.camera_calibration import find_target
    image, truth = _tilted_grid(rng, np.radians(tilt_deg))
    points = find_target(image, 'circles', 10, 8)
    errors = min((points - truth, points - truth[::-1]), key=lambda e: np.abs(e).max())
    assert np.abs(errors).max() < 0.03


@pytest.mark.parametrize('plan, message', [
    ({'pitch': 0.0}, 'pitch must be a positive length'),
    ({'pitch': 0.5}, 'look like mm'),
    ({'nx': 2.7}, 'nx must be an integer from 2 to'),
    ({'ny': True}, 'ny must be an integer'),
    ({'x_range': (0.2, 0.0)}, 'x_range must be (low, high)'),
    ({'y_range': (0.0, 150.0)}, 'look like mm'),
])
def test_a_bad_vision_plan_is_refused_before_anything_moves(plan, message):
    with pytest.raises(InvalidInputError, match=re.escape(message)):
        VisionPlan(**plan)


def test_stage_plan_counts_must_be_integers():
    from printer_alignment.core.stage_calibration import StagePlan
    with pytest.raises(InvalidInputError, match='grid must be an integer'):
        StagePlan(grid=(5, 2.5, 3))
    assert StagePlan(sweep_points=9.0).sweep_points == 9
