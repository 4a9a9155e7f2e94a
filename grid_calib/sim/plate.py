"""A simulated grid plate with its own mark errors on a stage with a measuring-system
error, measured at the three placements (SEEDS_CDE.md section 002, proposed defaults).
Truth is for tests and benches only."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from grid_calib.core.model import (
    PLACEMENTS, Grid, mark_error_seen, misalignment, site_of, stage_error)
from grid_calib.core.selfcal import Placement


def zero_moment_field(sites: np.ndarray, grid: Grid, amplitude: float,
                      rng: np.random.Generator) -> np.ndarray:
    """A smooth residual field F (s, 2) at ``sites`` (low-order Fourier terms over the
    region, ``amplitude`` m RMS) with its mean and first moments removed over the sites."""
    u = sites * grid.pitch / ((grid.half + 1) * grid.pitch)
    field = np.zeros((len(sites), 2))
    for kx in range(1, 3):
        for ky in range(1, 3):
            coefficients = rng.normal(size=(2, 2))
            field += (coefficients[:, 0] * np.sin(np.pi * kx * u[:, :1] + ky * u[:, 1:])
                      + coefficients[:, 1] * np.cos(np.pi * ky * u[:, 1:] - kx * u[:, :1]))
    basis = np.column_stack([np.ones(len(sites)), u])
    field -= basis @ np.linalg.lstsq(basis, field, rcond=None)[0]
    return field * amplitude / np.sqrt(np.mean(field ** 2))


@dataclass(frozen=True)
class GridTruth:
    """The plate's and the stage's true errors (m, rad) and each placement's misalignment."""

    non_orthogonality: float
    scale_difference: float
    residual_field: np.ndarray         # F at grid.sites, (s, 2)
    mark_errors: np.ndarray            # A at grid.marks, (N^2, 2)
    misalignments: dict                # placement -> (shift_x, shift_y, angle)

    def stage_error(self, grid: Grid) -> np.ndarray:
        return stage_error(grid.sites * grid.pitch, self.non_orthogonality,
                           self.scale_difference, self.residual_field)


def default_truth(grid: Grid, seed: int = 0, plate_error: float = 1e-6,
                  stage_residual: float = 0.15e-6) -> GridTruth:
    """O 20 urad, R 10 ppm, a smooth F of ``stage_residual`` m RMS, plate marks off by
    ``plate_error`` m RMS (random plus a smooth part: worse than the stage), placements off
    by up to 50 um and 100 urad."""
    rng = np.random.default_rng(seed)
    marks = grid.marks
    smooth = zero_moment_field(marks, grid, 1.0, rng)
    mark_errors = (smooth + rng.normal(size=smooth.shape)) * plate_error / np.sqrt(2)
    mis = {name: (rng.uniform(-50e-6, 50e-6), rng.uniform(-50e-6, 50e-6),
                  rng.uniform(-100e-6, 100e-6)) for name in PLACEMENTS}
    return GridTruth(20e-6, 10e-6, zero_moment_field(grid.sites, grid, stage_residual, rng),
                     mark_errors, mis)


def measure_placements(grid: Grid, truth: GridTruth, noise: float = 0.0,
                       seed: int = 0) -> list[Placement]:
    """The three placements measured: stage reading minus nominal site position for every
    mark, with Gaussian ``noise`` (m, per coordinate)."""
    rng = np.random.default_rng(seed + 1000)
    marks = grid.marks
    site_row = {tuple(s): k for k, s in enumerate(grid.sites)}
    out = []
    for name in PLACEMENTS:
        sites = site_of(marks, name)
        positions = sites * grid.pitch
        field = truth.residual_field[[site_row[tuple(s)] for s in sites]]
        g = stage_error(positions, truth.non_orthogonality, truth.scale_difference, field)
        deviation = (g + mark_error_seen(truth.mark_errors, name)
                     + misalignment(positions, *truth.misalignments[name])
                     + rng.normal(0.0, noise, positions.shape))
        out.append(Placement(name, marks.copy(), deviation))
    return out
