"""The closed loop on two real cameras others calibrated (test/data/measured, ROS-Industrial
industrial_calibration, Apache-2.0): a 640 x 480 camera's 10 x 10 dot grid in 14 views, and
an AVT Mako's ChArUco corners in 15. What it adds agrees with OpenCV's own calibration of
the same points (the sources' figures, SOURCES.md), what it leaves is said in pixels, and a
view whose points were mis-ordered by the detector is named, by the loop and by
``calibrate camera``."""
import json

import numpy as np
import pytest

from calib_core.closed_loop import LoopConfig, analyze
from machine_alignment.cli import main as cli_main
from printer_alignment.core.camera_calibration import read_correspondences
from printer_alignment.core.loop_models import CameraLoopModel

DOTS = 'ric_circlegrid_640'
CHARUCO = 'ric_charuco_mako'


def _loop(path, size):
    return analyze(CameraLoopModel(read_correspondences(path), size), LoopConfig()).report


def _agrees(effect, independent, sigmas=3.0):
    """Each of the effect's parameters within ``sigmas`` of its standard deviation of the
    independent value."""
    for name, value in independent.items():
        found, sigma = effect['parameters'][name], effect['std_devs'][name]
        assert abs(found - value) < sigmas * sigma, (name, found, sigma, value)


def test_the_dot_grid_camera_gets_the_distortion_opencv_finds(measured_data):
    """OpenCV with k1, k2, p1, p2, k3: 0.0816, -0.2284, 0.0092, -0.0022, 0.4923 at 0.188 px
    RMS (fitted rows; 0.202 px without k3). Without its k3 candidate the loop had stopped
    at k1, k2, p1, p2, held out 0.211 px RMS and 2.44 px max (now 0.198 and 1.40 px), and
    named the rest "lens distortion of higher order". Structure left is reported in px:
    it had been printed in normalised image coordinates labelled px (5e-5 'px' for 0.028
    px)."""
    report = _loop(measured_data / DOTS / 'correspondences.csv', (640, 480))
    added = {e['name']: e for e in report['effects_added']}
    assert list(added) == ['radial_distortion', 'radial_distortion_k3', 'tangential_distortion']
    _agrees(added['radial_distortion'], {'k1': 0.0816, 'k2': -0.2284})
    _agrees(added['radial_distortion_k3'], {'k3': 0.4923})
    _agrees(added['tangential_distortion'], {'p1': 0.0092, 'p2': -0.0022})
    assert report['rms_after'] < 0.2 < report['rms_before']
    assert report['max_after'] < 1.6
    structure = [u for u in report['unexplained'] if 'structure_rms' in u]
    assert structure
    for item in structure:
        assert 0.005 < item['structure_rms'] < report['rms_after'], item
    assert not report['outliers'].get('strata')


def test_a_mis_ordered_view_is_named(measured_data, tmp_path):
    """View 11, which OpenCV's grid finder ordered wrongly (its last row 6.5 px off a
    homography), put back among views 0-7 (the run's time: the whole set names it too):
    most of its rows are outliers, and the report names it and no other view."""
    path = tmp_path / 'with_view_11.csv'
    lines = (measured_data / DOTS / 'correspondences.csv').read_text().splitlines()
    suspect = (measured_data / DOTS / 'view11_suspect.csv').read_text().splitlines()[1:]
    kept = [line for line in lines[1:] if int(line.split(',')[0]) <= 7]
    path.write_text('\n'.join([lines[0], *kept, *suspect]) + '\n')
    report = _loop(path, (640, 480))
    named = report['outliers']['strata']
    assert [s['label'] for s in named] == ['11'], named
    assert named[0]['outliers'] >= 40 and named[0]['rows'] == 100   # 46 (70 with all views)
    assert all(row['view'] == '11' for row in report['outliers']['rows'][:10])


