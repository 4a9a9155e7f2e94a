"""``machine-align simulate|calibrate five-axis`` and ``machine-align locate``: the
five-axis dispenser's vision calibration from board images (observations CSV) and the
localisation of a workpiece's features through the calibrated chain (issue 23)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_core.errors import InvalidInputError  # noqa: E402
from calib_core.figures import arrow_key  # noqa: E402
from calib_core.files import read_csv_rows  # noqa: E402
from dispenser_calib.core.calibration import calibrate, check_calibration, reprojection  # noqa: E402
from dispenser_calib.core.procedure import finish  # noqa: E402
from dispenser_calib.core.records import (  # noqa: E402
    OBSERVATIONS_TOPIC, RESULT_TOPIC, image_from_message)
from dispenser_calib.core.data import check_poses, read_observations, write_observations  # noqa: E402
from dispenser_calib.core.iso230 import ORIENTATION, iso230_7_report  # noqa: E402
from dispenser_calib.core.localisation import locate  # noqa: E402
from dispenser_calib.core.model import (  # noqa: E402
    NAMES, nominal_model, parameter_unit, read_model, write_model)
from dispenser_calib.core.procedure import plan_stops, rotary_sweep  # noqa: E402
from dispenser_calib.sim.machine import IMAGE_SIZE, observe, true_model  # noqa: E402
from machine_alignment.cli.common import (  # noqa: E402
    parse_size, quantity, ranged, read_run, write_json, write_json_and_plot)


def cmd_simulate(args) -> int:
    truth = true_model(args.seed)
    stops = rotary_sweep() if args.sweep else plan_stops(nominal_model(), args.seed)
    worm = None
    if args.worm:
        amplitude, order = args.worm
        worm = lambda c: amplitude * np.cos(order * c)  # noqa: E731
    images, bad = observe(truth, stops, args.noise, args.seed, args.bad_fraction, worm)
    write_observations(args.out, images)
    print(f'wrote {args.out} ({len(images)} images of an 11 x 9 dot board, 2 mm pitch, '
          f'{IMAGE_SIZE[0]}x{IMAGE_SIZE[1]} px; {len(bad)} with a mis-detected dot: '
          f'{", ".join(bad) or "none"})')
    if args.truth:
        write_model(args.truth, truth)
        print(f'wrote {args.truth} (the simulation\'s true model)')
    return 0


def _plot(path: Path, images, result) -> None:
    """Reprojection per image, convergence per iteration, residual vectors of all dots
    (one scale, a key), and the rotary axes' orientation errors (ISO 230-7 names)."""
    errors = reprojection(result.model, images)
    per_image = [float(np.sqrt(np.mean(e ** 2))) for e in errors]
    fig, axes = plt.subplots(2, 2, figsize=(13, 9.5))
    colours = ['C3' if im.name in result.outliers else 'C0' for im in images]
    axes[0, 0].bar(np.arange(len(images)), per_image, color=colours)
    axes[0, 0].set_yscale('log')
    axes[0, 0].set_xlabel('image (red: set aside by RANSAC)')
    axes[0, 0].set_ylabel('RMS reprojection (px, log)')
    axes[0, 1].semilogy(np.arange(len(result.history)), result.history, 'o-')
    axes[0, 1].set_xlabel('iteration')
    axes[0, 1].set_ylabel('mean reprojection (px, log)')
    used = [(im, e) for im, e in zip(images, errors) if im.name not in result.outliers]
    uv = np.concatenate([im.pixels for im, _ in used])
    r = np.concatenate([e for _, e in used])
    longest = max(np.linalg.norm(r, axis=1).max(), 1e-9)
    arrows = axes[1, 0].quiver(uv[:, 0], uv[:, 1], r[:, 0], r[:, 1], angles='xy',
                               scale_units='xy', scale=longest / 60.0, width=0.002)
    arrow_key(axes[1, 0], arrows, longest / 2, 'px')
    axes[1, 0].set_xlim(0, IMAGE_SIZE[0])
    axes[1, 0].set_ylim(IMAGE_SIZE[1], 0)
    axes[1, 0].set_xlabel('u (px)')
    axes[1, 0].set_ylabel('v (px)')
    axes[1, 0].set_title(f'residuals of the images used (longest {longest:.3g} px)', loc='left',
                         fontsize=10)
    iso = iso230_7_report(result.model, result.covariance)
    values = [iso['values'][n] * 1e6 for n in ORIENTATION]
    sigmas = [iso['std_devs'][n] * 1e6 for n in ORIENTATION]
    axes[1, 1].errorbar(np.arange(len(ORIENTATION)), values, yerr=sigmas, fmt='o', capsize=4)
    axes[1, 1].set_xticks(np.arange(len(ORIENTATION)), ORIENTATION)
    axes[1, 1].axhline(0, color='k', lw=0.8)
    axes[1, 1].set_ylabel('rotary axis orientation error, machine frame (urad, 1 sigma bars)')
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=80)
    plt.close(fig)


