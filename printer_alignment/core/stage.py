"""XY-Theta alignment stage (3-PRP planar parallel stage): kinematics and error model.

Frames (m, rad): ``stage`` is the base frame of the stage: chain 1's guide runs along +x at
y = d1, the guides of chains 2 and 3 run along +y at x = d2 and x = d3. ``platform`` moves
with the table; its pose in the stage frame is ``(x, y, theta)``: the platform origin is
where the slots of chains 1 and 2 cross, and its x axis runs along chain 2's slot.
``stage2plate`` places the stage frame in the plate frame in which the camera measures.

The paper's ideal kinematics (inputs q in m, nominal lead 2 mm/rev)::

    q1 = x + (y - d1) tan(theta)
    q2 = y + (d2 - x) tan(theta)
    q3 = y + (d3 - x) tan(theta)

The error model keeps that structure and adds every error source the paper names, plus
backlash per chain. Chain i's slider moves along its guide by

    s_i = (R_i / R_nominal) q_i + dq_i - b_i / 2 * dir_i

(lead ratio, input offset, lost motion against the last direction of motion dir_i). Guide
i starts at (0, d1) / (d2, 0) / (d3, 0) with its direction turned by beta_i. On the
platform, chain 1's slot runs at angle alpha1 from chain 2's (nominal 90 deg: the angle
between the stage's X and Y motions, the paper's axis skew), chain 3's slot at alpha2 from
chain 2's (nominal 0, parallel) and offset from it by the link-length difference l3 - l2.
Each chain's revolute joint sits on its slot, so each input is linear in its slider
displacement and the inverse kinematics is closed form; the forward kinematics is the
paper's closed form for the ideal stage and Newton iterations on the error model.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from calib_core.errors import InvalidInputError, OutOfTravelError
from calib_core.parameters import Parameter, ParameterSet

NOMINAL_LEAD = 2e-3                     # m/rev, R1..R3
NOMINAL_D = (0.268, 0.0395, 0.4315)     # m, d1, d2, d3
LINK_LENGTH = 0.028                     # m, l1 = l2 = l3
STROKE = 5e-3                           # m, inputs limited to [-STROKE, STROKE]
APPROACH = 30e-6                        # m, length of the last, landing motion of a chain
LANDING_SIGMA = 1.2e-6                  # m, a chain's landing repeatability (1 sigma), docs/stage.md
CAMERA_NOISE = 0.3e-6                   # m, a Mark's measured plate coordinate (1 sigma)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _rot(angle: np.ndarray) -> np.ndarray:
    """Rotation matrices, shape angle.shape + (2, 2)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _as_poses(pose) -> np.ndarray:
    pose = np.atleast_2d(np.asarray(pose, dtype=float))
    if pose.shape[-1] != 3:
        raise InvalidInputError(f'poses must have shape (n, 3) (x m, y m, theta rad), not {pose.shape}')
    if not np.all(np.isfinite(pose)):
        raise InvalidInputError('pose contains NaN or infinite values')
    return pose


def landing_path(q_now, q_target, directions, approach: float = APPROACH,
                 stroke: float = STROKE) -> np.ndarray:
    """Two waypoints (m, (2, 3)) that land every chain on ``q_target`` with a last motion
    of ``approach`` (m) in its direction of travel; a chain that does not travel keeps its
    last direction (``directions``, +1 / -1, (3,)).

    Every chain lands again at every stop, so its landing scatter is drawn afresh each
    time (independent between stops, as the closed loop's tests assume; a chain that
    stood still would carry one landing error over many stops), and the direction of
    approach, hence backlash, is what the plan says. The pre-position is clipped to the
    ``stroke`` (m).
    """
    q_target = np.asarray(q_target, dtype=float)
    travel = landing_directions(q_now, q_target, directions)
    before = np.clip(q_target - approach * travel, -stroke, stroke)
    return np.array([before, q_target])


