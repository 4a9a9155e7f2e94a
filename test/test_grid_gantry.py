"""The grid self-calibration run on the printer's simulated gantry, camera and Mark
detector (issue 21): the procedure measures every placement of every region through the
image, the readings stitch, and the map improves the gantry's vision calibration made on
an imperfect dot plate, against the simulation's truth; a plan that leaves the travel is
refused before anything moves."""
from dataclasses import replace

import numpy as np
import pytest

from calib_core.errors import OutOfTravelError
from grid_calib.core.compensation import StageErrorMap
from grid_calib.core.procedure import GridPlan
from machine_alignment.bench.grid_gantry import (
    evaluate, grid_self_calibration, vision_calibration)
from printer_alignment.sim.gantry import GantryErrors, GantrySim, Travel

SMALL = GridPlan(half=2, pitch=7.5e-3, columns=2, rows=2, first_centre=(5, 5))
TOLERANCE = {'after_rms_m': 0.5e-6, 'improvement': 5.0}   # measured: 0.19 um, 16x


@pytest.fixture(scope='module')
def run():
    gantry = GantrySim(replace(GantryErrors(), periodic_amplitude_x=0.0,
                               periodic_amplitude_y=0.0))
    calibration = vision_calibration(gantry, seed=4)
    travel = grid_self_calibration(gantry, calibration, 4, SMALL, progress=lambda line: None)
    return gantry, calibration, travel


def test_the_run_measures_and_stitches_every_region(run):
    _, _, travel = run
    assert sorted(travel.results) == [0, 1, 2, 3]
    assert {r: tuple(o) for r, o in travel.origins.items()} == SMALL.origins()
    # Every mark found through the image; residuals at the detector's noise (~0.1 um).
    assert all(0 < r.noise < 0.3e-6 for r in travel.results.values())
    assert travel.stitched.overlap_rms < 0.3e-6
    assert travel.isotropic_scale is not None


def test_the_map_improves_the_vision_calibration_against_truth(run):
    """The vision calibration on a dot plate with 30 ppm scale, 20 urad shear and 1 um of
    smooth error leaves several um; the grid map, from a plate with 1 um mark errors,
    brings it to below 0.5 um RMS (targets approached as calibrated)."""
    gantry, calibration, travel = run
    stage_map = StageErrorMap(travel.stitched.sites, travel.stitched.stage_error, SMALL.pitch)
    result = evaluate(gantry, calibration, stage_map, seed=5, bidirectional=False, count=60)
    before = result['vision calibration']['rms_m']
    after = result['vision + grid self-calibration']['rms_m']
    assert after < TOLERANCE['after_rms_m']
    assert before / after > TOLERANCE['improvement']


def test_a_plan_outside_the_travel_is_refused_before_anything_moves():
    travel = Travel()
    GridPlan().check((travel.x_min, travel.x_max), (travel.y_min, travel.y_max))
    with pytest.raises(OutOfTravelError, match='outside the travel'):
        GridPlan(columns=4).check((travel.x_min, travel.x_max), (travel.y_min, travel.y_max))
    with pytest.raises(OutOfTravelError, match='outside the travel'):
        GridPlan(first_centre=(4, 4)).check((0.0, 0.2), (0.0, 0.15))
    assert np.allclose(GridPlan().stops(0, 'shifted')[1][0], [(5 - 4 + 1) * 7.5e-3,
                                                               (5 - 4) * 7.5e-3])
