"""A simulated grid plate with its own mark errors on a stage with a measuring-system
error, measured at the three placements (SEEDS_CDE.md section 002, proposed defaults).
Truth is for tests and benches only."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from grid_calib.core.model import (
    PLACEMENTS, Grid, linear_parts, mark_error_seen, misalignment, region_origins, site_of,
    stage_error)
from grid_calib.core.selfcal import Placement


class SmoothField:
    """A smooth vector field (low-order Fourier terms, m) over a square of half-width
    ``extent`` (m), evaluable anywhere, with its mean and first moments removed over the
    reference points it was made with and scaled to ``amplitude`` m RMS there."""

    def __init__(self, reference: np.ndarray, extent: float, amplitude: float,
                 rng: np.random.Generator):
        self.extent = extent
        self.coefficients = [(kx, ky, rng.normal(size=(2, 2)))
                             for kx in range(1, 3) for ky in range(1, 3)]
        self.linear = np.zeros((3, 2))
        self.gain = 1.0
        raw = self(reference)
        basis = self._basis(reference)
        self.linear = np.linalg.lstsq(basis, raw, rcond=None)[0]
        self.gain = amplitude / np.sqrt(np.mean((raw - basis @ self.linear) ** 2))

    def _basis(self, points: np.ndarray) -> np.ndarray:
        return np.column_stack([np.ones(len(points)), points / self.extent])

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """The field at ``points`` (k, 2) m, (k, 2) m."""
        u = np.asarray(points, dtype=float) / self.extent
        field = np.zeros((len(u), 2))
        for kx, ky, c in self.coefficients:
            field += (c[:, 0] * np.sin(np.pi * kx * u[:, :1] + ky * u[:, 1:])
                      + c[:, 1] * np.cos(np.pi * ky * u[:, 1:] - kx * u[:, :1]))
        return (field - self._basis(points) @ self.linear) * self.gain


def zero_moment_field(sites: np.ndarray, grid: Grid, amplitude: float,
                      rng: np.random.Generator) -> np.ndarray:
    """A smooth residual field F (s, 2) at ``sites`` (indices) with zero mean and first
    moments over them, ``amplitude`` m RMS."""
    positions = sites * grid.pitch
    return SmoothField(positions, (grid.half + 1) * grid.pitch, amplitude, rng)(positions)


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


def measure_placements(grid: Grid, truth: GridTruth, noise: float = 0.0, seed: int = 0,
                       expansion: float = 0.0, warm_up: float = 0.0,
                       origin=(0.0, 0.0)) -> list[Placement]:
    """The three placements measured: stage reading minus nominal site position for every
    mark, with Gaussian ``noise`` (m, per coordinate). Each reading takes 3 s and each
    re-placement 120 s; the machine warms at ``warm_up`` K/s from 20 C and its scale
    expands by ``expansion`` (1/K) about ``origin`` (m, the travel's zero), which the
    self-calibration's model lacks. Time (s) and temperature (K) are logged per reading."""
    rng = np.random.default_rng(seed + 1000)
    marks = grid.marks
    site_row = {tuple(s): k for k, s in enumerate(grid.sites)}
    out, clock = [], 0.0
    for name in PLACEMENTS:
        sites = site_of(marks, name)
        positions = sites * grid.pitch
        field = truth.residual_field[[site_row[tuple(s)] for s in sites]]
        g = stage_error(positions, truth.non_orthogonality, truth.scale_difference, field)
        time = clock + 3.0 * np.arange(len(marks))
        clock = time[-1] + 120.0
        warming = warm_up * time
        deviation = (g + mark_error_seen(truth.mark_errors, name)
                     + misalignment(positions, *truth.misalignments[name])
                     + expansion * warming[:, None] * (positions + np.asarray(origin))
                     + rng.normal(0.0, noise, positions.shape))
        out.append(Placement(name, marks.copy(), deviation,
                             {'time': time, 'temperature': 293.15 + warming}))
    return out


@dataclass(frozen=True)
class TravelTruth:
    """A stage travel covered region by region with one plate: the stage error over the
    whole travel, the plate's mark errors, each region's centre (site indices in the travel
    frame) and each region's placement misalignments."""

    non_orthogonality: float
    scale_difference: float
    field: SmoothField
    mark_errors: np.ndarray                 # (N^2, 2) m, the same plate in every region
    origins: dict                           # region -> (m0, n0)
    misalignments: dict                     # region -> placement -> (shift_x, shift_y, angle)
    isotropic_scale: float = 0.0            # of the stage, 1 (the plate cannot see it)

    def error_at(self, positions: np.ndarray) -> np.ndarray:
        """The stage error G (k, 2) m at travel positions (k, 2) m."""
        positions = np.asarray(positions, dtype=float)
        return (stage_error(positions, self.non_orthogonality, self.scale_difference,
                            np.zeros_like(positions)) + self.field(positions)
                + self.isotropic_scale * positions)

    def mean_pitch(self, grid: Grid) -> float:
        """The plate's mean pitch (m), least squares over its marks: what a certificate
        states."""
        return grid.pitch * (1 + linear_parts(grid.marks * grid.pitch, self.mark_errors)['scale'])

    def region(self, grid: Grid, region: int) -> GridTruth:
        """One region as a single-region truth in the region's own frame (its F then holds
        the rest of the travel's error there, not zero-moment)."""
        local = grid.sites * grid.pitch
        g = self.error_at(local + np.asarray(self.origins[region]) * grid.pitch)
        linear = stage_error(local, self.non_orthogonality, self.scale_difference,
                             np.zeros_like(local))
        return GridTruth(self.non_orthogonality, self.scale_difference, g - linear,
                         self.mark_errors, self.misalignments[region])


def default_travel(grid: Grid, columns: int = 3, rows: int = 3, seed: int = 0,
                   plate_error: float = 1e-6, stage_residual: float = 0.3e-6,
                   isotropic_scale: float = 0.0, plate_scale: float = 0.0) -> TravelTruth:
    """O 20 urad, R 10 ppm and a smooth residual of ``stage_residual`` m RMS over the whole
    travel, the stage's ``isotropic_scale``; the plate as in ``default_truth`` with its
    mean pitch off by ``plate_scale`` (a certified pitch is ``pitch (1 + plate_scale)``);
    placements off by up to 50 um and 100 urad."""
    rng = np.random.default_rng(seed)
    origins = region_origins(grid, columns, rows)
    sites = np.unique(np.vstack([grid.sites + o for o in origins.values()]), axis=0)
    extent = (np.abs(sites).max() + 1) * grid.pitch
    smooth = zero_moment_field(grid.marks, grid, 1.0, rng)
    mark_errors = ((smooth + rng.normal(size=smooth.shape)) * plate_error / np.sqrt(2)
                   + plate_scale * grid.marks * grid.pitch)
    mis = {r: {name: (rng.uniform(-50e-6, 50e-6), rng.uniform(-50e-6, 50e-6),
                      rng.uniform(-100e-6, 100e-6)) for name in PLACEMENTS} for r in origins}
    field = SmoothField(sites * grid.pitch, extent, stage_residual, rng)
    return TravelTruth(20e-6, 10e-6, field, mark_errors, origins, mis, isotropic_scale)


def measure_travel(grid: Grid, truth: TravelTruth, noise: float = 0.0, seed: int = 0,
                   expansion: float = 0.0, warm_up: float = 0.0) -> dict:
    """Every region's three placements (region -> list of Placement), deviations from the
    region's own nominal sites; ``expansion`` and ``warm_up`` as in
    :func:`measure_placements` (each region's clock starts at 0)."""
    return {r: measure_placements(grid, truth.region(grid, r), noise, seed + 7919 * r,
                                  expansion, warm_up, np.asarray(o) * grid.pitch)
            for r, o in truth.origins.items()}