def landing_directions(q_now, q_target, directions) -> np.ndarray:
    """Each chain's direction (3,) as it lands on ``q_target`` from ``q_now`` (m): +1 rising,
    -1 falling, its last direction (``directions``) if it does not travel."""
    step = np.asarray(q_target, dtype=float) - np.asarray(q_now, dtype=float)
    return np.where(step != 0, np.sign(step), np.asarray(directions, dtype=float))


def path_from_below(q_target, approach: float = APPROACH, stroke: float = STROKE) -> np.ndarray:
    """Two waypoints (m, (2, 3)) that land every chain on ``q_target`` moving upwards: the
    unidirectional approach of alignment and of ISO 9283 repeatability. The pre-position is
    clipped to the ``stroke`` (m)."""
    q_target = np.asarray(q_target, dtype=float)
    return np.array([np.maximum(q_target - approach, -stroke), q_target])


def check_stroke(q, stroke: float = STROKE) -> np.ndarray:
    """``q`` (m, (n, 3)) as an array, or :class:`OutOfTravelError` naming the chain."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.shape[-1] != 3 or not np.all(np.isfinite(q)):
        raise InvalidInputError(f'chain inputs must be finite with shape (n, 3), got {q.shape}')
    outside = np.abs(q) > stroke * (1 + 1e-12)
    if outside.any():
        row, chain = np.argwhere(outside)[0]
        raise OutOfTravelError(
            f'chain {chain + 1} input {q[row, chain] * 1e3:.4f} mm is outside the stroke '
            f'[{-stroke * 1e3:.1f}, {stroke * 1e3:.1f}] mm; not moved')
    return q


def ideal_inverse(pose, d=NOMINAL_D) -> np.ndarray:
    """Paper's inverse kinematics: inputs q (m, (n, 3)) for stage-frame poses (n, 3)."""
    x, y, t = _as_poses(pose).T
    d1, d2, d3 = d
    tan = np.tan(t)
    return np.stack([x + (y - d1) * tan, y + (d2 - x) * tan, y + (d3 - x) * tan], axis=1)


def ideal_forward(q, d=NOMINAL_D) -> np.ndarray:
    """Paper's closed-form forward kinematics: poses (n, 3) for inputs q (m, (n, 3))."""
    q1, q2, q3 = np.atleast_2d(np.asarray(q, dtype=float)).T
    d1, d2, d3 = d
    tan = (q3 - q2) / (d3 - d2)
    x = (q1 + d1 * tan - tan * (q2 - d2 * tan)) / (1 + tan ** 2)
    y = (q2 - d2 * tan + tan * (q1 + d1 * tan)) / (1 + tan ** 2)
    return np.stack([x, y, np.arctan(tan)], axis=1)


