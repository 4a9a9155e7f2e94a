"""What lies under the gantry camera: a dot calibration plate, substrate or stencil Marks."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class PlateMark:
    """A Mark on a plate, in the plate frame: centre (m), radius or half-length (m), bar
    width (m, crosses only)."""

    kind: str
    x: float
    y: float
    size: float
    width: float = 0.0


@dataclass(frozen=True)
class DotPlate:
    """A calibration plate with a square grid of dots: dot (i, j) at (i, j) * pitch (m),
    plus ``error`` (a function of the nominal positions (k, 2) m giving (k, 2) m) for a
    plate that is not perfect."""

    pitch: float = 0.5e-3
    radius: float = 0.1e-3
    extent: tuple[float, float, float, float] = (-0.01, 0.22, -0.01, 0.17)  # x0, x1, y0, y1 (m)
    error: Callable[[np.ndarray], np.ndarray] | None = None

    def marks_within(self, x0: float, x1: float, y0: float, y1: float) -> list[PlateMark]:
        """Dots whose centres lie in the rectangle (m), found by arithmetic, not search."""
        ex0, ex1, ey0, ey1 = self.extent
        i0 = int(np.ceil(max(x0, ex0) / self.pitch))
        i1 = int(np.floor(min(x1, ex1) / self.pitch))
        j0 = int(np.ceil(max(y0, ey0) / self.pitch))
        j1 = int(np.floor(min(y1, ey1) / self.pitch))
        nominal = np.array([(i * self.pitch, j * self.pitch) for j in range(j0, j1 + 1)
                            for i in range(i0, i1 + 1)]).reshape(-1, 2)
        where = nominal if self.error is None else nominal + self.error(nominal)
        return [PlateMark('circle', x, y, self.radius) for x, y in where]


class PlacedPlate:
    """A plate of dots at ``marks`` (k, 2) m in its own frame (true positions, its errors
    included), put down on the machine by :meth:`place`; nothing is seen before that."""

    def __init__(self, marks: np.ndarray, radius: float):
        self.marks = np.asarray(marks, dtype=float)
        self.radius = radius
        self.where = np.empty((0, 2))
        self.pose = (0.0, 0.0, 0.0)

    def place(self, x: float, y: float, angle: float) -> None:
        """Put the plate's origin at (x, y) m, turned by ``angle`` rad counter-clockwise."""
        self.pose = (float(x), float(y), float(angle))
        c, s = np.cos(angle), np.sin(angle)
        self.where = self.marks @ np.array([[c, s], [-s, c]]) + np.array([x, y])

    def marks_within(self, x0: float, x1: float, y0: float, y1: float) -> list[PlateMark]:
        w = self.where
        inside = (w[:, 0] >= x0) & (w[:, 0] <= x1) & (w[:, 1] >= y0) & (w[:, 1] <= y1)
        return [PlateMark('circle', x, y, self.radius) for x, y in w[inside]]


@dataclass(frozen=True)
class MarkSet:
    """A few fiducial Marks, e.g. on a substrate (circles) or a stencil (crosses)."""

    marks: tuple[PlateMark, ...]

    def marks_within(self, x0: float, x1: float, y0: float, y1: float) -> list[PlateMark]:
        return [m for m in self.marks if x0 <= m.x <= x1 and y0 <= m.y <= y1]


class StageScene:
    """The printer with its XY-Theta stage: the calibration Marks and the substrate's
    fiducials (circles) move with the platform; the stencil's fiducials (crosses) stay.
    A two-way camera sees either the ``substrate`` side (down) or the ``stencil`` (up).

    ``platform_marks``: (k, 2) platform-frame positions (m); ``stencil``: (k, 2) plate
    positions (m)."""

    def __init__(self, platform_marks, stencil, radius: float = 0.5e-3,
                 cross: tuple = (0.6e-3, 0.2e-3)):
        self.platform_marks = np.asarray(platform_marks, dtype=float)
        self.stencil = MarkSet(tuple(PlateMark('cross', float(x), float(y), *cross)
                                     for x, y in np.asarray(stencil, dtype=float)))
        self.radius = radius
        self.pose = np.zeros(3)     # platform pose in the plate frame (m, m, rad)
        self.view = 'substrate'

    def marks_within(self, x0: float, x1: float, y0: float, y1: float) -> list[PlateMark]:
        if self.view == 'stencil':
            return self.stencil.marks_within(x0, x1, y0, y1)
        c, s = np.cos(self.pose[2]), np.sin(self.pose[2])
        plate = self.platform_marks @ np.array([[c, s], [-s, c]]) + self.pose[:2]
        return MarkSet(tuple(PlateMark('circle', float(x), float(y), self.radius)
                             for x, y in plate)).marks_within(x0, x1, y0, y1)