def cmd_calibrate(args) -> int:
    size = parse_size(args.image_size) if args.image_size else IMAGE_SIZE
    recorded = None
    if args.bag:
        stops, recorded = read_run(args.bag, OBSERVATIONS_TOPIC,
                                   'alignment_msgs/msg/FiveAxisObservation', image_from_message,
                                   'five-axis observations', RESULT_TOPIC)
        images = [im for im, phase in stops if phase == 'calibrate']
        result, report, _ = finish(nominal_model(size=size), size, images,
                                   [im for im, phase in stops if phase == 'evaluate'])
    else:
        images = read_observations(args.data)
        _, result = calibrate(images, size)
        report = result.report(images)
        check_calibration(result.model, report)
    print(f'{len(images)} images, {report["images_used"]} used; mean reprojection '
          f'{report["mean_reprojection_px"]:.3f} px (RMS {report["rms_reprojection_px"]:.3f} '
          f'px); per iteration from the stepwise start: '
          + ', '.join(f'{h:.3g}' for h in result.history[:6]))
    for name, error in result.outliers.items():
        print(f'  set aside by RANSAC: {name} (RMS {error:.2f} px)')
    for name in NAMES:
        print(f'  {name:>11} = {quantity(report["parameters"][name], report["std_devs"][name], parameter_unit(name))}')
    print(f'  gauge: {report["gauge"]}')
    iso = report['iso230_7']
    print(f'  ISO 230-7, {iso["frame"]}:')
    for name, value in iso['values'].items():
        print(f'  {name:>17} = {quantity(value, iso["std_devs"][name], iso["units"][name])}')
    if 'held_out' in report:
        held = report['held_out']
        print(f'  held out ({held["images"]} images, A and C both turned): RMS '
              f'{held["rms_px_calibrated"]:.3f} px calibrated, {held["rms_px_nominal"]:.1f} px '
              'nominal')
    if recorded is not None:
        # In standard deviations: the refinement stops at its tolerances, which floating
        # point in another process can cross an iteration earlier or later.
        live = np.array([recorded['parameters'][n] for n in NAMES])
        report['max_difference_to_live_sigma'] = float(
            (np.abs(live - result.model.values) / result.std_devs).max())
        print(f'  same as the live run: max |difference| '
              f'{report["max_difference_to_live_sigma"]:.3g} sigma')
    if args.out:
        write_model(args.out, result.model, {'std_devs': report['std_devs']})
        print(f'wrote {args.out}')
    write_json_and_plot(args.json, report, lambda png: _plot(png, images, result))
    return 0


def cmd_locate(args) -> int:
    """Features from views: CSV feature, x, y, z, a, c, u, v."""
    model = read_model(args.calibration)
    rows = read_csv_rows(args.data, 'a features CSV',
                         ('feature', 'x', 'y', 'z', 'a', 'c', 'u', 'v'))
    views = {}
    try:
        for row in rows:
            views.setdefault(row['feature'], []).append(
                [float(row[k]) for k in ('x', 'y', 'z', 'a', 'c', 'u', 'v')])
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInputError(f'{args.data} needs feature, x, y, z, a, c, u, v ({exc!r})') from None
    check_poses(np.vstack([np.array(table)[:, :5] for table in views.values()]), str(args.data))
    located = {}
    for name, table in views.items():
        table = np.array(table)
        point, rms = locate(model, table[:, :5], table[:, 5:])
        located[name] = {'position_m': point.tolist(), 'reprojection_rms_px': rms,
                         'views': len(table)}
        print(f'{name}: ({point[0] * 1e3:.4f}, {point[1] * 1e3:.4f}, {point[2] * 1e3:.4f}) mm '
              f'from {len(table)} views, reprojection RMS {rms:.3f} px')
    write_json(args.json, located)
    return 0


def add_simulate_parser(simulated) -> None:
    p = simulated.add_parser('five-axis', help='board images of the simulated five-axis '
                                               'dispenser (observations CSV)')
    p.add_argument('--out', required=True)
    p.add_argument('--seed', type=ranged(int, 0), default=0)
    p.add_argument('--noise', type=ranged(float, 0.0, 50.0, 'px'), default=0.1, help='dot-centre noise, px')
    p.add_argument('--bad-fraction', type=ranged(float, 0.0, 0.5, '', 'RANSAC needs most images good'), default=0.05,
                   help='images with a mis-detected dot')
    p.add_argument('--truth', help='also write the true model (YAML)')
    p.add_argument('--sweep', action='store_true',
                   help='the rotary sweep with the linear axes held (for analyze rotary '
                        '--calibration) instead of the calibration stops')
    p.add_argument('--worm', type=float, nargs=2, metavar=('AMPLITUDE', 'ORDER'),
                   help='C turns AMPLITUDE cos(ORDER c) rad beyond its reading')
    p.set_defaults(func=cmd_simulate)


def add_calibrate_parser(what) -> None:
    p = what.add_parser('five-axis', help='the dispenser\'s camera and kinematic chain from '
                                          'board images')
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument('--data', help='CSV: image, x, y, z (m), a, c (rad), i, j, u, v (px)')
    source.add_argument('--bag', help='a run recorded by five_axis_calibrator')
    p.add_argument('--image-size', help='WxH px (default 2448x2048)')
    p.add_argument('--out', help='calibration YAML to write')
    p.add_argument('--json', help='report to write; the plot goes beside it')
    p.set_defaults(func=cmd_calibrate)


def add_locate_parser(sub) -> None:
    p = sub.add_parser('locate', help='a workpiece\'s features through the calibrated chain')
    p.add_argument('--calibration', required=True, help='five-axis calibration YAML')
    p.add_argument('--data', required=True, help='CSV: feature, x, y, z (m), a, c (rad), u, v (px)')
    p.add_argument('--json', help='positions to write')
    p.set_defaults(func=cmd_locate)
