"""The work of the subcommands ``camera.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

import numpy as np

from calib_core.errors import MachineAlignmentError
from machine_alignment.cli.common import parse_size, quantity, read_run, unit_hint, write_json
from printer_alignment.core.camera_calibration import (
    calibrate_intrinsics, camera_arrays, distortion_from_dot_views, infer_image_size,
    read_boofcv_intrinsics, read_correspondences, reprojection_errors, rms_px,
    suspect_views, views_from_images)
from printer_alignment.core.dot_markers import LlahIndex, load_uchiya_markers, read_marker_photos
from printer_alignment.core.records import INTRINSICS_RESULT_TOPIC, VISION_OBSERVATIONS_TOPIC
from printer_alignment.core.vision_procedure import observation_from_message


def cmd_calibrate_camera(args) -> int:
    if args.bag:
        return _calibrate_camera_from_bag(args)
    failures, photos = [], None
    if args.data:
        with unit_hint(args):
            views = read_correspondences(args.data, args.length_unit)
        size = parse_size(args.image_size) if args.image_size else infer_image_size(views)
    elif args.target == 'uchiya':
        if not args.markers:
            raise MachineAlignmentError('--target uchiya needs --markers (descriptions.yaml)')
        views, size, failures, photos = _views_from_marker_photos(args.images, args.markers)
    else:
        if not (args.cols and args.rows and args.spacing):
            raise MachineAlignmentError('--images needs --target, --cols, --rows and --spacing')
        views, size, failures = views_from_images(args.images, args.target, args.cols,
                                                  args.rows, args.spacing)
    for path, reason in failures:
        print(f'{path}: {reason}')
    if args.image_size:
        size = parse_size(args.image_size)
    options = {'distortion': not args.no_distortion, 'radial_only': args.radial_only}
    result = calibrate_intrinsics(views, size, **options)
    report = result.report()
    report['failed_images'] = [{'image': p, 'reason': r} for p, r in failures]
    if photos is not None:
        report['photos'] = [photo.summary() for photo in photos]
    p, s = report['parameters'], report['std_devs']
    print(f'{report["num_views"]} views, reprojection RMS {report["rms_reprojection_px"]:.3f} px')
    for name in p:
        print(f'  {name:>3} = {quantity(p[name], s[name], report["units"][name])}')
    _suspect_views(views, size, options, result, report)
    if args.reference:
        report['reference'] = _compare_with_reference(args.reference, views, report)
    write_json(args.json, report)
    return 0


def _suspect_views(views, size, options, result, report) -> None:
    """Views that reproject far worse than the others (suspect_views: mis-detected or
    mis-ordered points) named, and the calibration without them beside, in the report
    (``suspect_views``, ``without_suspect_views``): one such view had moved fx by 2.4 %."""
    suspects = suspect_views(result.per_view_rms_px)
    if not suspects.size:
        return
    median = float(np.median(result.per_view_rms_px))
    named = [{'view': views[i].label or str(i), 'rms_px': float(result.per_view_rms_px[i])}
             for i in suspects]
    report['suspect_views'] = named
    for view in named:
        print(f'WARNING: view {view["view"]} reprojects at {view["rms_px"]:.3g} px against a '
              f'median of {median:.3g} px over the views: mis-detected or mis-ordered points?')
    kept = [v for i, v in enumerate(views) if i not in suspects]
    if len(kept) < 3:
        return
    without = calibrate_intrinsics(kept, size, **options).report()
    report['without_suspect_views'] = {key: without[key] for key in (
        'parameters', 'std_devs', 'rms_reprojection_px', 'num_views')}
    p, s = without['parameters'], without['std_devs']
    print(f'without {"them" if len(named) > 1 else "it"}: {without["num_views"]} views, '
          f'reprojection RMS {without["rms_reprojection_px"]:.3f} px; '
          + ', '.join(f'{name} {quantity(p[name], s[name], without["units"][name])}'
                      for name in p)
          + '; leave the view out of the data and calibrate again')


def _views_from_marker_photos(images, markers_path):
    """Views of random-dot markers, one per marker matched in each photo."""
    photos, size, failures = read_marker_photos(images, LlahIndex(load_uchiya_markers(markers_path)))
    for photo in photos:
        found = ', '.join(f'{m.marker_id} ({len(m.marker_dots)} dots)' for m in photo.matches)
        print(f'{photo.path}: {len(photo.dots)} dots; markers {found or "none"}')
    return [v for photo in photos for v in photo.views()], size, failures, photos


def _compare_with_reference(path, views, report) -> dict:
    """Reference intrinsics (BoofCV YAML) against ours: parameter differences, and the
    reprojection RMS (px) of the same views with each after solving every view's pose."""
    reference = read_boofcv_intrinsics(path)
    ours = report['parameters']
    comparison = {
        'path': str(path), 'parameters': reference,
        'ours_minus_reference': {n: ours[n] - reference[n] for n in reference},
        'rms_px_with_reference': rms_px(reprojection_errors(*camera_arrays(reference), views)),
        'rms_px_with_ours': rms_px(reprojection_errors(*camera_arrays(ours), views))}
    print(f'reference {path}: reprojection RMS {comparison["rms_px_with_reference"]:.3f} px '
          f'(ours {comparison["rms_px_with_ours"]:.3f} px, poses solved per view)')
    for name, diff in comparison['ours_minus_reference'].items():
        print(f'  {name:>3}: ours - reference = {diff: .4g} (reference {reference[name]:.6g})')
    return comparison


def _calibrate_camera_from_bag(args) -> int:
    """Rerun a ``vision_calibrator/calibrate_intrinsics`` run from its bag."""
    dots, recorded = read_run(args.bag, VISION_OBSERVATIONS_TOPIC,
                              'alignment_msgs/msg/VisionObservation',
                              lambda m: observation_from_message(m).uv, 'dot-plate views',
                              INTRINSICS_RESULT_TOPIC)
    if recorded is None or 'setup' not in recorded:
        raise MachineAlignmentError(f'{args.bag} holds no intrinsics result with its setup '
                                    '(pitch, focal length, image size): not an intrinsics run?')
    report = distortion_from_dot_views(dots, recorded['setup']).report()
    report['setup'] = recorded['setup']
    p, s = report['parameters'], report['std_devs']
    print(f'{report["num_views"]} views, reprojection RMS {report["rms_reprojection_px"]:.4f} px')
    for name in p:
        why = f'   fixed: {report["fixed"][name]}' if name in report['fixed'] else ''
        print(f'  {name:>3} = {quantity(p[name], s[name], report["units"][name])}{why}')
    live = recorded['parameters']
    report['max_difference_to_live'] = max(abs(live[n] - v) for n, v in p.items())
    print(f'same as the live run: max |difference| {report["max_difference_to_live"]:.3g}')
    write_json(args.json, report)
    return 0
