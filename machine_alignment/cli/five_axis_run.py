"""The work of the subcommands ``five_axis.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_core.errors import InvalidInputError  # noqa: E402
from calib_core.figures import arrow_key  # noqa: E402
from calib_core.controller_formats import write_gcode_path  # noqa: E402
from dispenser_calib.core.calibration import calibrate, check_calibration, reprojection  # noqa: E402
from dispenser_calib.core.records import (  # noqa: E402
    OBSERVATIONS_TOPIC, RESULT_TOPIC, image_from_message)
from dispenser_calib.core.data import (  # noqa: E402
    SHIPPED_BOARD, board_as_dict, board_from_dict, read_observations, write_observations)
from dispenser_calib.core.description import read_description  # noqa: E402
from dispenser_calib.core.iso230 import ORIENTATION, iso230_7_report  # noqa: E402
from dispenser_calib.core.localisation import (  # noqa: E402
    fit_part_pose, locate, place_path, reached)
from dispenser_calib.core.model import (  # noqa: E402
    NAMES, nominal_model, parameter_unit, place, read_model, write_model)
from dispenser_calib.core.part_files import (  # noqa: E402
    read_path_poses, read_plan, read_points, read_views, write_path_poses, write_points,
    write_views)
from dispenser_calib.core.procedure import (  # noqa: E402
    FEATURE_VIEWS, NEEDLE_TIP, PART_CAD, PART_PATH, SHIPPED_WORKSPACE, TEST_SPOTS, check_stroke,
    finish, plan_stops, rotary_sweep, tip_from_dots, view_plan)
from dispenser_calib.sim.machine import (  # noqa: E402
    IMAGE_SIZE, PART_POSE, TRUE_TIP_OFFSET, observe, placed_part,
    points_in_view, true_model)
from machine_alignment.cli.common import (  # noqa: E402
    parse_size, quantity, read_in_si, read_run, write_json, write_report)


def cmd_simulate(args) -> int:
    described = read_description(args.description) if args.description else None
    if described and (args.features or args.needle):
        raise InvalidInputError('--features and --needle simulate the shipped machine\'s part '
                                'and needle: give them without --description')
    nominal = described.nominal() if described else nominal_model()
    workspace = described.workspace() if described else SHIPPED_WORKSPACE
    size = described.image_size if described else IMAGE_SIZE
    noise = args.noise if args.noise is not None else (
        described.centroid_sigma_px if described else 0.1)
    truth = true_model(args.seed, nominal)
    if args.plan and args.sweep:
        raise InvalidInputError('--plan and --sweep are two different runs: give one')
    if args.plan:
        stops = read_plan(args.plan)[1]
        for pose in stops:
            workspace.check(pose)
    else:
        stops = rotary_sweep() if args.sweep else plan_stops(nominal, args.seed, workspace)
    worm = None
    if args.worm:
        amplitude, order = args.worm
        worm = lambda c: amplitude * np.cos(order * c)  # noqa: E731
    images, bad = observe(truth, stops, noise, args.seed, args.bad_fraction, worm,
                          image_size=size, workspace=workspace,
                          pose_sigma=described.pose_sigma() if described else None)
    if described:
        described.write(args.out, images)
    else:
        write_observations(args.out, images)
    units = (f'poses in {described.linear_unit} and {described.rotary_unit}' if described
             else 'poses in m and rad')
    board = workspace.board
    print(f'wrote {args.out} ({len(images)} images of a {board.dots[0]} x {board.dots[1]} '
          f'dot board, {board.pitch * 1e3:g} mm pitch, {size[0]}x{size[1]} px, dots to '
          f'{noise:g} px; {units}; {len(bad)} with a mis-detected dot: '
          f'{", ".join(bad) or "none"})')
    if args.truth:
        write_model(args.truth, truth, {'part_pose': PART_POSE.tolist()})
        print(f'wrote {args.truth} (the simulation\'s true model and the part\'s pose: x, y, '
              'z m, rotation vector rad)')
    if args.features:
        _simulate_features(args, truth, noise)
    if args.needle:
        _simulate_needle(args, truth, noise)
    return 0


def _simulate_needle(args, truth, noise_px: float) -> None:
    """What ``needle`` reads: a test dot dispensed at each of TEST_SPOTS (aimed with the
    nominal model and the configured tip; the true tip is TRUE_TIP_OFFSET from it), then
    each dot imaged from FEATURE_VIEWS through the true chain."""
    dispensing = np.array([place(nominal_model(), spot, 0.0, 0.0, NEEDLE_TIP)
                           for spot in TEST_SPOTS])
    for pose in dispensing:
        check_stroke(pose)
    dots = reached(truth, NEEDLE_TIP + TRUE_TIP_OFFSET, dispensing)
    names = [f'd{k}' for k in range(len(TEST_SPOTS))]
    views = _imaged_views(truth, TEST_SPOTS, dots, names, noise_px,
                          np.random.default_rng(args.seed + 91))
    write_views(args.needle, *views)
    stem = Path(args.needle)
    dispensed = stem.with_name(stem.stem + '_dispensed.csv')
    write_path_poses(dispensed, names, dispensing)
    print(f'wrote {args.needle} ({len(views[0])} views of {len(TEST_SPOTS)} dispensed test '
          f'dots) and {dispensed} (the poses they were dispensed at)')


def _simulate_features(args, truth, noise_px: float) -> None:
    """The views ``locate`` reads: the simulated part (the node's default CAD, placed at
    PART_POSE) imaged through the true chain from FEATURE_VIEWS, each aimed with the
    nominal model; its CAD and dispensing path beside them."""
    names = [f'f{k}' for k in range(len(PART_CAD))]
    views = _imaged_views(truth, PART_CAD, placed_part(PART_CAD), names, noise_px,
                          np.random.default_rng(args.seed + 90))
    write_views(args.features, *views)
    stem = Path(args.features)
    cad_path = stem.with_name(stem.stem + '_cad.csv')
    path_path = stem.with_name(stem.stem + '_path.csv')
    write_points(cad_path, names, PART_CAD)
    write_points(path_path, [f'p{k}' for k in range(len(PART_PATH))], PART_PATH)
    print(f'wrote {args.features} ({len(views[0])} views of {len(PART_CAD)} features), '
          f'{cad_path} (the part\'s CAD) and {path_path} (its dispensing path, '
          f'{len(PART_PATH)} points); the configured needle tip: '
          f'{" ".join(f"{v:g}" for v in NEEDLE_TIP)} m')


def _imaged_views(truth, aimed_at, points, names, noise_px: float, rng) -> tuple:
    """Each of ``points`` (k, 3) (board frame, m; named ``names``) imaged through the true
    chain from FEATURE_VIEWS, the camera aimed with the nominal model at ``aimed_at`` (k,
    3), every pose checked against the strokes: (names, poses (n, 5), pixels (n, 2)) of
    the views in which it is in the frame."""
    views = []
    for k, pose in view_plan(nominal_model(), aimed_at, FEATURE_VIEWS):
        check_stroke(pose)
        seen, found = points_in_view(truth, points[k], pose, noise_px, rng)
        if len(seen):
            views.append((names[k], pose, found[0]))
    return [v[0] for v in views], np.array([v[1] for v in views]), np.array([v[2] for v in views])


def _plot(path: Path, images, result, image_size) -> None:
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
    axes[1, 0].set_xlim(0, image_size[0])
    axes[1, 0].set_ylim(image_size[1], 0)
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
    described = read_description(args.description) if args.description else None
    size = (described.image_size if described else
            parse_size(args.image_size) if args.image_size else IMAGE_SIZE)
    recorded = None
    if args.bag:
        # The graph carries poses in m and rad: a description gives the camera and the gate.
        stops, recorded = read_run(args.bag, OBSERVATIONS_TOPIC,
                                   'alignment_msgs/msg/FiveAxisObservation', image_from_message,
                                   'five-axis observations', RESULT_TOPIC)
        if recorded and not (described or args.image_size):
            size = tuple(recorded.get('image_size_px', size))
        # The board the dots were named on: the description's, else the one the live run
        # recorded in its result, else the shipped one.
        board = (described.board if described else
                 board_from_dict(recorded['board']) if recorded and 'board' in recorded
                 else SHIPPED_BOARD)
        stops = [(replace(im, board=board), phase) for im, phase in stops]
        images = [im for im, phase in stops if phase == 'calibrate']
        result, report, _ = finish(described.nominal() if described else nominal_model(size=size),
                                   size, images,
                                   [im for im, phase in stops if phase == 'evaluate'], described)
        live_description = (recorded or {}).get('description', {}).get('file')
        if live_description and not described:
            print(f'  the live run was gated by the machine description {live_description}; '
                  'this replay by the built-in gate (give --description to gate it the same '
                  'way)')
    else:
        images = (described.read(args.data) if described
                  else read_in_si(read_observations, args.data,
                                  actuators=('x', 'y', 'z', 'a', 'c')))
        _, result = calibrate(images, size,
                              pose_sigma=described.pose_sigma() if described else None)
        report = result.report(images)
        if described:
            described.check(result.model, report, images)
        else:
            check_calibration(result.model, report)
    if described:
        report['description'] = described.gate_report()
        read = (f'poses read in {described.linear_unit} and {described.rotary_unit}' if args.data
                else 'poses from the graph in m and rad')
        print(f'  machine description {described.source}: {described.expected_text()}; {read}')
    print(f'{len(images)} images, {report["images_used"]} used; mean reprojection '
          f'{report["mean_reprojection_px"]:.3f} px (RMS {report["rms_reprojection_px"]:.3f} '
          f'px); the refinement took it from {result.history[0]:.3g} px (the stepwise start) '
          f'to {result.history[-1]:.3g} px in {len(result.history) - 1} iterations (plotted)')
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
        write_model(args.out, result.model, {
            'std_devs': report['std_devs'], 'covariance': result.covariance.tolist(),
            'board': board_as_dict(images[0].board)})
        print(f'wrote {args.out}')
    write_report(args.json, report, lambda png: _plot(png, images, result, size))
    return 0


def cmd_locate(args) -> int:
    """Features from views (CSV feature, x, y, z, a, c, u, v); with the part's CAD and
    path, the part's pose and the path poses (labelled CSV, G-code)."""
    model = read_model(args.calibration)
    views = read_views(args.data)
    located = {}
    for name, point, rms in zip(views, *_located(model, views, list(views))):
        located[name] = {'position_m': point.tolist(), 'reprojection_rms_px': rms,
                         'views': len(views[name])}
        print(f'{name}: ({point[0] * 1e3:.4f}, {point[1] * 1e3:.4f}, {point[2] * 1e3:.4f}) mm '
              f'from {len(views[name])} views, reprojection RMS {rms:.3f} px')
    report = {'features': located}
    if args.cad:
        report['part'] = _place_part(args, model, located)
    elif args.path or args.csv or args.gcode:
        raise InvalidInputError('--path, --csv and --gcode place a path on the part: they '
                                'need --cad (the features\' CAD positions)')
    write_json(args.json, report)
    return 0


