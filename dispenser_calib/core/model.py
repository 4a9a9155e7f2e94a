"""The XYZAC chain of the dual-turntable dispenser with its camera on Z (SEEDS_CDE.md
section 003, rebuilt): a board point p_W (the board's frame at a = c = 0) is seen by the
camera at

    p_V = R_M T_A(a) T_C(c) p_W + M [x y z 1]^T,
    T_C(c) p = R(v_c, c) (p - t_c) + t_c,   T_A(a) p = R(v_a, a) (p - t_a) + t_a,

C applied first because A carries C. R_M (constant: the linear axes only translate) and
the 3 x 4 M hold the camera's mounting, the linear axes' directions and scales
(squareness included) and the board's place at reset; v_a, t_a and v_c, t_c are the
rotary axes' lines (direction and a point) in the board-at-reset frame. Pixels follow
OpenCV's pinhole with k1, k2, p1, p2 on normalised coordinates.

Rotation signs (tested): a and c turn the table by the right-hand rule about +v_a (nominal
+X) and +v_c (nominal +Z): a positive c carries a table point on +x towards +y, a positive
a one on +y towards +z. (ISO 841 names such table rotations with primed letters, A' and
C', whose positive sense is opposite to the unprimed tool-relative A and C; the data here
are the table's own angles.)

Gauge: a point's position along a rotary axis is not observable (turning about the axis
leaves it where it is): t_a and t_c are held perpendicular to their axes, ``t . v = 0``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import yaml

from calib_core.errors import InvalidInputError
from calib_core.files import read_yaml
from calib_core.storage import write_atomic

INTRINSIC_NAMES = ('fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'p1', 'p2')
GEOMETRY_NAMES = (('rm_x', 'rm_y', 'rm_z')
                  + tuple(f'M{r}{c}' for r in range(3) for c in range(4))
                  + ('a_tilt_1', 'a_tilt_2', 'a_offset_1', 'a_offset_2',
                     'c_tilt_1', 'c_tilt_2', 'c_offset_1', 'c_offset_2'))
NAMES = INTRINSIC_NAMES + GEOMETRY_NAMES
def parameter_unit(name: str) -> str:
    """The unit of a parameter: px for the focal lengths and principal point, 1 for the
    distortion, rad for tilts, m for the rest."""
    if name in ('fx', 'fy', 'cx', 'cy'):
        return 'px'
    if name in ('k1', 'k2', 'p1', 'p2'):
        return '1'
    return 'rad' if name.startswith(('rm_', 'a_tilt', 'c_tilt')) else 'm'


A_NOMINAL, C_NOMINAL = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
# The camera looking straight down: its x along the board's x, its y along -y, z down.
LOOKING_DOWN = np.diag([1.0, -1.0, -1.0])


def rodrigues(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations by ``angle`` (n,) rad about the unit ``axis`` (3,)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = np.atleast_1d(angle)[:, None, None]
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def rotation_vector_matrix(vector: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a rotation vector (rad)."""
    angle = np.linalg.norm(vector)
    if angle < 1e-15:
        return np.eye(3)
    return rodrigues(vector / angle, np.array([angle]))[0]


