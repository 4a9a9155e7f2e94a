"""The named scenes the simulated printer's camera looks at: the dot plate, a substrate,
a stencil, and the stage with its calibration Marks and a substrate on the platform.
Kept apart from the scene types (``scene``) and the stage (``stage``), which it uses."""
from __future__ import annotations

import numpy as np

from printer_alignment.sim.scene import DotPlate, MarkSet, PlacedPlate, PlateMark, StageScene
from printer_alignment.sim.stage import (
    CALIBRATION_MARKS, SUBSTRATE_MARKS, TRUE_STAGE, described_truth)


def stage_scene(substrate_shift=(0.0, 0.0, 0.0), stencil=None, description=None) -> StageScene:
    """The simulated printer's stage scene: calibration Marks and a substrate fixed with
    ``substrate_shift`` (x m, y m, rotation rad) on the platform; the stencil's fiducials at
    ``stencil`` (plate m, (2, 2)), by default where the substrate's would be if fixed
    perfectly with the stage at home. With a stage ``description`` (:class:`~printer_
    alignment.core.stage_description.StageDescription`), the user's stage as the stage
    simulator builds it (:func:`~printer_alignment.sim.stage.described_truth`): its Marks,
    and the substrate held beside them as the shipped one is beside the shipped Marks."""
    truth, marks, designed = TRUE_STAGE, CALIBRATION_MARKS, SUBSTRATE_MARKS
    if description is not None:
        truth, marks = described_truth(description), np.asarray(description.marks)
        designed = SUBSTRATE_MARKS + marks.mean(axis=0) - CALIBRATION_MARKS.mean(axis=0)
    dx, dy, turn = substrate_shift
    c, s = np.cos(turn), np.sin(turn)
    substrate = designed @ np.array([[c, s], [-s, c]]) + [dx, dy]
    if stencil is None:
        home = truth.stage_to_plate(truth.forward(np.zeros((1, 3))))[0]
        c0, s0 = np.cos(home[2]), np.sin(home[2])
        stencil = designed @ np.array([[c0, s0], [-s0, c0]]) + home[:2]
    return StageScene(np.vstack([marks, substrate]), stencil)


def grid_plate(half: int = 4, pitch: float = 7.5e-3, mark_error: float = 1e-6,
               seed: int = 0) -> PlacedPlate:
    """A (2 ``half`` + 1)-square grid plate of ``pitch`` (m) whose dots (0.3 mm radius) are
    off their nominal places by ``mark_error`` m RMS (a cheap plate), not yet placed."""
    k = np.arange(-half, half + 1)
    nominal = np.stack(np.meshgrid(k, k), -1).reshape(-1, 2) * pitch
    errors = np.random.default_rng([seed, 21]).normal(0.0, mark_error / np.sqrt(2), nominal.shape)
    return PlacedPlate(nominal + errors, 0.3e-3)


def make_scene(name: str):
    """The scene called ``name``: ``dot_plate``, ``substrate``, ``stencil``, ``stage`` or
    ``grid_plate`` (placed by the grid calibration's requests)."""
    if name == 'stage':
        return stage_scene()
    if name == 'dot_plate':
        return DotPlate()
    if name == 'substrate':
        return MarkSet((PlateMark('circle', 0.020, 0.020, 0.5e-3),
                        PlateMark('circle', 0.180, 0.130, 0.5e-3)))
    if name == 'stencil':
        return MarkSet((PlateMark('cross', 0.020, 0.020, 0.6e-3, 0.2e-3),
                        PlateMark('cross', 0.180, 0.130, 0.6e-3, 0.2e-3)))
    if name == 'grid_plate':
        return grid_plate()
    raise ValueError(f'unknown scene {name!r}; use dot_plate, substrate, stencil, stage or '
                     'grid_plate')