def _located(model, views: dict, names: list) -> tuple[np.ndarray, list]:
    """The named points located from their views through the calibrated chain: (k, 3) m
    and the reprojection RMS of each (px)."""
    found = [locate(model, views[name][:, :5], views[name][:, 5:]) for name in names]
    return np.array([point for point, _ in found]), [rms for _, rms in found]


def _place_part(args, model, located) -> dict:
    """The part's pose from its located CAD features and, given ``--path``, the poses that
    put the needle tip on each path point, checked against the strokes."""
    names, cad = read_points(args.cad, 'a part\'s CAD features')
    missing = [n for n in names if n not in located]
    if missing or len(names) < 3:
        raise InvalidInputError(f'{args.cad}: the part\'s pose needs at least 3 features '
                                f'located; {", ".join(missing) or "fewer than 3"} not in '
                                f'{args.data}')
    rotation, translation, misfit = fit_part_pose(
        cad, np.array([located[n]['position_m'] for n in names]))
    part = {'pose': {'translation_m': translation.tolist(),
                     'rotation_vector_rad': cv2.Rodrigues(rotation)[0].ravel().tolist()},
            'cad_misfit_rms_m': misfit}
    print(f'part at {", ".join(f"{v * 1e3:.4f}" for v in translation)} mm, rotation vector '
          f'{", ".join(f"{v:.5f}" for v in part["pose"]["rotation_vector_rad"])} rad; CAD '
          f'misfit {misfit * 1e6:.2f} um RMS')
    if not args.path:
        if args.csv or args.gcode:
            raise InvalidInputError('--csv and --gcode write the path poses: give --path')
        return part
    if args.tip is None:
        raise InvalidInputError('--path needs --tip X Y Z: the needle tip in the calibrated '
                                'camera frame (m), as five_axis_calibrator/measure_needle gives it')
    points, path = read_points(args.path, 'a dispensing path')
    poses = place_path(model, np.array(args.tip),
                       path @ rotation.T + translation, *args.path_angles)
    for pose in poses:
        check_stroke(pose)
    part['path_poses'] = {name: pose.tolist() for name, pose in zip(points, poses)}
    print(f'{len(poses)} path poses, table at a {args.path_angles[0]:g}, c '
          f'{args.path_angles[1]:g} rad; all inside the strokes')
    if args.csv:
        write_path_poses(args.csv, points, poses)
        print(f'wrote {args.csv} (point, x_m, y_m, z_m, a_rad, c_rad)')
    if args.gcode:
        write_gcode_path(args.gcode, poses, 'XYZAC', args.machine_units, args.feed,
                         f'dispensing path of {Path(args.path).name}, {len(poses)} points')
        print(f'wrote {args.gcode} (RS274/NGC, {args.machine_units}, A and C in degrees)')
    return part


def cmd_needle(args) -> int:
    """The needle tip from test dots: views CSV of the dots (feature = the dot's name) and
    the poses each was dispensed at (path poses CSV)."""
    model = read_model(args.calibration)
    views = read_views(args.data)
    names, dispensed_at = read_path_poses(args.dispensed, 'the poses the dots were dispensed at')
    missing = [n for n in names if n not in views]
    if missing:
        raise InvalidInputError(f'{args.data} has no views of dot(s) {", ".join(missing)} '
                                f'dispensed in {args.dispensed}')
    dots, rms = _located(model, views, names)
    result = dict(tip_from_dots(model, dispensed_at, dots), dots_m=dots.tolist(),
                  reprojection_rms_px=rms)
    print(f'needle tip {", ".join(f"{v * 1e3:.4f}" for v in result["tip_m"])} mm (calibrated '
          f'camera frame) from {len(names)} dots; one dot alone within '
          f'{result["spread_m"] * 1e6:.1f} um')
    write_json(args.json, result)
    return 0
