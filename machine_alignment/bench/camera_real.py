"""The closed loop on two real cameras others calibrated (test/data/measured, ROS-Industrial
industrial_calibration, Apache-2.0): a 640 x 480 camera's 10 x 10 dot grid in 14 views and
an AVT Mako's ChArUco corners in 15. Per camera: what the loop adds (share of its hold-out
splits, values and standard deviations), OpenCV's calibration of the same points with the
same coefficients free (the independent reference), how far each coefficient lies from
OpenCV's in its own standard deviations, the held-out error before and after, and what it
leaves unexplained. Writes ``<out>/camera_real.json`` and ``.md``."""
from __future__ import annotations

from pathlib import Path

from calib_core.closed_loop import LoopConfig, analyze
from machine_alignment.bench import main_with_out, write_results, write_table
from printer_alignment.core.camera_calibration import calibrate_intrinsics, read_correspondences
from printer_alignment.core.loop_models import CameraLoopModel

MEASURED = Path(__file__).resolve().parents[2] / 'test' / 'data' / 'measured'
CAMERAS = (('640 x 480, 10 x 10 dot grid, 14 views', 'ric_circlegrid_640', (640, 480)),
           ('AVT Mako 1600 x 1200, ChArUco corners, 15 views', 'ric_charuco_mako',
            (1600, 1200)))
# The coefficients each effect of the loop stands for.
OPENCV_FREE = {'radial_distortion': ('k1', 'k2'), 'radial_distortion_k3': ('k3',),
               'tangential_distortion': ('p1', 'p2')}


def opencv_coefficients(views, size, free: set) -> tuple[dict, float]:
    """The suite's OpenCV calibration (calibrate_intrinsics) of ``views`` with the
    distortion coefficients ``free``: all five, or k1, k2 alone (its radial_only); the
    coefficients and the RMS reprojection (px)."""
    if free not in ({'k1', 'k2', 'p1', 'p2', 'k3'}, {'k1', 'k2'}):
        raise ValueError(f'no OpenCV calibration frees exactly {sorted(free)}')
    result = calibrate_intrinsics(views, size, radial_only=free == {'k1', 'k2'})
    values = result.report()['parameters']
    return {name: values[name] for name in ('k1', 'k2', 'p1', 'p2', 'k3') if name in free}, \
        float(result.rms_px)


def run(out: Path) -> dict:
    rows = []
    for label, folder, size in CAMERAS:
        views = read_correspondences(MEASURED / folder / 'correspondences.csv')
        report = analyze(CameraLoopModel(views, size), LoopConfig()).report
        added = {e['name']: e for e in report['effects_added']}
        free = {c for name in added for c in OPENCV_FREE[name]}
        opencv, opencv_rms = opencv_coefficients(views, size, free)
        found = {c: (e['parameters'][c], e['std_devs'][c]) for e in added.values()
                 for c in e['parameters']}
        rows.append({
            'camera': label, 'data': folder, 'points': int(sum(len(v.model) for v in views)),
            'added': {name: report['selection_frequency'].get(name) for name in added},
            'found': {c: {'value': v, 'std_dev': s} for c, (v, s) in found.items()},
            'opencv': opencv, 'opencv_rms_px': opencv_rms,
            'largest_sigmas_from_opencv': max(
                (abs(found[c][0] - opencv[c]) / found[c][1] for c in opencv), default=0.0),
            'held_out': {k: report[k] for k in ('rms_before', 'rms_after', 'max_before',
                                                 'max_after')},
            'unexplained': [{k: u[k] for k in ('covariate', 'kind', 'structure_rms',
                                               'p_value') if k in u}
                            for u in report['unexplained']]})
        print(f'{folder}: added {list(added)}, held-out RMS {report["rms_before"]:.3f} -> '
              f'{report["rms_after"]:.3f} px')
    write_results(out, 'camera_real', {'rows': rows})
    lines = ['The closed loop (`machine-align analyze camera`, its defaults: 5 hold-out splits) '
             'on two real cameras\' point tables (test/data/measured, ROS-Industrial '
             'industrial_calibration, Apache-2.0), against OpenCV\'s calibrateCamera of the '
             'same points with the same coefficients free. Held-out figures pooled over the '
             'splits; px.', '',
             '| camera | points | added (share of splits) | loop: value +- sigma | OpenCV | '
             'largest difference | held-out RMS | held-out max | left unexplained |',
             '|---|---|---|---|---|---|---|---|---|']
    for row in rows:
        added = ', '.join(f'{n} ({100 * s:.0f} %)' for n, s in row['added'].items()) or 'nothing'
        found = ', '.join(f'{c} {v["value"]:.4g} +- {v["std_dev"]:.2g}'
                          for c, v in row['found'].items())
        opencv = ', '.join(f'{c} {v:.4g}' for c, v in row['opencv'].items())
        held = row['held_out']
        left = '; '.join(f'{u["kind"]} against {u["covariate"]}, {u["structure_rms"]:.3f} px '
                         f'(p = {u["p_value"]:.1g})' for u in row['unexplained']) or 'nothing'
        lines.append(f'| {row["camera"]} | {row["points"]} | {added} | {found} | {opencv} '
                     f'(RMS {row["opencv_rms_px"]:.3f}) | '
                     f'{row["largest_sigmas_from_opencv"]:.1f} sigma | '
                     f'{held["rms_before"]:.3f} -> {held["rms_after"]:.3f} | '
                     f'{held["max_before"]:.2f} -> {held["max_after"]:.2f} | {left} |')
    write_table(out, 'camera_real', lines)
    return {'rows': rows}


def main(argv=None) -> int:
    return main_with_out(run, __doc__.splitlines()[0], argv)


if __name__ == '__main__':
    raise SystemExit(main())
