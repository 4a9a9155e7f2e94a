"""The dispenser's calibration run: the stepwise plan (linear stops, A alone, C alone), the
strokes every stop is checked against before anything moves, and the run itself with the
hardware passed in as callables (the node, the tests and the offline replay run the same
code). The calibration is evaluated on held-out images at poses where A and C both turn,
which the stepwise plan never visits."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

from calib_core.errors import InvalidInputError
from dispenser_calib.core.calibration import calibrate, check_calibration, reprojection
from dispenser_calib.core.data import SHIPPED_BOARD, Board, Image
from dispenser_calib.core.localisation import fit_part_pose, locate, place_path, tool_centre
from dispenser_calib.core.model import DispenserModel, place
from dispenser_calib.errors import StrokeError

WORKING_DISTANCE = 0.120        # m, the camera to the board's centre
# A part for the localisation: its features (m, part frame), a 12-point circle to
# dispense (m), the needle tip in the camera frame (m) and the views of each feature.
PART_CAD = np.array([[0.02, 0.01, 0.005], [-0.03, 0.02, 0.008], [0.04, -0.03, 0.003],
                     [-0.02, -0.025, 0.006]])
PART_PATH = np.array([[0.01 * np.cos(t), 0.01 * np.sin(t), 0.006]
                      for t in np.linspace(0, 2 * np.pi, 12, endpoint=False)])
NEEDLE_TIP = np.array([0.03, 0.0, 0.125])
FEATURE_VIEWS = ((0.0, 0.0), (0.35, 0.0), (-0.35, 1.57), (0.26, 3.5))
# Where the needle's test dots go (m, board frame).
TEST_SPOTS = np.array([[-0.005, 0.0, 0.0], [0.005, 0.003, 0.0], [0.0, -0.004, 0.0]])
STROKES = {'x': (-0.200, 0.200), 'y': (-0.150, 0.150), 'z': (-0.050, 0.050),
           'a': (-np.pi / 2, np.pi / 2), 'c': (-2 * np.pi, 2 * np.pi)}




@dataclass(frozen=True)
class Workspace:
    """Where a dispenser works: each axis's stroke (name -> (low, high), m or rad), the
    camera's working distance (m, to the board's centre with the axes at zero) and the dot
    ``board`` on its table that the camera calibrates on; the shipped simulated machine's
    by default, a machine description's for a user's."""

    strokes: dict = field(default_factory=lambda: dict(STROKES))
    working_distance: float = WORKING_DISTANCE
    board: Board = SHIPPED_BOARD

    def check(self, pose: np.ndarray) -> None:
        """:func:`check_stroke` against these strokes."""
        check_stroke(pose, self.strokes)

    def inside(self, pose: np.ndarray) -> bool:
        return all(low <= v <= high for v, (low, high) in zip(pose, self.strokes.values()))


SHIPPED_WORKSPACE = Workspace()


def check_stroke(pose: np.ndarray, strokes: dict = STROKES) -> None:
    """Refuse a pose (5,) outside an axis's stroke (m, rad).

    Raises
    ------
    StrokeError"""
    for value, (name, (low, high)) in zip(pose, strokes.items()):
        if not low <= value <= high:
            raise StrokeError(f'{name} = {value:.6g} is outside the stroke {low:.6g}..{high:.6g}; '
                              'nothing moved')


def plan_stops(nominal: DispenserModel, seed: int = 0,
               workspace: Workspace = SHIPPED_WORKSPACE) -> np.ndarray:
    """The stepwise plan (n, 5): 12 linear stops (a = c = 0, not coplanar), A alone at
    -60, -30, 30, 60 degrees, C alone every 30 degrees; each aimed (nominal model) so the
    board's centre is on the optical axis at the ``workspace``'s working distance, then
    moved a little."""
    rng = np.random.default_rng(seed + 50)
    centre = np.array([0.0, 0.0, workspace.working_distance])
    stops = []
    for _ in range(12):
        pose = place(nominal, np.zeros(3), 0.0, 0.0, centre)
        stops.append(pose + np.r_[rng.uniform(-3e-3, 3e-3, 2), rng.uniform(-4e-3, 4e-3), 0, 0])
    for a in np.deg2rad([-60, -30, 30, 60]):
        stops.append(place(nominal, np.zeros(3), a, 0.0, centre))
    for c in np.deg2rad(np.arange(30, 360, 30)):
        stops.append(place(nominal, np.zeros(3), 0.0, c, centre))
    return np.array(stops)


def rotary_sweep(tilts=np.linspace(-0.3, 0.3, 5), step: float = np.deg2rad(22.5),
                 both_ways: bool = False) -> np.ndarray:
    """Stops (n, 5) with the linear axes held at zero: A at each of ``tilts`` (rad), C round
    the turn in ``step`` (rad), and with ``both_ways`` back again (every place approached
    from both sides: lost motion shows); the board stays in view (A's line lies 30 mm below
    it), so the camera measures the board's pose at each (:func:`target_poses.poses_from_images`)."""
    turn = np.arange(0, 2 * np.pi - 1e-9, step)
    turn = np.r_[turn, turn[::-1]] if both_ways else turn
    a, c = np.meshgrid(np.asarray(tilts, float), turn, indexing='ij')
    return np.column_stack([np.zeros((a.size, 3)), a.ravel(), c.ravel()])


