"""Random-dot (Uchiya) markers: dot finding, LLAH matching, and the real photos."""
import cv2
import numpy as np
import pytest
import yaml

from calib_core.errors import DetectionError, InvalidInputError
from printer_alignment.core.camera_calibration import (
    read_boofcv_intrinsics, reprojection_errors, rms_px)
from printer_alignment.core.dot_markers import (
    DotConfig, LlahConfig, LlahIndex, find_dots, load_uchiya_markers, read_marker_photos)

MARKER_WIDTH_M = 0.08


def random_marker(rng, dots=30, min_spacing=0.008):
    """Dot centres (m) spread over an 8 cm square, no two closer than ``min_spacing``."""
    points = []
    while len(points) < dots:
        p = rng.uniform(-0.035, 0.035, 2)
        if all(np.hypot(*(p - q)) >= min_spacing for q in points):
            points.append(p)
    return np.array(points)


def homography(rng, centre_px, scale_px_per_m):
    """Marker plane (m) -> photo (px): rotation, scale and a mild perspective."""
    angle = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(angle), np.sin(angle)
    similarity = np.array([[scale_px_per_m * c, -scale_px_per_m * s, centre_px[0]],
                           [scale_px_per_m * s, scale_px_per_m * c, centre_px[1]], [0, 0, 1]])
    tilt = np.array([[1, 0.15, 0], [0, 1, 0], rng.uniform(-2.0, 2.0, 3) * [1, 1, 0] + [0, 0, 1]])
    return similarity @ tilt


def project(h, xy):
    return cv2.perspectiveTransform(np.asarray(xy, float)[None], h)[0]


def render(rng, dots_px, size=(800, 600), radius_px=3.0, noise=2.0):
    """Dark anti-aliased dots on light paper, 8-bit, with blur and read noise."""
    canvas = np.full((size[1], size[0]), 220, np.uint8)
    shift = 4
    for u, v in dots_px:
        cv2.circle(canvas, (int(round(u * 2 ** shift)), int(round(v * 2 ** shift))),
                   int(round(radius_px * 2 ** shift)), 30, -1, cv2.LINE_AA, shift)
    blurred = cv2.GaussianBlur(canvas.astype(float), (0, 0), 0.7)
    return np.clip(blurred + rng.normal(0, noise, blurred.shape), 0, 255).astype(np.uint8)


@pytest.fixture
def markers(rng):
    return {k: random_marker(rng) for k in range(20)}


@pytest.fixture
def index(markers):
    return LlahIndex(markers)


def test_markers_found_under_perspective_with_occlusion_and_clutter(rng, markers, index):
    placed = {3: homography(rng, (200, 170), 2000), 11: homography(rng, (560, 200), 1800),
              17: homography(rng, (380, 440), 2200)}
    photo_dots, truth = [], {}
    for marker_id, h in placed.items():
        visible = np.sort(rng.choice(30, 25, replace=False))      # 5 dots occluded
        truth[marker_id] = dict(zip(visible, range(len(photo_dots), len(photo_dots) + 25)))
        photo_dots += list(project(h, markers[marker_id][visible]))
    clutter = rng.uniform([0, 0], [800, 600], (80, 2))
    clutter = clutter[np.min(np.linalg.norm(clutter[:, None] - np.array(photo_dots)[None], axis=2),
                             axis=1) > 12]
    true_px = np.vstack([photo_dots, clutter])
    dots = find_dots(render(rng, true_px))
    # Which found dot is which true dot (all are found, each within 0.1 px).
    nearest = np.argmin(np.linalg.norm(dots[:, None] - true_px[None], axis=2), axis=1)
    assert len(dots) == len(true_px)
    assert np.max(np.linalg.norm(dots - true_px[nearest], axis=1)) < 0.1

    matches = index.match(dots)

    assert sorted(m.marker_id for m in matches) == sorted(placed)
    for m in matches:
        assert len(m.marker_dots) >= 24
        for marker_dot, photo_dot in zip(m.marker_dots, m.photo_dots):
            assert truth[m.marker_id][marker_dot] == nearest[photo_dot]
        assert m.rms_px < 0.1
        np.testing.assert_allclose(project(m.homography, markers[m.marker_id]),
                                   project(placed[m.marker_id], markers[m.marker_id]), atol=0.2)


