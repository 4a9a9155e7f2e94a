"""Compile the detector's numba code into its on-disk cache (``make setup`` runs this), so
that no process pays the 15-20 s of compiling on its first frame. One frame of dots in
each pixel type the detector meets compiles every specialisation it uses."""
from __future__ import annotations

import numpy as np

from calib_core.marks.detect import detect_marks
from calib_core.marks.pixels import PIXEL_TYPES


def dot_frame(dtype, highlight: bool = False) -> np.ndarray:
    """A 120 x 160 frame of 4 dark dots of 10 px radius with a 1 px edge on a bright
    background lit unevenly (so that the illumination trend is fitted), in ``dtype``
    (half full scale for the integer types); with ``highlight``, a highlight beside the
    first dot, which calls its local fit (local_fit)."""
    v, u = np.mgrid[:120, :160].astype(float)
    frame = np.ones((120, 160))
    for cu, cv in ((45.3, 35.6), (115.1, 34.8), (44.7, 85.2), (114.9, 84.6)):
        frame = np.minimum(frame, np.clip(np.hypot(u - cu, v - cv) - 9.5, 0.0, 1.0))
    frame = (0.2 + 0.6 * frame) * (0.8 + 0.2 * u / 160)
    if highlight:
        frame += 0.15 * np.exp(-((u - 60.0) ** 2 + (v - 40.0) ** 2) / (2 * 10.0 ** 2))
    scale = np.iinfo(dtype).max / 2 if np.issubdtype(dtype, np.integer) else 1.0
    return (frame * scale).astype(dtype)


def main() -> None:
    for dtype in PIXEL_TYPES:
        for highlight in (False, True):
            detect_marks(dot_frame(dtype, highlight), expected_count=4)


if __name__ == '__main__':
    main()
