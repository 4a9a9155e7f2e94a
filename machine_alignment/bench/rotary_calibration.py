"""The rotary axes' loop on poses measured through the dispenser's own camera, with and
without weighing the effects against the camera calibration's covariance
(calib_core/closed_loop/inputs.py): 20 simulated dispensers (`true_model(seed)`), each
calibrated from its 27 stepwise images (0.1 px), then a sweep (A at -0.3, 0, 0.3 rad, C
every 22.5 degrees) with the table turning exactly as read, and with A turning 1e-3, 2e-3
and 3e-3 further than read. Per case: how often a scale of A is added, by either loop,
and for the weighed loop the error of the added scale in its stated sigma (the data's and
the calibration's together). Writes bench_results/rotary_calibration.{md,json}."""
import time
from dataclasses import replace

import numpy as np

from calib_core.closed_loop import analyze
from dispenser_calib.core.calibration import calibrate
from dispenser_calib.core.loop_model import RotaryLoopModel
from dispenser_calib.core.model import nominal_model
from dispenser_calib.core.procedure import plan_stops, rotary_sweep
from dispenser_calib.core.target_poses import pose_variants, poses_from_images
from dispenser_calib.sim.machine import IMAGE_SIZE, observe, true_model
from machine_alignment.bench import main_with_out, write_results, write_table

MACHINES = 20
SCALES = (0.0, 1e-3, 2e-3, 3e-3)
SWEEP = rotary_sweep([-0.3, 0.0, 0.3], 0.3927, False)


def one_case(truth, result, scale: float, seed: int) -> dict:
    """Both loops on the sweep of ``truth`` with A turning ``scale`` further than read,
    its poses through the calibration ``result``."""
    turned = SWEEP.copy()
    turned[:, 3] *= 1 + scale
    images, _ = observe(truth, turned, 0.1, seed + 7)
    images = [replace(im, pose=pose.copy()) for im, pose in zip(images, SWEEP)]
    poses = poses_from_images(result.model, images)
    out = {'scale': scale}
    for name, variants in (('plain', None),
                           ('weighed', pose_variants(result.model, result.covariance, images))):
        start = time.process_time()
        report = analyze(RotaryLoopModel(poses, variants=variants)).report
        found = next((e for e in report['effects_added'] if e['name'] == 'scale'), None)
        out[name] = {'added': [e['name'] for e in report['effects_added']],
                     'cpu_s': time.process_time() - start}
        if found is not None and 'scale_a' in found['parameters']:
            sigma = np.hypot(found['std_devs']['scale_a'],
                             found.get('calibration_std_devs', {}).get('scale_a', 0.0))
            out[name].update(scale_a=found['parameters']['scale_a'], sigma=float(sigma),
                             data_sigma=found['std_devs']['scale_a'],
                             z=float((found['parameters']['scale_a'] - scale) / sigma))
    return out


def run(out):
    runs = []
    for seed in range(MACHINES):
        truth = true_model(seed)
        images, _ = observe(truth, plan_stops(nominal_model(), seed), 0.1, seed)
        _, result = calibrate(images, IMAGE_SIZE)
        for scale in SCALES:
            runs.append({'seed': seed, **one_case(truth, result, scale, seed)})
            r = runs[-1]
            print(f'machine {seed}, scale {scale:g}: plain {r["plain"]["added"]}, weighed '
                  f'{r["weighed"]["added"]}', flush=True)
    lines = [f'# The rotary loop through the camera\'s calibration ({MACHINES} machines)', '',
             '`python -m machine_alignment.bench.rotary_calibration`: each simulated '
             'dispenser calibrated from its 27 stepwise images (0.1 px), then a sweep with '
             'the linear axes held (A at -0.3, 0, 0.3 rad, C every 22.5 deg, 48 images), '
             'its poses through that calibration; A turning as read or a share further. '
             '`plain`: the loop weighing the poses by their own noise; `weighed`: also '
             'against the calibration\'s covariance. z: the added scale\'s error over its '
             'stated sigma (data and calibration together).', '',
             '| A turns further by | plain: scale of A added | weighed: added | weighed: '
             'median |z| (max) | sigma of the scale: data, with the calibration (median) | '
             'weighed: CPU s (median) |', '|---|---|---|---|---|---|']
    summary = {}
    for scale in SCALES:
        rows = [r for r in runs if r['scale'] == scale]
        plain = sum('scale' in r['plain']['added'] for r in rows)
        weighed = [r['weighed'] for r in rows if 'z' in r['weighed']]
        z = np.abs([w['z'] for w in weighed])
        summary[str(scale)] = {'plain_added': plain, 'weighed_added': len(weighed),
                               'median_abs_z': float(np.median(z)) if len(z) else None}
        lines.append(
            f'| {scale:g} | {plain} of {len(rows)} | {len(weighed)} of {len(rows)} | '
            + (f'{np.median(z):.2f} ({z.max():.2f})' if len(z) else '-') + ' | '
            + (f'{np.median([w["data_sigma"] for w in weighed]):.2g}, '
               f'{np.median([w["sigma"] for w in weighed]):.2g}' if weighed else '-') + ' | '
            + f'{np.median([r["weighed"]["cpu_s"] for r in rows]):.2f} |')
    write_results(out, 'rotary_calibration', {'machines': MACHINES, 'summary': summary,
                                              'runs': runs})
    write_table(out, 'rotary_calibration', lines)
    return summary


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    raise SystemExit(main())
