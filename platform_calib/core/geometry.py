"""The platform's geometry: three prismatic-revolute-revolute chains (SEEDS_CDE.md section
004, rebuilt). Chain i: a feed slides from A_i along the direction alpha_i by rho_i to
B_i; a link of length L_i joins B_i to the platform's joint C_i. SI units: m, rad.

Frames: the base frame is the one the laser tracker measures in; the platform frame's
origin is the platform centre C (the circumcentre of C_1..C_3, also the screen's centre)
and a pose P = (x, y, theta) puts a platform point p at ``(x, y) + R(theta) p``.

The 18 parameters, 6 per chain: ``x_A``, ``y_A`` (the feed's zero, base frame), ``alpha``
(its direction), ``L`` (the link), ``x_C``, ``y_C`` (the joint, platform frame). The
identified values live in the tracker's base frame and the platform frame the tracker's
targets define, not in the drawing's.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import yaml

from calib_core.errors import InvalidInputError
from calib_core.files import read_yaml
from calib_core.storage import write_atomic

CHAIN_PARAMETERS = ('x_A', 'y_A', 'alpha', 'L', 'x_C', 'y_C')
UNITS = {'x_A': 'm', 'y_A': 'm', 'alpha': 'rad', 'L': 'm', 'x_C': 'm', 'y_C': 'm'}


def parameter_names() -> list[str]:
    """The 18 names, chain by chain: x_A1, y_A1, alpha1, L1, x_C1, y_C1, x_A2, ..."""
    return [f'{name}{i + 1}' for i in range(3) for name in CHAIN_PARAMETERS]


@dataclass(frozen=True)
class PlatformGeometry:
    """The 18 parameters, the assembly (branch) and the feed strokes.

    Attributes
    ----------
    base : (3, 2)
        A_i, the feeds' zeros (m, base frame).
    alpha : (3,)
        Feed directions (rad, from the base x axis).
    length : (3,)
        Link lengths L_i (m).
    joints : (3, 2)
        C_i in the platform frame (m).
    branch : (3,)
        +1 or -1: which root of each chain's inverse kinematics the machine is assembled
        on (-1: the link points ahead of the slide, along the feed).
    stroke : (2,)
        Feed limits (m), the same for every chain.
    """

    base: np.ndarray
    alpha: np.ndarray
    length: np.ndarray
    joints: np.ndarray
    branch: np.ndarray
    stroke: tuple = (0.0, 0.040)

    def __post_init__(self):
        for name, shape in (('base', (3, 2)), ('alpha', (3,)), ('length', (3,)),
                            ('joints', (3, 2)), ('branch', (3,))):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise InvalidInputError(f'platform geometry: {name} must be {shape} finite '
                                        f'values, not {getattr(self, name)!r}')
            object.__setattr__(self, name, value)
        if not np.all(self.length > 0) or not set(np.unique(self.branch)) <= {-1.0, 1.0}:
            raise InvalidInputError('platform geometry: link lengths must be positive and '
                                    'branches +1 or -1')
        low, high = self.stroke
        if not (np.isfinite(low) and np.isfinite(high) and high > low):
            raise InvalidInputError(f'platform geometry: stroke must be (low, high) m, not '
                                    f'{self.stroke!r}')

    def vector(self) -> np.ndarray:
        """The 18 parameters in :func:`parameter_names` order."""
        return np.column_stack([self.base, self.alpha, self.length, self.joints]).ravel()

    def with_vector(self, vector: np.ndarray) -> 'PlatformGeometry':
        v = np.asarray(vector, dtype=float).reshape(3, 6)
        return replace(self, base=v[:, 0:2], alpha=v[:, 2], length=v[:, 3], joints=v[:, 4:6])

    def as_dict(self) -> dict:
        return dict(zip(parameter_names(), map(float, self.vector())))


def nominal_geometry(side: float = 0.200, link: float = 0.060,
                     mid_stroke: float = 0.020) -> PlatformGeometry:
    """SEEDS_CDE.md's proposed platform: the joints an isosceles right triangle with legs
    ``side`` (right angle at C_1, C the midpoint of the hypotenuse C_2 C_3); two feeds
    along x (chains 1 and 2) and one along y (chain 3), links of ``link`` along their
    feeds, each feed at ``mid_stroke`` with the platform at P = 0. Feeds 0-40 mm."""
    h = side / 2
    joints = np.array([[h, -h], [h, h], [-h, -h]])
    alpha = np.array([0.0, 0.0, np.pi / 2])
    direction = np.column_stack([np.cos(alpha), np.sin(alpha)])
    base = joints - (mid_stroke + link) * direction
    return PlatformGeometry(base, alpha, np.full(3, link), joints, -np.ones(3))


def geometry_mapping(geometry: PlatformGeometry) -> dict:
    """``geometry`` as :func:`geometry_from_mapping` reads it: the 18 named parameters (SI),
    the branches and the stroke (m)."""
    return {'parameters': geometry.as_dict(), 'branch': [int(b) for b in geometry.branch],
            'stroke_m': [float(v) for v in geometry.stroke]}


def write_geometry(path, geometry: PlatformGeometry, extra: dict | None = None) -> None:
    """A YAML file any tool can read: the 18 named parameters (SI), their units, the
    branches, the stroke, and ``extra`` (e.g. standard deviations, the report)."""
    mapping = geometry_mapping(geometry)
    content = {'parameters': mapping.pop('parameters'),
               'units': {n: UNITS[n.rstrip('123')] for n in parameter_names()},
               **mapping, **(extra or {})}
    write_atomic(path, yaml.safe_dump(content, sort_keys=False))


def read_geometry(path) -> PlatformGeometry:
    """The geometry of :func:`write_geometry`'s file.

    Raises
    ------
    InvalidInputError
        Unreadable, not YAML, or a parameter missing or not a number."""
    return geometry_from_mapping(read_yaml(path, 'a platform geometry'), str(path))


def geometry_from_mapping(content, where: str) -> PlatformGeometry:
    """The geometry in a mapping laid out as :func:`write_geometry`'s file (``parameters``,
    ``branch``, ``stroke_m``): the file's own, or a machine description's section."""
    try:
        values = [float(content['parameters'][n]) for n in parameter_names()]
        branch = np.asarray(content.get('branch', [-1, -1, -1]), dtype=float)
        stroke = tuple(float(v) for v in content.get('stroke_m', (0.0, 0.040)))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InvalidInputError(f'{where}: a platform geometry needs parameters '
                                f'{", ".join(parameter_names())} as numbers ({exc!r})') from None
    nominal = nominal_geometry()
    return PlatformGeometry(nominal.base, nominal.alpha, nominal.length, nominal.joints,
                            branch, stroke).with_vector(np.array(values))


def calibrated_frames(content: dict) -> list:
    """The frames a platform calibration file's ``content`` fixes, for ``/tf_static``:
    ``base`` -> ``feed<i>`` (the feed's zero A_i, x along its direction alpha_i) and
    ``platform`` -> ``joint<i>`` (C_i), i = 1..3; m, rad."""
    from calib_core.frames import planar
    values = content['parameters']
    return ([('base', f'feed{i}', *planar(values[f'x_A{i}'], values[f'y_A{i}'],
                                          values[f'alpha{i}'])) for i in (1, 2, 3)]
            + [('platform', f'joint{i}', *planar(values[f'x_C{i}'], values[f'y_C{i}'], 0.0))
               for i in (1, 2, 3)])