def measure_sweep(stops: np.ndarray, move: Callable[[np.ndarray], np.ndarray],
                  capture: Callable[[], tuple],
                  record: Callable[[Image, str], None] = lambda *a: None,
                  progress: Callable[[int, int, str], None] = lambda *a: None,
                  workspace: Workspace = SHIPPED_WORKSPACE) -> list:
    """Image the board at each of ``stops`` (n, 5) (:func:`rotary_sweep`), every stop
    checked against the ``workspace``'s strokes before anything moves; ``record`` gets
    each image as it is taken (its time and the machine's temperature are the
    recorder's). Returns the images.

    Raises
    ------
    StrokeError
        A stop outside a stroke (before anything moves)."""
    for pose in stops:
        workspace.check(pose)
    images = []
    for pose in stops:
        reached = np.asarray(move(pose), dtype=float)
        indices, pixels = capture()
        images.append(Image(f'sweep{len(images):03d}', reached, np.asarray(indices, int),
                            np.asarray(pixels, float), workspace.board))
        record(images[-1], 'sweep')
        progress(len(images), len(stops), f'sweep image {len(images)}: {len(indices)} dots')
    return images


def evaluation_stops(nominal: DispenserModel, count: int, seed: int = 0,
                     workspace: Workspace = SHIPPED_WORKSPACE) -> np.ndarray:
    """``count`` held-out stops (count, 5) with A and C both turned (a within +-45
    degrees), aimed at the ``workspace``'s working distance; none for 0."""
    rng = np.random.default_rng(seed + 70)
    centre = np.array([0.0, 0.0, workspace.working_distance])
    return np.array([place(nominal, np.zeros(3), rng.uniform(-0.8, 0.8), rng.uniform(0, 2 * np.pi),
                           centre) for _ in range(count)]).reshape(count, 5)


def run_five_axis_calibration(nominal: DispenserModel, image_size, seed: int, evaluation: int,
                              move: Callable[[np.ndarray], np.ndarray],
                              capture: Callable[[], tuple],
                              record: Callable[[Image, str], None] = lambda *a: None,
                              progress: Callable[[int, int, str], None] = lambda *a: None,
                              stops: np.ndarray | None = None,
                              adapt: Callable[[list], np.ndarray] | None = None,
                              description=None):
    """Plan, check every stop, drive, image, calibrate (RANSAC), evaluate on the held-out
    stops. ``move(pose)`` returns the pose the encoders report; ``capture()`` the dots'
    (indices (k, 2), pixels (k, 2)); ``stops`` (n, 5) a planned set
    (:func:`dispenser_calib.core.planning.plan_five_axis`) instead of the stepwise plan;
    ``adapt(images)`` (:class:`dispenser_calib.core.planning.AdaptivePlan`), after the
    stops are imaged and after each addition, the further stops to image (none: enough);
    ``description`` (:class:`dispenser_calib.core.description.FiveAxisDescription`) the
    machine's strokes, working distance and board (the one ``capture`` names the dots
    of), and the gate (:func:`finish`).
    Returns (the refinement, its report with the held-out evaluation, the images).

    Raises
    ------
    StrokeError
        A planned stop outside a stroke (before anything moves)."""
    workspace = SHIPPED_WORKSPACE if description is None else description.workspace()
    stops = (plan_stops(nominal, seed, workspace) if stops is None
             else np.asarray(stops, dtype=float))
    held_out = evaluation_stops(nominal, evaluation, seed, workspace)
    for pose in np.vstack([stops, held_out]):
        workspace.check(pose)
    images, evaluation_images = [], []

    def image(phase, pose, out):
        reached = np.asarray(move(pose), dtype=float)
        indices, pixels = capture()
        out.append(Image(f'{phase}{len(out):03d}', reached, np.asarray(indices, int),
                         np.asarray(pixels, float), workspace.board))
        record(out[-1], phase)
        # An adaptive run adds stops: the count grows past the first plan's total.
        total = max(len(stops), len(images)) + len(held_out) + 1
        progress(len(images) + len(evaluation_images), total,
                 f'{phase} image {len(out)}: {len(indices)} dots')

    for pose in stops:
        image('calibrate', pose, images)
    more = adapt(images) if adapt else ()
    while len(more):
        for pose in more:
            workspace.check(pose)
        for pose in more:
            image('calibrate', pose, images)
        more = adapt(images)
    for pose in held_out:
        image('evaluate', pose, evaluation_images)
    return finish(nominal, image_size, images, evaluation_images, description)