def test_the_mako_gets_radial_distortion_only(measured_data):
    """OpenCV with k1, k2: -0.1297, 0.2175 at 0.527 px RMS; p1, p2 (-0.0015, 0.0015) and k3
    leave it at 0.525 px: nothing else is worth adding, k3 included."""
    report = _loop(measured_data / CHARUCO / 'correspondences.csv', (1600, 1200))
    assert [e['name'] for e in report['effects_added']] == ['radial_distortion']
    _agrees(report['effects_added'][0], {'k1': -0.1297, 'k2': 0.2175})
    assert report['rms_after'] < 0.7 < report['rms_before']
    assert np.isfinite(report['max_after'])


def test_calibrate_camera_names_the_mis_ordered_view_and_calibrates_without_it(
        measured_data, tmp_path, capsys):
    """calibrate camera on all 15 views: view 11 reprojects at 12.8x the views' median and
    moves fx by 2.4 % (529.4 against 542.6 px, the sources' figures); it is named, and the
    calibration without it (OpenCV's of the 14 good views) is given beside. The two clean
    sets name no view."""
    lines = (measured_data / DOTS / 'correspondences.csv').read_text().splitlines()
    suspect = (measured_data / DOTS / 'view11_suspect.csv').read_text().splitlines()[1:]
    path, out = tmp_path / 'all_views.csv', tmp_path / 'camera.json'
    path.write_text('\n'.join(lines + suspect) + '\n')
    assert cli_main(['calibrate', 'camera', '--data', str(path), '--image-size', '640x480',
                     '--json', str(out)]) == 0
    report = json.loads(out.read_text())
    assert [v['view'] for v in report['suspect_views']] == ['11']
    assert 'view 11 reprojects at' in capsys.readouterr().out
    assert report['parameters']['fx'] == pytest.approx(529.4, abs=0.5)
    without = report['without_suspect_views']
    assert without['num_views'] == 14
    assert without['parameters']['fx'] == pytest.approx(542.61, abs=0.05)
    assert without['rms_reprojection_px'] == pytest.approx(0.188, abs=0.001)
    for name, size in ((DOTS, '640x480'), (CHARUCO, '1600x1200')):
        assert cli_main(['calibrate', 'camera', '--data',
                         str(measured_data / name / 'correspondences.csv'), '--image-size',
                         size, '--json', str(out)]) == 0
        assert 'suspect_views' not in json.loads(out.read_text()), name


def _with_centre_bias(views, size):
    """OpenCV's full model (fx, fy, cx, cy, k1, k2, p1, p2, k3, a pose per view) fitted to
    the views twice: with every point the image of the dot's centre, and with it the
    centre of the dot's image, a circle of radius r about the point, whose squared radius
    ``s`` is then fitted too (any sign). Under perspective the image of a circle is an
    ellipse whose centre is, in homogeneous normalised coordinates, p p_z - r^2 (a1 a1_z
    + a2 a2_z) with p the point and a1, a2 the plate's axes in the camera frame (Heikkila
    2000; ``dispenser_calib.core.model.dot_centres``, written out here with s for r^2).
    Returns (RMS px without, RMS px with, s m^2, its standard deviation)."""
    import cv2
    from scipy.optimize import least_squares
    objects = [np.column_stack([v.model, np.zeros(len(v.model))]) for v in views]
    _, matrix, distortion, rvecs, tvecs = cv2.calibrateCamera(
        [o.astype(np.float32) for o in objects], [v.pixels.astype(np.float32) for v in views],
        size, None, None)

    def residuals(x):
        (fx, fy, cx, cy), (k1, k2, p1, p2, k3), s = x[:4], x[4:9], x[-1]
        out = []
        for view, points, pose in zip(views, objects, x[9:-1].reshape(-1, 6)):
            rotation = cv2.Rodrigues(pose[:3])[0]
            p = points @ rotation.T + pose[3:]
            axes = rotation[:, 0] * rotation[2, 0] + rotation[:, 1] * rotation[2, 1]
            centre = (p[:, :2] * p[:, 2:] - s * axes[:2]) / (p[:, 2:] ** 2 - s * axes[2])
            x_n, y_n = centre.T
            r2 = x_n ** 2 + y_n ** 2
            radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
            u = fx * (x_n * radial + 2 * p1 * x_n * y_n + p2 * (r2 + 2 * x_n ** 2)) + cx
            v = fy * (y_n * radial + p1 * (r2 + 2 * y_n ** 2) + 2 * p2 * x_n * y_n) + cy
            out.append(np.column_stack([u, v]) - view.pixels)
        return np.concatenate(out).ravel()

    start = np.r_[matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], distortion.ravel()[:5],
                  np.concatenate([np.r_[r.ravel(), t.ravel()] for r, t in zip(rvecs, tvecs)])]
    without = least_squares(lambda x: residuals(np.r_[x, 0.0]), start, method='lm', x_scale='jac')
    with_s = least_squares(residuals, np.r_[without.x, 0.0], method='lm', x_scale='jac')
    variance = 2 * with_s.cost / (with_s.fun.size - with_s.x.size)
    sigma = np.sqrt(np.linalg.inv(with_s.jac.T @ with_s.jac)[-1, -1] * variance)

    def rms(fit):
        return float(np.sqrt(2 * np.mean(fit.fun ** 2)))
    return rms(without), rms(with_s), float(with_s.x[-1]), float(sigma)


