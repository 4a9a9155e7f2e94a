"""What lies under the gantry camera: a dot calibration plate, substrate or stencil Marks."""
from __future__ import annotations

from dataclasses import dataclass

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
    """A calibration plate with a square grid of dots: dot (i, j) at (i, j) * pitch (m)."""

    pitch: float = 0.5e-3
    radius: float = 0.1e-3
    extent: tuple[float, float, float, float] = (-0.01, 0.22, -0.01, 0.17)  # x0, x1, y0, y1 (m)

    def marks_within(self, x0: float, x1: float, y0: float, y1: float) -> list[PlateMark]:
        """Dots whose centres lie in the rectangle (m), found by arithmetic, not search."""
        ex0, ex1, ey0, ey1 = self.extent
        i0 = int(np.ceil(max(x0, ex0) / self.pitch))
        i1 = int(np.floor(min(x1, ex1) / self.pitch))
        j0 = int(np.ceil(max(y0, ey0) / self.pitch))
        j1 = int(np.floor(min(y1, ey1) / self.pitch))
        return [PlateMark('circle', i * self.pitch, j * self.pitch, self.radius)
                for j in range(j0, j1 + 1) for i in range(i0, i1 + 1)]


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
