"""The hexapod's measurement plan (issue 32): today's 13 poses (each leg's information
determinant, greedily), the shared exchange's (I: least pose error over the box; D) and
random ones (13, 26, 39) and the I exchange over 2000 candidates at 13, 26 and 39 poses
(how far planning can go in this box), each predicted before anything moves and realised on 20
simulated hexapods without leg play (the effect the 42 parameters lack; the closed loop's
job), at the same 100 working poses. Writes bench_results/plan_hexapod.{md,json}."""
import dataclasses
import time
from pathlib import Path

import numpy as np

from calib_core.errors import CalibrationError
from hexapod_calib.core.calibration import identifiability
from hexapod_calib.core.geometry import nominal_geometry
from hexapod_calib.core.planning import LEVER, criterion_rms, planning_floor, predict
from hexapod_calib.core.procedure import HexapodPlan
from hexapod_calib.sim.hexapod import HexapodTruth, displacement_after_identifying
from machine_alignment.bench import main_with_out, write_results, write_table

MACHINES = 20
POSES = 13
WORKING = 100
LARGE_POOL = 2000


def _random(pool: np.ndarray, count: int, nominal, rng) -> np.ndarray:
    """``count`` poses drawn from ``pool`` that determine the 42 parameters."""
    while True:
        poses = pool[rng.choice(len(pool), count, replace=False)]
        try:
            identifiability(nominal, poses)
            return poses
        except CalibrationError:    # a draw that does not determine them: draw again
            continue


def designs(nominal) -> tuple[dict, np.ndarray, dict]:
    """The designs' poses, the shared working poses and the planning time per design (s).
    Working poses and random designs are another seed's candidates (inside the stroke,
    well conditioned), so no working pose is one a design measured."""
    plan = HexapodPlan(num_poses=POSES, seed=0)
    _, others = HexapodPlan(num_poses=POSES, num_evaluation=2 * WORKING, seed=99).poses(nominal)
    working, pool = others[:WORKING], others[WORKING:]
    rng = np.random.default_rng(7)
    out, seconds = {}, {}
    for design in ('greedy', 'I', 'D'):
        start = time.perf_counter()
        out[f'planned {POSES} ({design})'] = dataclasses.replace(plan, design=design).poses(
            nominal)[0]
        seconds[design] = time.perf_counter() - start
    for count in (POSES, 2 * POSES, 3 * POSES):
        out[f'random {count}'] = _random(pool, count, nominal, rng)
    # How far planning can go in this box: the I exchange over five times the candidates,
    # and at 2N and 3N poses (issue 50 asked planned N to match random 3N).
    for count in (POSES, 2 * POSES, 3 * POSES):
        out[f'planned {count} (I, {LARGE_POOL} candidates)'] = dataclasses.replace(
            plan, design='I', num_poses=count, num_candidates=LARGE_POOL).poses(nominal)[0]
    return out, working, seconds


def _bound(nominal, poses_by_design: dict, working: np.ndarray) -> dict:
    """The I criterion's certified floor for 13, 26 and 39 poses of the large pool and the
    designs' poses together (RMS, m), and each design's criterion (RMS, m)."""
    _, candidates = HexapodPlan(num_poses=POSES, seed=0,
                                num_candidates=LARGE_POOL)._candidates(nominal)
    pool = np.vstack([candidates, *poses_by_design.values()])
    start = time.process_time()
    floor = planning_floor(nominal, pool, working, (POSES, 2 * POSES, 3 * POSES))
    return {'candidates': len(pool), 'seconds': time.process_time() - start,
            **{k: v for k, v in floor.items() if k != 'rms_m'},
            'rms_m': {str(n): v for n, v in floor['rms_m'].items()},
            'designs_rms_m': {name: criterion_rms(nominal, poses, working)
                              for name, poses in poses_by_design.items()}}


def realised(poses: np.ndarray, working: np.ndarray, nominal) -> list:
    """Per simulated hexapod, the RMS displacement (m) at ``working`` after identifying
    from ``poses``."""
    return [displacement_after_identifying(
        dataclasses.replace(HexapodTruth.default(seed=seed), leg_play=np.zeros(6)), nominal,
        poses, working, seed) for seed in range(MACHINES)]