def test_the_dot_grids_leftover_trend_is_not_its_dots_perspective_bias(measured_data):
    """The trend the loop leaves on the dot grid (the y residuals against the image radius,
    0.026 px) is not the perspective bias of the dots' centres. Fitted jointly with every
    other parameter, r^2 comes out negative (-0.036 +- 0.004 m^2: no circle), while a dot
    as large as the 25.4 mm pitch allows (r < 12.7 mm, r^2 < 1.6e-4 m^2) would be under
    a tenth of that sigma (0.04): these views cannot show the bias of any real dot. The
    Mako's ChArUco corners, points with no area, get r^2 within one sigma of zero."""
    dots = _with_centre_bias(read_correspondences(measured_data / DOTS / 'correspondences.csv'),
                             (640, 480))
    rms_without, rms_with, s, sigma = dots
    assert s < -5 * sigma, dots
    assert (0.0127 ** 2) < 0.1 * sigma, dots           # 0.04 sigma
    assert rms_without - rms_with < 0.005, dots       # 0.1876 -> 0.1857 px
    corners = _with_centre_bias(
        read_correspondences(measured_data / CHARUCO / 'correspondences.csv'), (1600, 1200))
    assert abs(corners[2]) < corners[3], corners


def test_views_named_by_their_photos_file_names_are_the_same_views(measured_data, tmp_path):
    """A view may be named by any text, such as its photo's file name: the views are the
    same (in the order they first appear), the calibration the same, and the suspect view
    named by its file."""
    lines = (measured_data / DOTS / 'correspondences.csv').read_text().splitlines()
    suspect = (measured_data / DOTS / 'view11_suspect.csv').read_text().splitlines()[1:]
    numbered, named = tmp_path / 'numbered.csv', tmp_path / 'named.csv'
    numbered.write_text('\n'.join(lines + suspect) + '\n')
    named.write_text('\n'.join([lines[0]] + [f'photo_{int(line.split(",")[0]):02d}.png,'
                                             + line.split(',', 1)[1]
                                             for line in lines[1:] + suspect]) + '\n')
    reports = {}
    for path in (numbered, named):
        out = tmp_path / f'{path.stem}.json'
        assert cli_main(['calibrate', 'camera', '--data', str(path), '--image-size',
                         '640x480', '--json', str(out)]) == 0
        reports[path.stem] = json.loads(out.read_text())
    # The same views in another order (view 11 last, as in the file): OpenCV's solution
    # to rounding.
    assert reports['named']['parameters'] == pytest.approx(reports['numbered']['parameters'],
                                                           rel=1e-6)
    assert [v['view'] for v in reports['named']['suspect_views']] == ['photo_11.png']
    assert cli_main(['analyze', 'camera', '--data', str(named)]) == 0