def finish(nominal: DispenserModel, image_size, images: list, evaluation_images: list,
           description=None):
    """Calibrate on ``images`` and evaluate on the held-out ``evaluation_images``: the
    reprojection RMS with the calibrated and with the nominal model (px), over the held-out
    images that are not bad themselves (RANSAC's rule: over 5 x the median image's RMS and
    0.5 px; those are named). The gate is ``description``'s
    (:meth:`dispenser_calib.core.description.FiveAxisDescription.check`) where one is given,
    and the covariance then holds its axes' stopping noise."""
    _, result = calibrate(images, image_size, pose_sigma=None if description is None
                          else description.pose_sigma())
    report = result.report(images)
    if description is None:
        check_calibration(result.model, report)
    else:
        description.check(result.model, report, images)
    if evaluation_images:
        per_image = [np.sqrt(np.mean(e ** 2)) for e in reprojection(result.model, evaluation_images)]
        limit = max(0.5, 5 * float(np.median(per_image)))
        good = [im for im, e in zip(evaluation_images, per_image) if e < limit]

        def rms(model):
            return float(np.sqrt(np.mean(np.concatenate(reprojection(model, good)) ** 2)))
        report['held_out'] = {'images': len(good), 'rms_px_calibrated': rms(result.model),
                              'rms_px_nominal': rms(nominal),
                              'bad_images': [im.name for im, e in zip(evaluation_images, per_image)
                                             if e >= limit]}
    return result, report, images


def view_plan(model: DispenserModel, points: np.ndarray, views,
              workspace: Workspace = SHIPPED_WORKSPACE) -> list:
    """(point number, pose (5,)) per point and view ((a, c) rad): the camera aimed at where
    the point would be, at the ``workspace``'s working distance."""
    centre = np.array([0.0, 0.0, workspace.working_distance])
    return [(k, place(model, point, a, c, centre)) for k, point in enumerate(points)
            for a, c in views]


def _located(model: DispenserModel, points: np.ndarray, plan: list, move, capture,
             what: str) -> tuple[np.ndarray, list]:
    """Drive to each pose of ``plan`` (checked already), image, and locate each point
    (expected near ``points`` (k, 3)) from the views it was seen in: (k, 3) m and the
    reprojection RMS per point (px)."""
    seen = {k: ([], []) for k in range(len(points))}
    for k, pose in plan:
        reached = np.asarray(move(pose), dtype=float)
        numbers, pixels = capture()
        for number, pixel in zip(numbers, np.atleast_2d(pixels)):
            if int(number) == k:
                seen[k][0].append(reached)
                seen[k][1].append(pixel)
    located, rms = [], []
    for k, (poses, pixels) in seen.items():
        if len(poses) < 2:
            raise InvalidInputError(f'{what} {k} was seen in {len(poses)} view(s); it needs 2')
        point, error = locate(model, np.array(poses), np.array(pixels), points[k])
        located.append(point)
        rms.append(error)
    return np.array(located), rms