def _basis(nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``nominal``: the directions of its tilts and of
    the offsets of its line."""
    first = np.array([0.0, 1.0, 0.0]) if abs(nominal[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    first = first - nominal * (first @ nominal)
    first /= np.linalg.norm(first)
    return first, np.cross(nominal, first)


@dataclass(frozen=True)
class DispenserModel:
    """Intrinsics (px; distortion unitless) and the 23 geometric parameters (m, rad).

    The rotary axes are parametrised about their nominal directions: ``a_tilt_1, 2`` tilt
    v_a towards the two perpendicular directions (rad, small), ``a_offset_1, 2`` place its
    line along them (m); the same for C. For A (nominal +X) the perpendiculars are +Y and
    +Z, for C (nominal +Z) +Y and -X."""

    values: np.ndarray        # (len(NAMES),) in NAMES order

    def __post_init__(self):
        values = np.asarray(self.values, dtype=float)
        if values.shape != (len(NAMES),) or not np.all(np.isfinite(values)):
            raise InvalidInputError(f'a dispenser model needs {len(NAMES)} finite values')
        object.__setattr__(self, 'values', values)

    def __getitem__(self, name: str) -> float:
        return float(self.values[NAMES.index(name)])

    def with_values(self, **changes) -> 'DispenserModel':
        values = self.values.copy()
        for name, value in changes.items():
            values[NAMES.index(name)] = value
        return replace(self, values=values)

    @property
    def camera_matrix(self) -> np.ndarray:
        return np.array([[self['fx'], 0, self['cx']], [0, self['fy'], self['cy']], [0, 0, 1.0]])

    @property
    def distortion(self) -> np.ndarray:
        return np.array([self['k1'], self['k2'], self['p1'], self['p2']])

    @property
    def rotation(self) -> np.ndarray:
        """R_M: the camera's tilt (rotation vector ``rm_x, rm_y, rm_z``, rad, in the camera
        frame) from looking straight down."""
        tilt = rotation_vector_matrix(np.array([self['rm_x'], self['rm_y'], self['rm_z']]))
        return tilt @ LOOKING_DOWN

    @property
    def affine(self) -> np.ndarray:
        """M (3, 4)."""
        start = NAMES.index('M00')
        return self.values[start:start + 12].reshape(3, 4)

    def _axis(self, prefix: str, nominal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        first, second = _basis(nominal)
        direction = nominal + self[f'{prefix}_tilt_1'] * first + self[f'{prefix}_tilt_2'] * second
        direction /= np.linalg.norm(direction)
        point = self[f'{prefix}_offset_1'] * first + self[f'{prefix}_offset_2'] * second
        # The gauge: the point is held perpendicular to the (tilted) axis.
        return direction, point - direction * (point @ direction)

    @property
    def a_axis(self) -> tuple[np.ndarray, np.ndarray]:
        """(v_a, t_a) in the board-at-reset frame."""
        return self._axis('a', A_NOMINAL)

    @property
    def c_axis(self) -> tuple[np.ndarray, np.ndarray]:
        return self._axis('c', C_NOMINAL)


def _table_rows(model: DispenserModel, points: np.ndarray, a: np.ndarray,
                c: np.ndarray) -> np.ndarray:
    """Points (k, 3), each carried by the table at its own angles a, c (k,) rad: (k, 3) in
    the board-at-reset frame (C first: A carries C)."""
    (va, ta), (vc, tc) = model.a_axis, model.c_axis
    turned = np.einsum('kij,kj->ki', rodrigues(vc, c), points - tc) + tc
    return np.einsum('kij,kj->ki', rodrigues(va, a), turned - ta) + ta


def _camera_rows(model: DispenserModel, points: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Points (k, 3), each at its own pose (k, 5), in the camera frame: (k, 3)."""
    turned = _table_rows(model, points, poses[:, 3], poses[:, 4])
    q = np.column_stack([poses[:, :3], np.ones(len(poses))])
    return turned @ model.rotation.T + q @ model.affine.T


def _every_pose(points: np.ndarray, poses: np.ndarray):
    """Every point at every pose as rows: points (n k, 3), poses (n k, 5)."""
    points, poses = np.atleast_2d(points), np.atleast_2d(poses)
    return np.tile(points, (len(poses), 1)), np.repeat(poses, len(points), axis=0)


def table_points(model: DispenserModel, points: np.ndarray, a: np.ndarray,
                 c: np.ndarray) -> np.ndarray:
    """Board points (k, 3) carried by the table at angles a, c (n,) rad: (n, k, 3) in the
    board-at-reset frame."""
    a, c = np.atleast_1d(a), np.atleast_1d(c)
    rows, angles = _every_pose(points, np.column_stack([a, c]))
    return _table_rows(model, rows, angles[:, 0], angles[:, 1]).reshape(len(a), -1, 3)


