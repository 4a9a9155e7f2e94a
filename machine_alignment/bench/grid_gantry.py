"""The grid self-calibration on the printer's XY camera gantry (issue 21): the gantry's
vision calibration as it is today, on a dot plate that is not perfect, against the same
calibration followed by the grid self-calibration with an imperfect grid plate (three
placements per region, 3 x 2 regions stitched, the plate's certified mean pitch for the
scale), both measured against the simulation's truth over the whole travel.

Everything runs through the simulated gantry, camera and Mark detector. Writes
bench_results/grid_gantry.{json,md} and grid_gantry.png."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from calib_core.figures import arrow_key  # noqa: E402
from grid_calib.core.compensation import StageErrorMap  # noqa: E402
from grid_calib.core.model import linear_parts, without_similarity  # noqa: E402
from grid_calib.core.procedure import GridPlan, measure_grid  # noqa: E402
from grid_calib.core.travel import calibrate_travel  # noqa: E402
from grid_calib.sim.plate import SmoothField, default_truth  # noqa: E402
from machine_alignment.bench import main_with_out, write_results, write_table  # noqa: E402
from printer_alignment.core.geometry import NOMINAL_LEADS, GantryModel  # noqa: E402
from calib_core.marks import detect_marks  # noqa: E402
from printer_alignment.core.vision_procedure import VisionPlan, run_vision_calibration  # noqa: E402
from printer_alignment.sim.camera import CameraSim  # noqa: E402
from printer_alignment.sim.gantry import GantryErrors, GantrySim  # noqa: E402
from printer_alignment.sim.scene import DotPlate, PlacedPlate  # noqa: E402

PLAN = GridPlan()                      # 9 x 9 marks, 7.5 mm pitch, 3 x 2 regions
GRID_MARK_RADIUS = 0.3e-3              # m
EVALUATION_TARGETS = 200


def dot_plate_error(seed: int):
    """The dot plate's error (m) at nominal positions: 30 ppm too long, 20 urad of shear
    and a smooth field of 1 um RMS over the plate: an ordinary plate, not a certified one."""
    rng = np.random.default_rng(seed + 500)
    reference = np.stack(np.meshgrid(np.linspace(0, 0.2, 21), np.linspace(0, 0.15, 16)),
                         -1).reshape(-1, 2)
    field = SmoothField(reference - [0.1, 0.075], 0.12, 1e-6, rng)
    linear = np.array([[30e-6, 20e-6], [0.0, 30e-6]])

    def error(nominal: np.ndarray) -> np.ndarray:
        return nominal @ linear.T + field(nominal - [0.1, 0.075])
    return error


def _nearest_offset(camera, gantry, camera2plate) -> np.ndarray:
    """The detected Mark nearest the image centre as an offset from it (m, (2,))."""
    marks = detect_marks(camera.capture(gantry.true_camera_position()), shape='circle').marks
    uv = np.array([[m.u, m.v] for m in marks]).reshape(-1, 2)
    if not len(uv):
        raise RuntimeError('no mark in view')
    nearest = uv[np.argmin(np.linalg.norm(uv - np.asarray(camera2plate.principal), axis=1))]
    return camera2plate.offset(nearest[None])[0]


def vision_calibration(gantry: GantrySim, seed: int):
    """Today's vision calibration (pixel size, then the gantry model) on the imperfect dot
    plate."""
    camera = CameraSim(DotPlate(error=dot_plate_error(seed)), seed=seed)
    _, calibration = run_vision_calibration(
        VisionPlan(), lambda x, y: gantry.move(x, y) / NOMINAL_LEADS,
        lambda: np.array([[m.u, m.v] for m in detect_marks(
            camera.capture(gantry.true_camera_position())).marks]))
    return calibration


def grid_self_calibration(gantry: GantrySim, calibration, seed: int, plan: GridPlan = PLAN,
                          progress=print):
    """The grid plate measured through today's calibration at every placement of every
    region, self-calibrated and stitched; the plate's certified mean pitch gives the
    scale."""
    grid = plan.grid
    plate = default_truth(grid, seed)                    # 1 um RMS mark errors
    scene = PlacedPlate(grid.marks * grid.pitch + plate.mark_errors, GRID_MARK_RADIUS)
    camera = CameraSim(scene, seed=seed + 1)
    model, rng = calibration.gantry, np.random.default_rng(seed + 2)
    true_model = gantry.errors.model

    def place(region, placement, centre):
        # The operator puts the plate's centre under the camera as the machine reads it
        # there, turned or shifted as asked, to within tens of um and urad.
        world = true_model.camera_position(model.revs_for(centre))[0]
        shift = np.array([grid.pitch, 0.0]) if placement == 'shifted' else np.zeros(2)
        turn = np.pi / 2 if placement == 'rotated' else 0.0
        x, y = world + shift + rng.uniform(-50e-6, 50e-6, 2)
        scene.place(x, y, turn + rng.uniform(-100e-6, 100e-6))

    def move(x, y):
        revs = model.revs_for([x, y])[0]
        reached = gantry.move(*(revs * NOMINAL_LEADS)) / NOMINAL_LEADS
        return model.camera_position(reached)[0]

    regions = measure_grid(plan, place, move,
                           lambda: _nearest_offset(camera, gantry, calibration.camera2plate),
                           lambda done, total, what: progress(f'    {done}/{total} {what}'))
    mean_pitch = grid.pitch * (1 + linear_parts(grid.marks * grid.pitch,
                                                plate.mark_errors)['scale'])
    return calibrate_travel(grid, regions, 'joint', certified_pitch=mean_pitch)


def evaluate(gantry: GantrySim, calibration, stage_map: StageErrorMap, seed: int,
             bidirectional: bool, count: int = EVALUATION_TARGETS) -> dict:
    """Camera positions as each calibration measures them against the truth at random
    targets over the calibrated area, approached from below (as calibrated) or from random
    directions (backlash in the data). The frames differ by a rigid motion, removed."""
    rng = np.random.default_rng(seed + 3)
    low, high = stage_map.x[[0, -1]], stage_map.y[[0, -1]]
    targets = rng.uniform([low[0] + 2e-3, high[0] + 2e-3], [low[1] - 2e-3, high[1] - 2e-3],
                          (count, 2))
    model = calibration.gantry
    measured, truth = {'nominal model': [], 'vision calibration': [],
                       'vision + grid self-calibration': []}, []
    for target in targets:
        revs = model.revs_for(target)[0]
        sign = rng.choice([-1.0, 1.0], 2) if bidirectional else -np.ones(2)
        gantry.move(*(revs * NOMINAL_LEADS + sign * 1e-3))
        reached = gantry.move(*(revs * NOMINAL_LEADS)) / NOMINAL_LEADS
        truth.append(gantry.true_camera_position())
        reading = model.camera_position(reached)[0]
        measured['nominal model'].append(GantryModel().camera_position(reached)[0])
        measured['vision calibration'].append(reading)
        measured['vision + grid self-calibration'].append(
            stage_map.true_position(reading[None])[0])
    truth = np.array(truth)
    out = {}
    for name, values in measured.items():
        error = without_similarity(truth, np.array(values) - truth, keep_scale=True)
        norm = np.linalg.norm(error, axis=1)
        out[name] = {'max_m': float(norm.max()), 'rms_m': float(np.sqrt(np.mean(norm ** 2))),
                     'errors': error, 'targets': truth}
    return out


def run_seed(seed: int, periodic: bool) -> dict:
    errors = GantryErrors() if periodic else replace(GantryErrors(), periodic_amplitude_x=0.0,
                                                     periodic_amplitude_y=0.0)
    gantry = GantrySim(errors)
    print(f'  seed {seed} ({"with" if periodic else "without"} screw periodic error): '
          'vision calibration', flush=True)
    calibration = vision_calibration(gantry, seed)
    travel = grid_self_calibration(gantry, calibration, seed,
                                   progress=lambda line: print(line, flush=True))
    stage_map = StageErrorMap(travel.stitched.sites, travel.stitched.stage_error,
                              PLAN.grid.pitch)
    return {'unidirectional': evaluate(gantry, calibration, stage_map, seed, False),
            'bidirectional': evaluate(gantry, calibration, stage_map, seed, True),
            'overlap_rms_m': travel.stitched.overlap_rms,
            'noise_m': float(np.mean([r.noise for r in travel.results.values()])),
            'isotropic_scale': travel.isotropic_scale}


def plot(path: Path, one: dict) -> None:
    """Error vectors before and after the grid self-calibration on one scale."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.6))
    names = ('vision calibration', 'vision + grid self-calibration')
    longest = max(np.linalg.norm(one[n]['errors'], axis=1).max() for n in names) * 1e6
    for ax, name in zip(axes, names):
        where, error = one[name]['targets'] * 1e3, one[name]['errors'] * 1e6
        arrows = ax.quiver(where[:, 0], where[:, 1], error[:, 0], error[:, 1], angles='xy',
                           scale_units='xy', scale=longest / 15.0, width=0.004)
        arrow_key(ax, arrows, round(longest / 2, 1), 'um')
        ax.set_title(f'{name}: max {one[name]["max_m"] * 1e6:.2f} um, RMS '
                     f'{one[name]["rms_m"] * 1e6:.2f} um', loc='left', fontsize=10)
        ax.set_xlabel('x (mm)')
        ax.set_ylabel('y (mm)')
        ax.set_aspect('equal')
    # Room for the arrow keys below the axes and the titles above (equal-aspect axes grow
    # to the top of their box, and a title there was cut off).
    fig.tight_layout(rect=(0, 0.12, 1, 0.93))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def run(out: Path, seeds=(1, 2, 3)) -> None:
    out.mkdir(parents=True, exist_ok=True)
    runs = {f'{"with" if p else "without"} periodic error': [run_seed(s, p) for s in seeds]
            for p in (True, False)}
    plot(out / 'grid_gantry.png', runs['with periodic error'][0]['unidirectional'])
    summary = {}
    for case, by_seed in runs.items():
        for approach in ('unidirectional', 'bidirectional'):
            for name in by_seed[0][approach]:
                values = [r[approach][name] for r in by_seed]
                summary.setdefault(case, {}).setdefault(approach, {})[name] = {
                    k: {'mean': float(np.mean([v[k] for v in values])),
                        'min': float(np.min([v[k] for v in values])),
                        'max': float(np.max([v[k] for v in values]))}
                    for k in ('max_m', 'rms_m')}
        summary[case]['overlap_rms_m'] = [r['overlap_rms_m'] for r in by_seed]
        summary[case]['noise_m'] = [r['noise_m'] for r in by_seed]
    result = {'seeds': list(seeds), 'targets_per_seed': EVALUATION_TARGETS,
              'plan': {'marks_per_side': 2 * PLAN.half + 1, 'pitch_m': PLAN.pitch,
                       'regions': f'{PLAN.columns} x {PLAN.rows}'}, 'summary': summary}
    write_results(out, 'grid_gantry', result)
    lines = [f'Camera position error against truth at {EVALUATION_TARGETS} random targets over '
             f'the calibrated area, seeds {list(seeds)}: mean over seeds (range), um.', '',
             '| gantry | approach | calibration | max | RMS |', '|---|---|---|---|---|']
    for case, by_approach in summary.items():
        for approach in ('unidirectional', 'bidirectional'):
            for name, v in by_approach[approach].items():
                lines.append(f'| {case} | {approach} | {name} | '
                             f'{v["max_m"]["mean"] * 1e6:.2f} ({v["max_m"]["min"] * 1e6:.2f}-'
                             f'{v["max_m"]["max"] * 1e6:.2f}) | {v["rms_m"]["mean"] * 1e6:.2f} '
                             f'({v["rms_m"]["min"] * 1e6:.2f}-{v["rms_m"]["max"] * 1e6:.2f}) |')
    write_table(out, 'grid_gantry', lines)


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    main()