def test_clutter_and_unknown_markers_match_nothing(rng, index):
    """Random dots, and a random-dot marker the index does not hold, are not markers."""
    for _ in range(3):
        clutter = rng.uniform([0, 0], [800, 600], (400, 2))
        assert index.match(clutter) == []
        stranger = project(homography(rng, (400, 300), 3000), random_marker(rng))
        assert index.match(stranger) == []


def test_real_random_dot_photos(real_data):
    """BoofCV's photos: the markers whose printed numbers can be read in the photo, all
    36 on the wall, and reprojection with the intrinsics shipped beside the photos."""
    folder = real_data / 'boofcv_fiducial_dots' / 'random_dots'
    index = LlahIndex(load_uchiya_markers(folder / 'descriptions.yaml'))
    photos, size, failures = read_marker_photos(sorted(folder.glob('image0*.jpg')), index)
    assert failures == [] and size == (800, 600)
    ids = {p.path[-11:]: sorted(m.marker_id for m in p.matches) for p in photos}
    assert ids['image00.jpg'] == [0, 1, 3, 84, 86, 87]                # numbers printed beside them
    assert ids['image01.jpg'] == list(range(12)) + list(range(44, 56)) + list(range(104, 116))
    assert {85, 87} <= set(ids['image02.jpg'])
    assert ids['image03.jpg'] == [2]                                  # the needle in the haystack

    shipped = yaml.safe_load((folder / 'intrinsic.yaml').read_text())
    pin = shipped['pinhole']
    camera = np.array([[pin['fx'], 0, pin['cx']], [0, pin['fy'], pin['cy']], [0, 0, 1]])
    k1, k2 = shipped['radial_tangential']['radial']
    views = [v for p in photos for v in p.views()]
    # One dot given to the wrong marker dot would cost pixels, not tenths.
    errors = reprojection_errors(camera, [k1, k2, 0, 0, 0], views)
    assert rms_px(errors) < 0.3 and max(np.abs(e).max() for e in errors) < 2.0


def test_bad_input(tmp_path, rng, index):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('markers: [[[0, 1], [2]]]\nunits: cm\n')
    with pytest.raises(InvalidInputError, match='marker 0'):
        load_uchiya_markers(bad)
    bad.write_text('units: furlong\nmarkers: [[[0, 1]]]\n')
    with pytest.raises(InvalidInputError, match='furlong'):
        load_uchiya_markers(bad)
    bad.write_text('{{{')
    with pytest.raises(InvalidInputError, match='is not valid YAML'):
        load_uchiya_markers(bad)
    with pytest.raises(InvalidInputError, match='needs more'):
        LlahIndex({0: random_marker(rng, dots=8)})
    bad.write_text('pinhole: {fx: 600, fy: 600, cx: 320}\n')
    with pytest.raises(InvalidInputError, match='not BoofCV pinhole'):
        read_boofcv_intrinsics(bad)
    bad.write_text('pinhole: {fx: .nan, fy: 600, cx: 320, cy: 240}\n')
    with pytest.raises(InvalidInputError, match='NaN'):
        read_boofcv_intrinsics(bad)
    with pytest.raises(InvalidInputError):
        LlahConfig(neighbours=5, combination=6)
    with pytest.raises(InvalidInputError):
        DotConfig(block_px=30)
    with pytest.raises(DetectionError, match='no dot'):
        find_dots(np.full((100, 100), 200, np.uint8))
    with pytest.raises(InvalidInputError):
        find_dots(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(InvalidInputError, match='finite'):
        index.match(np.array([[0.0, np.nan]] * 20))
    with pytest.raises(DetectionError, match='LLAH needs more'):
        index.match(rng.uniform(0, 100, (5, 2)))