def camera_points(model: DispenserModel, points: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Board points (k, 3) in the camera frame for poses (n, 5) = x, y, z (m), a, c (rad):
    (n, k, 3)."""
    poses = np.atleast_2d(poses)
    return _camera_rows(model, *_every_pose(points, poses)).reshape(len(poses), -1, 3)


def distort(model: DispenserModel, normalised: np.ndarray) -> np.ndarray:
    """Pixels of normalised image coordinates (..., 2) (OpenCV's k1, k2, p1, p2)."""
    x, y = normalised[..., 0], normalised[..., 1]
    k1, k2, p1, p2 = model.distortion
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([model['fx'] * xd + model['cx'], model['fy'] * yd + model['cy']], -1)


def chain_rotation(model: DispenserModel, a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """R_M R_A(a) R_C(c), (n, 3, 3): the board-at-reset frame's orientation in the camera
    frame with the table at a, c (n,) rad."""
    (va, _), (vc, _) = model.a_axis, model.c_axis
    return model.rotation @ rodrigues(va, a) @ rodrigues(vc, c)


def dot_centres(points: np.ndarray, axes: np.ndarray, radius: float) -> np.ndarray:
    """Homogeneous normalised image coordinates (k, 3) of the centres of the images of
    circles of ``radius`` (m) about ``points`` (k, 3, camera frame) in the planes spanned by
    ``axes`` (k, 3, 2): p p_z - r^2 (a1 a1_z + a2 a2_z) (see :func:`project_rows`)."""
    return points * points[:, 2:3] - radius ** 2 * np.einsum('kij,kj->ki', axes, axes[:, 2, :])


def project_rows(model: DispenserModel, points: np.ndarray, poses: np.ndarray,
                 dot_radius: float = 0.0) -> np.ndarray:
    """Pixels (k, 2) of board points (k, 3), each seen at its own pose (k, 5): every dot of
    every image in one call; points behind the camera are NaN.

    With ``dot_radius`` (m), each point is the centre of a circle of that radius on the
    board, and its pixel is the centre of the circle's image, which a dot detector finds:
    under perspective the image of a circle is an ellipse whose centre is not the image
    of the circle's centre. The ellipse's centre is the pole of the line at infinity,
    H diag(1, 1, -1/r^2) H^T e3 with H = [a1 a2 p] (the board's axes and the dot in the
    camera frame), i.e. p p_z - r^2 (a1 a1_z + a2 a2_z) in homogeneous normalised
    coordinates (Heikkila 2000). Lens distortion then moves that centre (the distortion's
    own bias across the dot, second order in its size, is not modelled)."""
    p = _camera_rows(model, points, poses)
    depth = p[:, 2]
    if dot_radius:
        p = dot_centres(p, chain_rotation(model, poses[:, 3], poses[:, 4])[:, :, :2], dot_radius)
    with np.errstate(divide='ignore', invalid='ignore'):
        normalised = p[:, :2] / np.where(depth > 0, p[:, 2], np.nan)[:, None]
    return distort(model, normalised)


def project(model: DispenserModel, points: np.ndarray, poses: np.ndarray,
            dot_radius: float = 0.0) -> np.ndarray:
    """Pixels (n, k, 2) of board points (k, 3) at poses (n, 5) (dot centres as
    :func:`project_rows`); points behind the camera are NaN."""
    poses = np.atleast_2d(poses)
    return project_rows(model, *_every_pose(points, poses), dot_radius).reshape(len(poses), -1, 2)


def nominal_model(focal_px: float = 7246.0, size=(2448, 2048),
                  working_distance: float = 0.120, a_height: float = -0.030) -> DispenserModel:
    """SEEDS_CDE.md's proposed machine without errors: the camera looking straight down
    (its x along the machine's X, y along -Y, z down), at ``working_distance`` above the
    board's centre with the axes at zero; A along X through a line ``a_height`` below the
    board surface, C along Z through the board's centre. X and Z move the camera, Y the
    table, so M's columns are -R_M e_X, +R_M e_Y, -R_M e_Z and the board's place."""
    values = dict.fromkeys(NAMES, 0.0)
    values.update(fx=focal_px, fy=focal_px, cx=(size[0] - 1) / 2, cy=(size[1] - 1) / 2)
    rotation = LOOKING_DOWN
    columns = np.column_stack([-rotation[:, 0], rotation[:, 1], -rotation[:, 2],
                               np.array([0.0, 0.0, working_distance])])
    for r in range(3):
        for c in range(4):
            values[f'M{r}{c}'] = columns[r, c]
    values['a_offset_2'] = a_height                 # A's line: y = 0, z = a_height
    return DispenserModel(np.array([values[n] for n in NAMES]))


def place(model: DispenserModel, point: np.ndarray, a: float, c: float,
          at_camera: np.ndarray) -> np.ndarray:
    """The pose (5,) that brings board ``point`` (3,) m, with the table at ``a``, ``c``
    rad, to ``at_camera`` (3,) m in the camera frame (the optical axis at the working
    distance to look at it; the needle's tip to dispense on it): the inverse kinematics
    of the linear axes, exact for the model."""
    turned = table_points(model, np.asarray(point, float)[None], np.array([a]), np.array([c]))[0, 0]
    m = model.affine
    xyz = np.linalg.solve(m[:, :3], np.asarray(at_camera, float) - model.rotation @ turned - m[:, 3])
    return np.array([*xyz, a, c])


def write_model(path, model: DispenserModel, extra: dict | None = None) -> None:
    """YAML: the named parameters (px, 1, m, rad) and ``extra`` (std devs, the report)."""
    content = {'parameters': dict(zip(NAMES, map(float, model.values))), **(extra or {})}
    write_atomic(path, yaml.safe_dump(content, sort_keys=False))


def read_covariance(path) -> np.ndarray | None:
    """The parameters' covariance (31, 31; in :data:`NAMES`' order, SI units) a
    calibration file of :func:`write_model` or of the five-axis calibrator holds, None for
    a file without one (written before it was kept).

    Raises
    ------
    InvalidInputError
        A covariance that is not 31 x 31 finite numbers."""
    return covariance_from(read_yaml(path, 'a five-axis calibration'), str(path))


def covariance_from(content, where: str) -> np.ndarray | None:
    """:func:`read_covariance` of a calibration file's content (read from ``where``)."""
    if not isinstance(content, dict) or 'covariance' not in content:
        return None
    try:
        covariance = np.array(content['covariance'], dtype=float)
    except (TypeError, ValueError):
        covariance = None
    if covariance is None or covariance.shape != (len(NAMES),) * 2 \
            or not np.all(np.isfinite(covariance)):
        raise InvalidInputError(f'{where}: covariance must be {len(NAMES)} x {len(NAMES)} '
                                'finite numbers')
    return covariance


def read_model(path) -> DispenserModel:
    """The model of :func:`write_model`'s file.

    Raises
    ------
    InvalidInputError
        Unreadable, not YAML, a parameter missing or not a number."""
    return model_from(read_yaml(path, 'a five-axis calibration'), str(path))


def model_from(content, where: str) -> DispenserModel:
    """:func:`read_model` of a calibration file's content (read from ``where``)."""
    try:
        return DispenserModel(np.array([float(content['parameters'][n]) for n in NAMES]))
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInputError(f'{where}: a five-axis calibration needs the parameters '
                                f'{", ".join(NAMES)} as numbers ({exc!r})') from None


def nominal_frames(pose, working_distance: float = 0.120,
                   a_height: float = -0.030) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """The machine's frames at a commanded ``pose`` (5,) (x, y, z m, a, c rad) through the
    nominal kinematics (:func:`nominal_model`'s, not a calibration), for a viewer: (parent,
    child, translation (3,) m, quaternion (x, y, z, w)). ``machine`` is the board-at-reset
    frame (Z up); X and Z carry the ``camera`` (looking down), Y the table; ``a_cradle``
    turns by A about X through the line ``a_height`` below the board, ``table`` by C about
    Z through the board's centre."""
    x, y, z, a, c = (float(v) for v in np.asarray(pose, dtype=float))
    return [
        ('machine', 'camera', np.array([x, 0.0, working_distance + z]),
         np.array([1.0, 0.0, 0.0, 0.0])),                           # half a turn about X
        ('machine', 'y_carriage', np.array([0.0, y, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])),
        ('y_carriage', 'a_cradle', np.array([0.0, 0.0, a_height]),
         np.array([np.sin(a / 2), 0.0, 0.0, np.cos(a / 2)])),
        ('a_cradle', 'table', np.array([0.0, 0.0, -a_height]),
         np.array([0.0, 0.0, np.sin(c / 2), np.cos(c / 2)])),
    ]


def calibrated_frames(content: dict) -> list:
    """The frames a five-axis calibration file's ``content`` fixes, for ``/tf_static``:
    ``machine`` -> ``a_axis`` (origin on the calibrated A axis line, x along it) and
    ``machine`` -> ``c_axis`` (origin on the C axis line, z along it); m. The camera's
    position is not a parameter of this model (only its tilt and the affine map), so it
    gets no frame."""
    from calib_core.frames import turning
    model = DispenserModel(np.array([content['parameters'][n] for n in NAMES]))
    (a_direction, a_point), (c_direction, c_point) = model.a_axis, model.c_axis
    return [('machine', 'a_axis', a_point, turning(A_NOMINAL, a_direction)),
            ('machine', 'c_axis', c_point, turning(C_NOMINAL, c_direction))]
