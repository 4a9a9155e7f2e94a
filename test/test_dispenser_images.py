"""The dispenser's rendered board frames through the shared Mark detector (the dots'
ellipse centres, perspective included, and their names) and the ISO 230-7 names of its
axes' errors. The full calibration on rendered frames runs in `make bench`
(bench_results/five_axis.md)."""
import numpy as np
import pytest

from calib_core.errors import CalibrationError
from dispenser_calib.core.board_images import name_dots, observe_frame
from dispenser_calib.core.data import SHIPPED_BOARD, board_points
from dispenser_calib.core.iso230 import iso230_7
from dispenser_calib.core.model import nominal_model, project
from dispenser_calib.core.procedure import plan_stops
from dispenser_calib.sim.images import dot_ellipse, render_board
from dispenser_calib.sim.machine import IMAGE_SIZE, true_model

TOLERANCE = {'conic_px': 1e-9, 'detected_px': 0.06, 'perspective_shift_px': 0.01}


def _tilted_stop():
    """A calibration stop where A alone turns (the dots seen most obliquely)."""
    stops = plan_stops(nominal_model())
    return next(s for s in stops if abs(s[3]) > 0.3 and s[4] == 0)


def test_ellipse_centre_of_a_projected_dot_is_not_the_projected_centre():
    """The closed form of project_rows(dot_radius) against the conic mapped by the
    homography (no distortion: both are exact); the perspective shift itself is real."""
    model = true_model(1).with_values(k1=0.0, k2=0.0, p1=0.0, p2=0.0)
    board, _ = board_points()
    pose = _tilted_stop()
    conic = np.array([[m.u, m.v] for m in (dot_ellipse(model, pose, p) for p in board)])
    closed = project(model, board, pose[None], SHIPPED_BOARD.radius)[0]
    centre = project(model, board, pose[None])[0]
    assert np.abs(conic - closed).max() < TOLERANCE['conic_px']
    assert np.abs(conic - centre).max() > TOLERANCE['perspective_shift_px']


def test_rendered_frame_gives_every_dot_named_at_its_ellipse_centre():
    truth, nominal = true_model(0), nominal_model()
    pose = _tilted_stop()
    image = observe_frame(render_board(truth, pose, IMAGE_SIZE, seed=3), pose, nominal, 'tilted')
    board, indices = board_points()
    assert len(image.indices) == len(indices)
    where = {tuple(i): k for k, i in enumerate(indices)}
    expected = project(truth, board, pose[None], SHIPPED_BOARD.radius)[0][[where[tuple(i)] for i in image.indices]]
    assert np.abs(image.pixels - expected).max() < TOLERANCE['detected_px']


def test_dot_centre_noise_moves_each_detected_centre_by_its_sigma():
    """``centre_noise_px`` (the source's 0.1 px dot-centre noise) draws each dot that far
    off its true image, per frame: the detected centres scatter about the truth by it
    (the detector's own floor, about 0.003 px, adds nothing visible)."""
    truth, nominal = true_model(0), nominal_model()
    pose = _tilted_stop()
    board, indices = board_points()
    where = {tuple(i): k for k, i in enumerate(indices)}
    expected = project(truth, board, pose[None], SHIPPED_BOARD.radius)[0]
    image = observe_frame(render_board(truth, pose, IMAGE_SIZE, seed=3, centre_noise_px=0.1),
                          pose, nominal, 'tilted')
    scatter = image.pixels - expected[[where[tuple(i)] for i in image.indices]]
    assert len(scatter) == len(indices)
    assert np.allclose(scatter.std(axis=0), 0.1, rtol=0.2)
    assert np.all(np.abs(scatter.mean(axis=0)) < 0.03)


@pytest.mark.parametrize('shift_pitches', [0.3, 0.7, 1.3])
def test_naming_survives_a_prediction_off_by_more_than_half_a_pitch(shift_pitches):
    """The full board in view: the whole-pitch lattice shift is unique and corrects it."""
    board, indices = board_points()
    truth_pixels = project(true_model(0), board, plan_stops(nominal_model())[0][None])[0]
    pitch_px = np.linalg.norm(truth_pixels[1] - truth_pixels[0])
    predicted = truth_pixels + np.array([shift_pitches * pitch_px, 0.2 * pitch_px])
    detected = truth_pixels[::-1] + np.random.default_rng(0).normal(0, 0.05, truth_pixels.shape)
    names = name_dots(detected, predicted, indices)
    assert np.array_equal(names, np.arange(len(board))[::-1])


def test_blank_frame_is_a_clear_error_naming_the_image():
    blank = np.full((IMAGE_SIZE[1], IMAGE_SIZE[0]), 200, np.uint8)
    with pytest.raises(CalibrationError, match='image007: no board dots found.*out of view'):
        observe_frame(blank, plan_stops(nominal_model())[0], nominal_model(), 'image007')


def test_iso230_7_names_in_the_machine_frame():
    """Known errors on the nominal machine (board frame = machine frame) read back under
    their ISO names and signs; the same machine seen by a camera turned otherwise and a
    board placed elsewhere gives the same values."""
    model = nominal_model().with_values(c_tilt_1=1e-4, c_tilt_2=-2e-4, a_tilt_1=3e-4,
                                        a_tilt_2=-5e-5, c_offset_1=50e-6, c_offset_2=-20e-6,
                                        a_offset_1=30e-6)
    iso = iso230_7(model)
    # C tilted towards +y by 1e-4 is turned about x by -1e-4 (right-hand rule)
    assert iso['E_A0C'] == pytest.approx(-1e-4, rel=1e-3)
    assert iso['E_B0C'] == pytest.approx(2e-4, rel=1e-3)          # c_tilt_2 is along -x
    assert iso['E_C0A'] == pytest.approx(3e-4, rel=1e-3)          # a_tilt_1 is along +y
    assert iso['E_B0A'] == pytest.approx(5e-5, rel=1e-3)          # a_tilt_2 along +z: -rot about y
    assert iso['E_Z0A'] == pytest.approx(-0.030, abs=1e-9)        # A's line 30 mm below the board
    assert iso['E_Y0A'] == pytest.approx(30e-6, abs=1e-9)
    assert iso['E_Y0C'] == pytest.approx(50e-6, abs=1e-8)
    assert iso['E_X0C'] == pytest.approx(20e-6, abs=1e-8)         # c_offset_2 is along -x
    assert iso['offset_C_from_A_y'] == pytest.approx(20e-6, abs=1e-8)
    # The camera turned by 2 degrees about its axis: the same machine, other parameters.
    turn = np.deg2rad(2.0)
    turned = model.with_values(rm_z=turn)
    extra = turned.rotation @ model.rotation.T
    affine = extra @ model.affine
    turned = turned.with_values(**{f'M{r}{c}': affine[r, c] for r in range(3) for c in range(4)})
    again = iso230_7(turned)
    for name, value in iso.items():
        assert again[name] == pytest.approx(value, abs=1e-12), name