def run(out: Path) -> dict:
    nominal = nominal_geometry()
    poses_by_design, working, seconds = designs(nominal)
    results = {}
    for name, poses in poses_by_design.items():
        predicted = predict(nominal, poses, working)['predicted_displacement_m']['rms']
        achieved = realised(poses, working, nominal)
        results[name] = {'poses': len(poses), 'predicted_rms_m': predicted,
                         'realised_rms_m': {'median': float(np.median(achieved)),
                                            'min': float(np.min(achieved)),
                                            'max': float(np.max(achieved))},
                         'per_machine_m': achieved}
        print(f'{name}: predicted {predicted * 1e6:.2f} um, realised median '
              f'{np.median(achieved) * 1e6:.2f} um', flush=True)
    lines = [f'Hexapod: displacement error at {WORKING} working poses after identifying the 42 '
             f'parameters, predicted before anything moves (pose sensor 0.6 um / 6 urad, '
             f'actuators 0.5 um, first order) and realised on {MACHINES} simulated hexapods '
             'without leg play (RMS over the working poses; median and range over the '
             'hexapods).', '',
             '| design | poses | predicted RMS | realised RMS (range) | realised / predicted |',
             '|---|---|---|---|---|']
    for name, r in results.items():
        median = r['realised_rms_m']['median']
        lines.append(f'| {name} | {r["poses"]} | {r["predicted_rms_m"] * 1e6:.2f} um | '
                     f'{median * 1e6:.2f} um ({r["realised_rms_m"]["min"] * 1e6:.2f}-'
                     f'{r["realised_rms_m"]["max"] * 1e6:.2f}) | '
                     f'{median / r["predicted_rms_m"]:.2f} |')
    lines += ['', 'Planning time (400 candidates): ' + ', '.join(
        f'{d} {t:.2f} s' for d, t in seconds.items()) + '.']
    best = results[f'planned {POSES} (I, {LARGE_POOL} candidates)']['predicted_rms_m']
    random2, random3 = (results[f'random {k * POSES}']['predicted_rms_m'] for k in (2, 3))
    lines += ['', f'Planned {POSES} against random {3 * POSES} (issue 50): the best the I '
              f'exchange finds among {LARGE_POOL} candidates of this box is predicted at '
              f'{best * 1e6:.2f} um, random {2 * POSES} at {random2 * 1e6:.2f} um and random '
              f'{3 * POSES} at {random3 * 1e6:.2f} um ({best / random3:.2f}x). The poses a '
              'plan may take are bounded by the box and the strokes; more candidates or a '
              'better search within them do not reach the information of three times as '
              'many random poses.']
    bound = _bound(nominal, poses_by_design, working)
    lines += ['', f'Why (the I criterion: the mean squared pose error at the working poses, a '
              f'rotation weighed at {LEVER} m, of a fit weighted by the noise, whose '
              'variance no other linear fit undercuts; the actuators\' repeatability not '
              f'counted): no plan of N of the {bound["candidates"]} candidates (the '
              f'{LARGE_POOL} of the box and every design\'s poses) can have less than the '
              'optimal approximate design over them gives, phi*/N, certified by the '
              'equivalence theorem (calib_core.planning.design_bound, '
              f'{bound["seconds"]:.0f} s). At 13 poses that is '
              f'{bound["rms_m"][str(POSES)] * 1e6:.3f} um, above random {3 * POSES}\'s '
              f'{bound["designs_rms_m"][f"random {3 * POSES}"] * 1e6:.3f} um: no 13-pose plan '
              'of this box reaches random 39. The I exchange over the 2000 candidates ends '
              f'{bound["designs_rms_m"][f"planned {POSES} (I, {LARGE_POOL} candidates)"] / bound["rms_m"][str(POSES)]:.3f}'
              'x the bound at 13 poses, '
              f'{bound["designs_rms_m"][f"planned {2 * POSES} (I, {LARGE_POOL} candidates)"] / bound["rms_m"][str(2 * POSES)]:.3f}'
              f'x at 26 and '
              f'{bound["designs_rms_m"][f"planned {3 * POSES} (I, {LARGE_POOL} candidates)"] / bound["rms_m"][str(3 * POSES)]:.3f}'
              'x at 39.', '',
              '| design | poses | criterion RMS | the bound for as many poses |',
              '|---|---|---|---|']
    for name, value in bound['designs_rms_m'].items():
        count = len(poses_by_design[name])
        lines.append(f'| {name} | {count} | {value * 1e6:.3f} um | '
                     f'{bound["rms_m"][str(count)] * 1e6:.3f} um |')
    write_results(out, 'plan_hexapod', {**results, 'planning_seconds': seconds,
                                        'bound': bound})
    write_table(out, 'plan_hexapod', lines)
    return results


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    raise SystemExit(main())