def locate_workpiece(model: DispenserModel, cad: np.ndarray, path: np.ndarray, tip: np.ndarray,
                     views, path_angles, move: Callable[[np.ndarray], np.ndarray],
                     capture: Callable[[], tuple],
                     workspace: Workspace = SHIPPED_WORKSPACE) -> dict:
    """Image each CAD feature (k, 3) (part frame, m) from ``views`` ((a, c) rad each; the
    camera aimed at where the feature would be with the part at the board's origin),
    triangulate it, fit the part's pose, and place the CAD ``path`` (p, 3) on the located
    part with the table at ``path_angles`` (a, c) and the needle tip ``tip`` (camera
    frame). ``capture()`` returns (feature numbers (n,), pixels (n, 2)). Every pose is
    checked against the ``workspace``'s strokes before the machine goes there.

    Raises
    ------
    StrokeError
        A view or a path pose outside a stroke.
    InvalidInputError
        A feature seen in fewer than 2 views, or too few features for a pose."""
    cad = np.atleast_2d(cad)
    plan = view_plan(model, cad, views, workspace)
    for _, pose in plan:
        workspace.check(pose)
    located, rms = _located(model, cad, plan, move, capture, 'feature')
    rotation, translation, misfit = fit_part_pose(cad, located)
    on_table = np.atleast_2d(path) @ rotation.T + translation
    path_poses = place_path(model, tip, on_table, *path_angles)
    for pose in path_poses:
        workspace.check(pose)
    return {'features_m': located.tolist(), 'reprojection_rms_px': rms,
            'pose': {'translation_m': translation.tolist(),
                     'rotation_vector_rad': cv2.Rodrigues(rotation)[0].ravel().tolist()},
            'cad_misfit_rms_m': misfit, 'path_poses': path_poses.tolist()}


def measure_needle(model: DispenserModel, tip_guess: np.ndarray, spots, views,
                   move: Callable[[np.ndarray], np.ndarray], dispense: Callable[[], None],
                   capture: Callable[[], tuple],
                   workspace: Workspace = SHIPPED_WORKSPACE) -> dict:
    """The needle tip in the camera frame from test dots: the machine dispenses one dot at
    each of ``spots`` (k, 3) (board frame, m; aimed with ``tip_guess``), then the camera
    images each dot from ``views`` ((a, c) rad each) and it is located through the chain;
    the tip is where the chain carried each located dot at the moment it was dispensed
    (:func:`tool_centre`). ``capture()`` returns the dispensed dots in view: (numbers (n,),
    in the order dispensed, pixels (n, 2)). Every pose is checked against the
    ``workspace``'s strokes first.

    Returns the tip (m), each dot's located place (m), the tip each dot alone gives and
    their spread (m), the reprojection RMS per dot (px).

    Raises
    ------
    StrokeError
        A pose outside a stroke (nothing moves).
    InvalidInputError
        A dot seen in fewer than two views."""
    spots = np.atleast_2d(np.asarray(spots, float))
    dispensing = [place(model, spot, 0.0, 0.0, tip_guess) for spot in spots]
    looking = view_plan(model, spots, views, workspace)
    for pose in dispensing + [pose for _, pose in looking]:
        workspace.check(pose)
    dispensed_at = []
    for pose in dispensing:
        dispensed_at.append(np.asarray(move(pose), dtype=float))
        dispense()
    dots, rms = _located(model, spots, looking, move, capture, 'dispensed dot')
    return dict(tip_from_dots(model, np.array(dispensed_at), dots), dots_m=dots.tolist(),
                reprojection_rms_px=rms, dispensed_at=np.array(dispensed_at).tolist())


def tip_from_dots(model: DispenserModel, dispensed_at: np.ndarray, dots: np.ndarray) -> dict:
    """The needle tip (camera frame, m) from test dots located at ``dots`` (k, 3) (board
    frame, m), dispensed with the machine at ``dispensed_at`` (k, 5): ``tip_m``, the tip
    each dot alone gives (``tip_per_dot_m``) and their largest distance from it
    (``spread_m``, m)."""
    each = np.array([tool_centre(model, q[None], d[None]) for q, d in zip(dispensed_at, dots)])
    tip = tool_centre(model, dispensed_at, dots)
    return {'tip_m': tip.tolist(), 'tip_per_dot_m': each.tolist(),
            'spread_m': float(np.max(np.linalg.norm(each - tip, axis=1)))}