@dataclass(frozen=True)
class StageGeometry:
    """Geometry of one stage (true, nominal or identified). Lengths in m, angles in rad.

    Attributes
    ----------
    lead : (3,)
        Transmission ratios R1..R3, m/rev (nominal 2 mm/rev).
    input_offset : (3,)
        dq1..dq3, slider displacement at zero input, m.
    d : (3,)
        d1 (y of chain 1's guide), d2, d3 (x of chains 2 and 3's guides), m.
    link_difference : float
        l3 - l2: offset of chain 3's slot from chain 2's on the platform, m.
    beta : (3,)
        Guide direction errors, rad.
    alpha1 : float
        Angle of chain 1's slot from chain 2's, rad (nominal pi/2).
    alpha2 : float
        Angle of chain 3's slot from chain 2's, rad (nominal 0).
    backlash : (3,)
        Lost motion per chain, m.
    stage2plate : (3,)
        x, y (m) and angle (rad) of the stage frame in the plate frame.
    """

    lead: tuple = (NOMINAL_LEAD,) * 3
    input_offset: tuple = (0.0, 0.0, 0.0)
    d: tuple = NOMINAL_D
    link_difference: float = 0.0
    beta: tuple = (0.0, 0.0, 0.0)
    alpha1: float = np.pi / 2
    alpha2: float = 0.0
    backlash: tuple = (0.0, 0.0, 0.0)
    stage2plate: tuple = (0.0, 0.0, 0.0)

    # --- parameter-set mapping -------------------------------------------------------
    def as_parameters(self) -> ParameterSet:
        """Named parameters (SI units), all free; the optimiser's view of the geometry."""
        out = []
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, tuple):
                names = _VECTOR_NAMES[f.name]
                out += [Parameter(n, float(v), _UNITS[n]) for n, v in zip(names, value)]
            else:
                out.append(Parameter(f.name, float(value), _UNITS[f.name]))
        return ParameterSet(out)

    @classmethod
    def from_parameters(cls, parameters) -> 'StageGeometry':
        """Inverse of :meth:`as_parameters`; accepts a ParameterSet or a dict."""
        values = parameters.as_dict() if isinstance(parameters, ParameterSet) else dict(parameters)
        kwargs = {}
        for f in fields(cls):
            if f.name in _VECTOR_NAMES:
                kwargs[f.name] = tuple(float(values[n]) for n in _VECTOR_NAMES[f.name])
            else:
                kwargs[f.name] = float(values[f.name])
        return cls(**kwargs)

    def as_dict(self) -> dict:
        return self.as_parameters().as_dict()

    def with_changes(self, **changes) -> 'StageGeometry':
        return replace(self, **changes)

    # --- chain geometry --------------------------------------------------------------
    def _guides(self):
        d1, d2, d3 = self.d
        b = np.asarray(self.beta)
        origins = np.array([[0.0, d1], [d2, 0.0], [d3, 0.0]])
        directions = np.array([[np.cos(b[0]), np.sin(b[0])],
                               [-np.sin(b[1]), np.cos(b[1])],
                               [-np.sin(b[2]), np.cos(b[2])]])
        return origins, directions

    def _slots(self):
        points = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, self.link_difference]])
        directions = np.array([[np.cos(self.alpha1), np.sin(self.alpha1)], [1.0, 0.0],
                               [np.cos(self.alpha2), np.sin(self.alpha2)]])
        return points, directions

    def slider_displacements(self, pose) -> np.ndarray:
        """Slider displacement s (m, (n, 3)) along each guide for stage-frame poses."""
        return self._displacements_and_jacobian(pose)[0]

    def _displacements_and_jacobian(self, pose):
        pose = _as_poses(pose)
        origins, guides = self._guides()
        points, slots = self._slots()
        rot = _rot(pose[:, 2])[:, None]                    # (n, 1, 2, 2)
        w = (rot @ slots[None, :, :, None])[..., 0]        # slot directions, (n, 3, 2)
        c = (rot @ points[None, :, :, None])[..., 0]       # slot points, (n, 3, 2)
        q = pose[:, None, :2] + c                          # (n, 3, 2)
        rel = q - origins[None]
        num = _cross(w, rel)
        den = _cross(w, guides[None])
        if np.any(np.abs(den) < 1e-3):
            raise InvalidInputError('singular pose: a slot is parallel to its guide')
        s = num / den
        # Derivatives: d(rot v)/dtheta = perp(rot v) with perp(a) = (-a_y, a_x).
        perp = lambda a: np.stack([-a[..., 1], a[..., 0]], -1)  # noqa: E731
        dnum_dt = _cross(perp(w), rel) + _cross(w, perp(c))
        dden_dt = _cross(perp(w), guides[None])
        jac = np.empty(pose.shape[:1] + (3, 3))
        jac[..., 0] = -w[..., 1] / den
        jac[..., 1] = w[..., 0] / den
        jac[..., 2] = (dnum_dt * den - num * dden_dt) / den ** 2
        return s, jac

    def _ratios(self) -> np.ndarray:
        return np.asarray(self.lead) / NOMINAL_LEAD

    def inverse(self, pose, directions=None) -> np.ndarray:
        """Commanded inputs q (m, (n, 3)) that put the platform at stage-frame ``pose``
        ((n, 3)) when each chain's last motion was in ``directions`` ((n, 3) of +1/-1;
        None: backlash ignored, i.e. the middle of the lost motion)."""
        s = self.slider_displacements(pose)
        lost = 0.0 if directions is None else 0.5 * np.asarray(self.backlash) * directions
        return (s - np.asarray(self.input_offset) + lost) / self._ratios()

    def jacobian(self, pose) -> np.ndarray:
        """dq/dpose (m per (m, m, rad)), shape (n, 3, 3): rows chains, columns x, y, theta."""
        return self._displacements_and_jacobian(pose)[1] / self._ratios()[None, :, None]

    def forward(self, q, directions=None, iterations: int = 8) -> np.ndarray:
        """Stage-frame poses (n, 3) for inputs q (m, (n, 3)); Newton on :meth:`inverse`
        started from the paper's closed form."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if not np.all(np.isfinite(q)):
            raise InvalidInputError('chain inputs contain NaN or infinite values')
        lost = 0.0 if directions is None else 0.5 * np.asarray(self.backlash) * directions
        s_target = q * self._ratios() + np.asarray(self.input_offset) - lost
        pose = ideal_forward(s_target, self.d)
        for _ in range(iterations):
            s, jac = self._displacements_and_jacobian(pose)
            step = np.linalg.solve(jac, (s_target - s)[..., None])[..., 0]
            pose = pose + step
            if np.max(np.abs(step)) < 1e-15:
                break
        return pose

    # --- frames ----------------------------------------------------------------------
    def stage_to_plate(self, pose) -> np.ndarray:
        """Stage-frame platform poses (n, 3) as plate-frame poses (n, 3)."""
        pose = _as_poses(pose)
        x0, y0, a0 = self.stage2plate
        xy = pose[:, :2] @ _rot(a0).T + np.array([x0, y0])
        return np.column_stack([xy, pose[:, 2] + a0])

    def plate_to_stage(self, pose) -> np.ndarray:
        """Inverse of :meth:`stage_to_plate`."""
        pose = _as_poses(pose)
        x0, y0, a0 = self.stage2plate
        xy = (pose[:, :2] - np.array([x0, y0])) @ _rot(a0)
        return np.column_stack([xy, pose[:, 2] - a0])


# The stage as drawn: where the drawing mounts it in the plate frame (m, m, rad). The
# calibrator and the aligner start from it on a real machine as in simulation.
NOMINAL_STAGE2PLATE = (-0.140, -0.055, 0.0)
NOMINAL_STAGE = StageGeometry(stage2plate=NOMINAL_STAGE2PLATE)


def platform_points_in_plate(plate_pose, points) -> np.ndarray:
    """Plate positions (m, (n, k, 2)) of platform-frame ``points`` ((k, 2)) for plate-frame
    platform poses ((n, 3))."""
    plate_pose = _as_poses(plate_pose)
    points = np.asarray(points, dtype=float)
    return (_rot(plate_pose[:, 2])[:, None] @ points[None, :, :, None])[..., 0] \
        + plate_pose[:, None, :2]


_VECTOR_NAMES = {
    'lead': ('lead1', 'lead2', 'lead3'),
    'input_offset': ('q_offset1', 'q_offset2', 'q_offset3'),
    'd': ('d1', 'd2', 'd3'),
    'beta': ('beta1', 'beta2', 'beta3'),
    'backlash': ('backlash1', 'backlash2', 'backlash3'),
    'stage2plate': ('stage_x', 'stage_y', 'stage_angle'),
}
_UNITS = {'link_difference': 'm', 'alpha1': 'rad', 'alpha2': 'rad', 'stage_angle': 'rad',
          **{n: 'm/rev' for n in _VECTOR_NAMES['lead']},
          **{n: 'rad' for n in _VECTOR_NAMES['beta']},
          **{n: 'm' for group in ('input_offset', 'd', 'backlash')
             for n in _VECTOR_NAMES[group]},
          'stage_x': 'm', 'stage_y': 'm'}
