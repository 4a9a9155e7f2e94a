"""The simulated five-axis dispenser: true errors of realistic size (SEEDS_CDE.md section
003, proposed), the dot board's images as the dots' ellipse centres with detection noise, some images
with a mis-detected dot, and the stroke limits (refused). Truth is for tests and benches."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core.datasets import directions_from_order
from dispenser_calib.core.data import Image, board_points
from dispenser_calib.core.localisation import reached
from dispenser_calib.core.model import (
    NAMES, DispenserModel, rodrigues, _camera_rows, chain_rotation, nominal_model, project, project_rows,
    rotation_vector_matrix)
from dispenser_calib.core.procedure import SHIPPED_WORKSPACE, Workspace
from dispenser_calib.core.target_poses import TargetPoses

IMAGE_SIZE = (2448, 2048)


def true_model(seed: int = 0, nominal: DispenserModel | None = None) -> DispenserModel:
    """The ``nominal`` machine (default: the shipped one, :func:`nominal_model`) with:
    intrinsics off by up to 1 % and a lens with k1 -0.08, k2 0.15 and small tangential
    terms; the camera tilted by up to 3 degrees; the linear axes out of square by 50-200
    urad and off in scale by up to 100 ppm; the board placed within 1 mm; each rotary axis
    tilted by 100-500 urad and its line off by 20-200 um."""
    rng = np.random.default_rng(seed)
    nominal = nominal_model() if nominal is None else nominal
    v = dict(zip(NAMES, nominal.values))

    def signed(low, high):
        return float(rng.uniform(low, high) * rng.choice([-1, 1]))
    v['fx'] *= 1 + rng.uniform(-0.01, 0.01)
    v['fy'] = v['fx'] * (1 + rng.uniform(-1e-3, 1e-3))
    v['cx'] += rng.uniform(-20, 20)
    v['cy'] += rng.uniform(-20, 20)
    v.update(k1=-0.08, k2=0.15, p1=rng.uniform(-5e-4, 5e-4), p2=rng.uniform(-5e-4, 5e-4))
    v['rm_x'] += np.deg2rad(rng.uniform(-3, 3))
    v['rm_y'] += np.deg2rad(rng.uniform(-3, 3))
    v['rm_z'] += np.deg2rad(rng.uniform(-3, 3))
    for name in ('a_tilt_1', 'a_tilt_2', 'c_tilt_1', 'c_tilt_2'):
        v[name] = signed(100e-6, 500e-6)
    for name in ('a_offset_1', 'c_offset_1', 'c_offset_2'):
        v[name] = signed(20e-6, 200e-6)
    v['a_offset_2'] += signed(20e-6, 200e-6)
    model = DispenserModel(np.array([v[n] for n in NAMES]))
    # The linear axes as the camera sees them: directions out of square, scales off.
    rotation = model.rotation
    directions = np.eye(3) + np.array([[0, signed(50e-6, 200e-6), signed(50e-6, 200e-6)],
                                       [0, 0, signed(50e-6, 200e-6)], [0, 0, 0]]).T
    scale = 1 + rng.uniform(-100e-6, 100e-6, 3)
    columns = np.column_stack([-rotation @ directions[:, 0] * scale[0],
                               rotation @ directions[:, 1] * scale[1],
                               -rotation @ directions[:, 2] * scale[2],
                               nominal.affine[:, 3]
                               + rotation @ rng.uniform(-1e-3, 1e-3, 3) * [1, 1, 0.2]])
    return model.with_values(**{f'M{r}{c}': columns[r, c] for r in range(3) for c in range(4)})


def observe(truth: DispenserModel, stops: np.ndarray, noise_px: float = 0.1, seed: int = 0,
            bad_fraction: float = 0.0, angular_error=None, c_backlash: float = 0.0,
            image_size=IMAGE_SIZE, workspace: Workspace = SHIPPED_WORKSPACE,
            pose_sigma=None) -> tuple[list[Image], list[str]]:
    """The board imaged at each stop: the visible dots' ellipse centres (as a detector
    finds them) with ``noise_px`` of detection noise; a ``bad_fraction`` of the images has
    one dot mis-detected by 15-30 px and one occluded. ``angular_error`` (a function of c,
    rad) is what C turns beyond its reading (a worm gear's error); C lags its reading by
    ``c_backlash`` / 2 (rad) against the direction it last moved in (lost motion). Stops
    outside the ``workspace``'s strokes are refused; the board is the ``workspace``'s;
    the camera has ``image_size`` (w, h) px. ``pose_sigma`` (5,) (m, rad; a machine description's positioning noise and
    repeatability) is how far each axis stops from its reading, 1 sigma. Returns the
    images and the names of the bad ones (truth)."""
    rng = np.random.default_rng(seed + 60)
    board, indices = board_points(workspace.board)
    images = []
    bad = set(rng.choice(len(stops), int(round(bad_fraction * len(stops))), replace=False))
    approach = directions_from_order(np.asarray(stops)[:, 4:5])[:, 0]
    # Its own stream, so that a machine without positioning noise sees the same dots.
    stopped = np.random.default_rng(seed + 61).normal(
        0.0, 1.0, (len(stops), 5)) * (np.zeros(5) if pose_sigma is None else pose_sigma)
    for k, pose in enumerate(stops):
        workspace.check(pose)
        turned = pose + stopped[k]
        if angular_error is not None:
            turned[4] += angular_error(pose[4])
        turned[4] -= 0.5 * c_backlash * approach[k]
        pixels = project(truth, board, turned[None], workspace.board.radius)[0]
        inside = (np.all(np.isfinite(pixels), axis=1) & (pixels[:, 0] >= 0)
                  & (pixels[:, 0] <= image_size[0] - 1) & (pixels[:, 1] >= 0)
                  & (pixels[:, 1] <= image_size[1] - 1))
        pixels = pixels + rng.normal(0, noise_px, pixels.shape)
        if k in bad:
            wrong = rng.choice(np.flatnonzero(inside), 2, replace=False)
            pixels[wrong[0]] += rng.uniform(15, 30) * rng.choice([-1, 1], 2)
            inside[wrong[1]] = False
        images.append(Image(f'image{k:03d}', pose.copy(), indices[inside], pixels[inside],
                            workspace.board))
    return images, sorted(images[k].name for k in bad)


def measure_target_poses(truth: DispenserModel, a: np.ndarray, c: np.ndarray,
                         times: np.ndarray, position_noise: float = 20e-6,
                         rotation_noise: float = 50e-6, seed: int = 0,
                         angular_error=None, drift: np.ndarray | None = None,
                         c_error_motion=None, c_tilt_motion=None,
                         tilt_height: float = 0.0) -> TargetPoses:
    """The board's pose measured by the machine's own camera (linear axes at zero) at
    each table angle a, c (n,) rad and time (n,) s: the board's frame at reset is the table
    frame, so the truth's axes are those of the measured target. ``angular_error`` (a
    function of c, rad) is what C turns beyond its reading (a worm gear's error);
    ``drift`` (3,) m/s moves the board in the camera frame (Z's thermal drift); noise is
    normal, ``position_noise`` m per coordinate and ``rotation_noise`` rad per axis.
    ``c_error_motion`` (a function of c, (n, 3) m) shifts C's rotor, and the board with it,
    along C's housing directions: x along A's axis (made perpendicular to C's), y, and z
    along C's axis, all carried by A (ISO 230-7 EXC, EYC, EZC). ``c_tilt_motion`` (a
    function of c, (n, 2) rad) tilts C's rotor about the first two of those directions
    (EAC, EBC when C's x is the machine's X), about the point of C's axis ``tilt_height``
    m along it from the foot of the board's origin (a bearing below the table top: < 0)."""
    rng = np.random.default_rng(seed + 70)
    turned = c + (angular_error(c) if angular_error is not None else 0.0)
    stops = np.column_stack([np.zeros((len(a), 3)), a, turned])
    position = _camera_rows(truth, np.zeros((len(a), 3)), stops)
    if drift is not None:
        position = position + np.outer(times - times[0], drift)
    (va, ta), (vc, tc) = truth.a_axis, truth.c_axis
    x = va - vc * (va @ vc)
    x /= np.linalg.norm(x)
    carried = truth.rotation @ rodrigues(va, np.asarray(a, float))
    housing = carried @ np.column_stack([x, np.cross(vc, x), vc])
    rotation = chain_rotation(truth, a, turned)
    if c_tilt_motion is not None:
        tilt = np.einsum('nij,nj->ni', housing[:, :, :2], c_tilt_motion(c))
        pivot = carried @ (tc - ta + tilt_height * vc) + truth.rotation @ ta + truth.affine[:, 3]
        position = position + np.cross(tilt, position - pivot)
        rotation = Rotation.from_rotvec(tilt).as_matrix() @ rotation
    if c_error_motion is not None:
        position = position + np.einsum('nij,nj->ni', housing, c_error_motion(c))
    wobble = Rotation.from_rotvec(rng.normal(0, rotation_noise, (len(a), 3))).as_matrix()
    return TargetPoses(np.asarray(a, float), np.asarray(c, float), wobble @ rotation,
                       position + rng.normal(0, position_noise, position.shape),
                       {'time': np.asarray(times, float)})


def positioner_schedule(step_seconds: float = 36.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The real positioner data set's sampling (test/data/measured/ric_two_axis_positioner):
    A from -30 to +30 deg in 5 deg steps, at each a full turn of C in 22.5 deg steps, one
    pose every ``step_seconds``; returns a, c (rad) and time (s)."""
    a, c = np.meshgrid(np.deg2rad(np.arange(-30, 31, 5)), np.deg2rad(np.arange(0, 360, 22.5)),
                       indexing='ij')
    return a.ravel(), c.ravel(), step_seconds * np.arange(a.size)


def needle_hardware(truth: DispenserModel, tip: np.ndarray, noise_px: float,
                    rng: np.random.Generator) -> tuple:
    """move, dispense and capture callables, as :func:`procedure.measure_needle` takes them,
    of the simulated machine whose needle tip is ``tip`` (camera frame, m): a dispensed dot
    lands where the tip touches the table, and the camera sees the dots dispensed so far
    (numbered in order) with ``noise_px`` of noise."""
    state = {'pose': np.zeros(5), 'dots': []}

    def move(pose):
        state['pose'] = np.asarray(pose, float)
        return state['pose']

    def dispense():
        state['dots'].append(reached(truth, tip, state['pose'][None])[0])

    def capture():
        dots = np.array(state['dots'])
        pixels = project_rows(truth, dots, np.repeat(state['pose'][None], len(dots), 0))
        return np.arange(len(dots)), pixels + rng.normal(0, noise_px, pixels.shape)
    return move, dispense, capture


# The simulated needle's true tip: 0.3, -0.2, 0.1 mm from the configured NEEDLE_TIP (m,
# camera frame).
TRUE_TIP_OFFSET = np.array([0.3e-3, -0.2e-3, 0.1e-3])

# Where the simulated part lies on the table: 1.5 mm, -1 mm off its CAD place and turned
# 0.03 rad about Z (x, y, z m, rotation vector rad).
PART_POSE = np.array([1.5e-3, -1e-3, 0.0, 0.0, 0.0, 0.03])


def placed_part(cad: np.ndarray, part_pose: np.ndarray = PART_POSE) -> np.ndarray:
    """The CAD points (k, 3) (part frame, m) where the part lies (board frame, m)."""
    rotation = rotation_vector_matrix(np.asarray(part_pose[3:], float))
    return np.atleast_2d(cad) @ rotation.T + np.asarray(part_pose[:3], float)


def points_in_view(truth: DispenserModel, points: np.ndarray, pose: np.ndarray,
                   noise_px: float, rng: np.random.Generator,
                   image_size=IMAGE_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """The ``points`` (n, 3) (board frame, m) the camera sees at ``pose`` (5,): their row
    numbers (m,) and pixels (m, 2) with ``noise_px`` of noise, those off the ``image_size``
    (w, h) px image left out."""
    points = np.atleast_2d(points)
    pixels = project_rows(truth, points, np.repeat(np.asarray(pose, float)[None], len(points), 0))
    pixels = pixels + rng.normal(0.0, noise_px, pixels.shape)
    inside = (np.all(np.isfinite(pixels), axis=1) & np.all(pixels >= 0, axis=1)
              & (pixels[:, 0] <= image_size[0] - 1) & (pixels[:, 1] <= image_size[1] - 1))
    numbers = np.flatnonzero(inside)
    return numbers, pixels[numbers]
