"""Accuracy of a vision calibration against the simulation's truth (evaluation only).

At random gantry targets over the whole travel, approached from random directions (so
backlash is in the data, as on a real machine), the camera measures the dot nearest the
image centre; the measured plate position is compared with the dot's true position.
The calibration's plate frame is anchored at a dot, so the two frames differ by a whole
number of pitches, which is removed."""
from __future__ import annotations

import numpy as np

from calib_core.figures import arrow_key, save_figure
from printer_alignment.core.geometry import NOMINAL_LEADS, CameraToPlate, GantryModel
from calib_core.marks import detect_marks
from printer_alignment.core.vision_calibration import plate_position


def measure_errors(camera2plate: CameraToPlate, gantry_model: GantryModel, gantry, camera,
                   targets: np.ndarray, pitch: float) -> np.ndarray:
    """Measured minus true dot positions (m, (n, 2)) at ``targets`` (m, (n, 2))."""
    measured, truth = [], []
    for x, y in targets:
        revs = gantry.move(x, y) / NOMINAL_LEADS
        position = gantry.true_camera_position()
        marks = detect_marks(camera.capture(position), shape='circle').marks
        uv = np.array([[m.u, m.v] for m in marks])
        nearest = uv[np.argmin(np.linalg.norm(uv - np.asarray(camera2plate.principal), axis=1))]
        measured.append(plate_position(gantry_model, camera2plate, revs, nearest[None])[0])
        # The true dot is the grid point nearest to where the camera truly looks.
        true_offset = camera.optics.camera2plate.offset(nearest[None])[0]
        truth.append(np.round((position + true_offset) / pitch) * pitch)
    errors = np.array(measured) - np.array(truth)
    return errors - np.round(np.median(errors, axis=0) / pitch) * pitch


def summarise(errors: np.ndarray) -> dict:
    norm = np.linalg.norm(errors, axis=1)
    return {'max_um': float(norm.max() * 1e6), 'rms_um': float(np.sqrt(np.mean(norm ** 2)) * 1e6),
            'count': int(len(norm))}




def plot_errors(path, targets, before, after, title: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    # One arrow scale for both panels: the longest error before is drawn 25 mm long.
    longest = max(np.max(np.linalg.norm(before, axis=1)), 1e-12) * 1e6
    per_mm = longest / 25.0                                   # um of error per mm of arrow
    for ax, errors, name in ((axes[0], before, 'before'), (axes[1], after, 'after')):
        arrows = ax.quiver(targets[:, 0] * 1e3, targets[:, 1] * 1e3, errors[:, 0] * 1e6,
                           errors[:, 1] * 1e6, angles='xy', scale_units='xy', scale=per_mm,
                           width=0.004, color='C0' if name == 'before' else 'C2')
        arrow_key(ax, arrows, longest / 4, 'um')
        ax.set_title(f'{name}: longest {np.max(np.linalg.norm(errors, axis=1)) * 1e6:.1f} um '
                     '(one scale, key below)', loc='left', fontsize=10)
        ax.set_xlabel('gantry x (mm)')
        ax.set_ylabel('gantry y (mm)')
        ax.set_aspect('equal')
    bins = np.linspace(0, np.max(np.linalg.norm(before, axis=1)) * 1e6, 30)
    axes[2].hist(np.linalg.norm(before, axis=1) * 1e6, bins=bins, alpha=0.6, label='before')
    axes[2].hist(np.linalg.norm(after, axis=1) * 1e6, bins=bins, alpha=0.6, label='after')
    axes[2].set_xlabel('position error (um)')
    axes[2].set_ylabel('count')
    axes[2].legend()
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path, [__file__])
    plt.close(fig)
