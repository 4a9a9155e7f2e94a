"""machine-align: the command line of machine_alignment. It runs the same core code as
the nodes: subcommands read a dataset, image files or a recorded bag, print a human
report and write JSON (``--json PATH``, SI units)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from calib_core.errors import MachineAlignmentError
from calib_core.storage import write_atomic


def _progress(done: int, total: int, label: str) -> None:
    if not sys.stderr.isatty():
        return
    width = 30
    filled = int(width * done / max(total, 1))
    sys.stderr.write(f'\r{label} [{"#" * filled}{"." * (width - filled)}] {done}/{total}')
    if done == total:
        sys.stderr.write('\n')
    sys.stderr.flush()


def _write_json(path, content) -> None:
    if path:
        write_atomic(path, json.dumps(content, indent=2) + '\n')
        print(f'wrote {path}')


def cmd_detect(args) -> int:
    import cv2

    from printer_alignment.core.marks import DetectorConfig, detect_marks
    config = DetectorConfig(min_size_px=args.min_size, max_size_px=args.max_size,
                            polarity=args.polarity)
    results, failures = [], 0
    for k, path in enumerate(args.images):
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        entry = {'image': str(path)}
        if image is None:
            entry['error'] = 'not a readable image'
        else:
            try:
                detection = detect_marks(image, config, args.shape, args.expected)
                entry['marks'] = [{'shape': m.shape, 'u_px': m.u, 'v_px': m.v,
                                   'covariance_px2': m.covariance.tolist(), 'size_px': m.size,
                                   'contrast': m.contrast, 'quality': m.quality}
                                  for m in detection.marks]
                entry['rejected'] = detection.rejected
                entry['noise_sigma'] = detection.noise_sigma
            except MachineAlignmentError as exc:
                entry['error'] = str(exc)
        failures += 'error' in entry
        results.append(entry)
        _progress(k + 1, len(args.images), 'detect')
        if 'error' in entry:
            print(f'{path}: {entry["error"]}')
        else:
            sigma = np.median([np.sqrt(max(m['covariance_px2'][0][0], m['covariance_px2'][1][1]))
                               for m in entry['marks']])
            print(f'{path}: {len(entry["marks"])} Mark(s), median centre sigma {sigma:.4f} px')
    _write_json(args.json, {'images': results})
    return 1 if failures == len(args.images) else 0


def cmd_calibrate_camera(args) -> int:
    from printer_alignment.core.camera_calibration import (
        calibrate_intrinsics, infer_image_size, read_correspondences, views_from_images)
    if args.bag:
        return _calibrate_camera_from_bag(args)
    failures, photos = [], None
    if args.data:
        views = read_correspondences(args.data)
        size = _parse_size(args.image_size) if args.image_size else infer_image_size(views)
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
        size = _parse_size(args.image_size)
    result = calibrate_intrinsics(views, size, distortion=not args.no_distortion,
                                  radial_only=args.radial_only)
    report = result.report()
    report['failed_images'] = [{'image': p, 'reason': r} for p, r in failures]
    if photos is not None:
        report['photos'] = [photo.summary() for photo in photos]
    p, s = report['parameters'], report['std_devs']
    print(f'{report["num_views"]} views, reprojection RMS {report["rms_reprojection_px"]:.3f} px')
    for name in p:
        print(f'  {name:>3} = {p[name]: .6g} +- {s[name]:.2g} {report["units"][name]}')
    if args.reference:
        report['reference'] = _compare_with_reference(args.reference, views, report)
    _write_json(args.json, report)
    return 0


def _views_from_marker_photos(images, markers_path):
    """Views of random-dot markers, one per marker matched in each photo."""
    from printer_alignment.core.dot_markers import LlahIndex, load_uchiya_markers, read_marker_photos
    photos, size, failures = read_marker_photos(images, LlahIndex(load_uchiya_markers(markers_path)))
    for photo in photos:
        found = ', '.join(f'{m.marker_id} ({len(m.marker_dots)} dots)' for m in photo.matches)
        print(f'{photo.path}: {len(photo.dots)} dots; markers {found or "none"}')
    return [v for photo in photos for v in photo.views()], size, failures, photos


def _compare_with_reference(path, views, report) -> dict:
    """Reference intrinsics (BoofCV YAML) against ours: parameter differences, and the
    reprojection RMS (px) of the same views with each after solving every view's pose."""
    from printer_alignment.core.camera_calibration import (
        camera_arrays, read_boofcv_intrinsics, reprojection_errors, rms_px)
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
    from printer_alignment.core.camera_calibration import distortion_from_dot_views
    from printer_alignment.core.vision_procedure import observation_from_message
    dots, recorded = _read_run(args.bag, '/observations', lambda m: observation_from_message(m).uv,
                               'dot-plate views', result_suffix='/intrinsics')
    if recorded is None or 'setup' not in recorded:
        raise MachineAlignmentError(f'{args.bag} holds no intrinsics result with its setup '
                                    '(pitch, focal length, image size): not an intrinsics run?')
    report = distortion_from_dot_views(dots, recorded['setup']).report()
    report['setup'] = recorded['setup']
    p, s = report['parameters'], report['std_devs']
    print(f'{report["num_views"]} views, reprojection RMS {report["rms_reprojection_px"]:.4f} px')
    for name in p:
        why = f'   fixed: {report["fixed"][name]}' if name in report['fixed'] else ''
        print(f'  {name:>3} = {p[name]: .6g} +- {s[name]:.2g} {report["units"][name]}{why}')
    live = recorded['parameters']
    report['max_difference_to_live'] = max(abs(live[n] - v) for n, v in p.items())
    print(f'same as the live run: max |difference| {report["max_difference_to_live"]:.3g}')
    _write_json(args.json, report)
    return 0


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split('x'))
    except ValueError:
        raise MachineAlignmentError(f'--image-size must look like 640x480, not {text!r}') from None
    return w, h


def _read_run(bag, stop_suffix: str, convert, what: str,
              result_suffix: str = '/result') -> tuple[list, dict | None]:
    """The stops of a calibrator's recorded run (messages on the topic ending in
    ``stop_suffix``, each passed through ``convert``) and the report of its successful
    result (topic ending in ``result_suffix``), None if the run ended without one."""
    from calib_core.bags import decode_bag
    stops, recorded = [], None
    for topic, _, msg in decode_bag(bag):
        if topic.endswith(stop_suffix):
            stops.append(convert(msg))
        elif topic.endswith(result_suffix) and msg.success:
            recorded = json.loads(msg.report_json)
    if not stops:
        raise MachineAlignmentError(f'{bag} holds no {what}')
    return stops, recorded


def cmd_calibrate_vision(args) -> int:
    from printer_alignment.core.vision_procedure import (
        calibrate_from_observations, observation_from_message)
    observations, recorded = _read_run(args.bag, '/observations', observation_from_message,
                                       'vision calibration observations')
    calibration = calibrate_from_observations(observations, args.pitch)
    report = dict(calibration.report)
    g = report['gantry']
    print(f'{len(observations)} positions; pixel size '
          f'{report["pixel_size"]["pixel_size_m"] * 1e6:.5f} um')
    for name, value in g['parameters'].items():
        print(f'  {name:>17} = {value: .9g} +- {g["std_devs"][name]:.2g} {g["units"][name]}')
    if recorded is not None:
        live = recorded['gantry']['parameters']
        report['max_difference_to_live'] = {n: abs(live[n] - v) for n, v in g['parameters'].items()}
        print('same as the live run: max |difference| '
              f'{max(report["max_difference_to_live"].values()):.3g} (SI units)')
    _write_json(args.json, report)
    return 0


def cmd_calibrate_stage(args) -> int:
    """Rerun both stage calibrations from a run recorded by stage_calibrator (--bag) or a
    stage CSV (--data)."""
    from printer_alignment.core.stage_calibration import (
        StageData, calibrate_stage, models_as_dict)
    from printer_alignment.core.records import stage_data_from_records, stage_record
    recorded = None
    if args.bag:
        records, recorded = _read_run(args.bag, '/observations', stage_record,
                                      'stage calibration observations')
        data = stage_data_from_records(records)
    else:
        data = StageData.from_csv(args.data)
    models, report = calibrate_stage(data)
    s, p = report['stepwise'], report['parametric']
    print(f'{len(data)} stops. Stepwise: R1..R3 {s["R1"] * 1e3:.5f}, {s["R2"] * 1e3:.5f}, '
          f'{s["R3"] * 1e3:.5f} mm/rev, alpha1 {np.rad2deg(s["alpha1"]):.4f} deg, '
          f'd3 - d2 {s["d3_minus_d2"] * 1e3:.3f} mm')
    print(f'Parametric: Mark residual RMS {p["residual_rms_m"] * 1e6:.2f} um, max '
          f'{p["residual_max_m"] * 1e6:.2f} um, condition number {p["condition_number"]:.3g}')
    for name in p['parameters']:
        if name not in p['fixed']:
            print(f'  {name:>16} = {p["parameters"][name]: .9g} +- {p["std_devs"][name]:.2g} '
                  f'{p["units"][name]}')
    for name, why in p['weakly_determined'].items():
        print(f'  weakly determined: {name}: {why}')
    report['models'] = models_as_dict(models)
    if recorded is not None:
        live = recorded['parametric']['parameters']
        report['max_difference_to_live'] = max(abs(live[n] - v) for n, v in p['parameters'].items())
        # In units of each parameter's sigma: another numpy/scipy build ends the solver a
        # hair away along the weakly determined directions, which is no difference at all.
        report['max_difference_to_live_sigma'] = max(
            (abs(live[n] - v) / p['std_devs'][n] for n, v in p['parameters'].items()
             if n not in p['fixed'] and p['std_devs'][n] > 0), default=0.0)
        print(f'same as the live run: max |difference| {report["max_difference_to_live"]:.3g} '
              f'(SI units), {report["max_difference_to_live_sigma"]:.2g} sigma')
    _write_json(args.json, report)
    return 0


def _print_pose_summary(label: str, summary: dict) -> None:
    print(f'  {label:<28} max {summary["max_displacement_m"] * 1e6:8.2f} um '
          f'{summary["max_angle_rad"] * 1e6:8.1f} urad   RMS '
          f'{summary["rms_displacement_m"] * 1e6:8.2f} um {summary["rms_angle_rad"] * 1e6:8.1f} urad')


def cmd_calibrate_hexapod(args) -> int:
    from hexapod_calib.core.calibration import PoseData, identify, summarise_pose_errors
    from hexapod_calib.core.geometry import read_geometry
    if args.bag:
        return _calibrate_hexapod_from_bag(args)
    if not args.geometry:
        raise MachineAlignmentError('--data needs --geometry NOMINAL.yaml')
    nominal = read_geometry(args.geometry)
    data = PoseData.from_csv(args.data, nominal)
    identification = identify(data, nominal, fixed=args.fix or ())
    report = identification.report()
    report['data'] = str(args.data)
    report['commanded_vs_measured'] = summarise_pose_errors(data.commanded, data.measured)
    print(f'{len(data)} poses, 42 parameters ({len(args.fix or [])} fixed); leg-length residual '
          f'RMS {report["residual_rms_m"] * 1e6:.3f} um, max {report["residual_max_m"] * 1e6:.3f} um, '
          f'condition number {report["condition_number"]:.3g}')
    _print_pose_summary('commanded vs measured:', report['commanded_vs_measured'])
    changes = report['change_from_initial']
    for name in sorted(changes, key=lambda n: -abs(changes[n]))[:6]:
        print(f'  {name:>12} changed {changes[name] * 1e6:+9.1f} um '
              f'(+- {report["std_devs"].get(name, 0.0) * 1e6:.1f} um)')
    _write_hexapod_outputs(args, identification.geometry, report)
    return 0


def _write_hexapod_outputs(args, geometry, report) -> None:
    from hexapod_calib.core.geometry import write_geometry
    if args.out:
        write_geometry(args.out, geometry, {'std_devs': report['std_devs'],
                                            'residual_rms_m': report['residual_rms_m']})
        print(f'wrote {args.out}')
    _write_json(args.json, report)


def _calibrate_hexapod_from_bag(args) -> int:
    """Rerun the identification of a run recorded by hexapod_calibrator."""
    from hexapod_calib.core.geometry import HexapodGeometry, read_geometry
    from hexapod_calib.core.procedure import identify_from_records
    from hexapod_calib.core.records import MEASUREMENTS_TOPIC, measurement_record
    records, recorded = _read_run(args.bag, MEASUREMENTS_TOPIC, measurement_record,
                                  'hexapod calibration measurements')
    if args.geometry:
        nominal = read_geometry(args.geometry)
    elif recorded is not None:
        nominal = HexapodGeometry.from_dict(recorded['nominal_geometry'], 'recorded nominal')
    else:
        raise MachineAlignmentError(f'{args.bag} has no result (interrupted run?): give the '
                                    'nominal geometry with --geometry')
    identification, history = identify_from_records(records, nominal)
    report = {**identification.report(), 'iterations': history}
    print(f'{len(records)} recorded stops, {identification.num_poses} used for identification '
          f'in {len(history)} round(s); leg-length residual RMS '
          f'{report["residual_rms_m"] * 1e6:.3f} um')
    if recorded is not None:
        live = recorded['identification']['parameters']
        report['max_difference_to_live_m'] = max(abs(live[n] - v)
                                                  for n, v in report['parameters'].items())
        print(f'same as the live run: max |difference| {report["max_difference_to_live_m"]:.3g} m')
    _write_hexapod_outputs(args, identification.geometry, report)
    return 0


def cmd_evaluate_hexapod(args) -> int:
    from hexapod_calib.core.calibration import PoseData, summarise_pose_errors
    from hexapod_calib.core.geometry import read_geometry
    from hexapod_calib.core.kinematics import forward_kinematics
    calibrated = read_geometry(args.geometry)
    nominal = read_geometry(args.nominal) if args.nominal else None
    data = PoseData.from_csv(args.data, nominal if nominal is not None else calibrated)
    predicted = forward_kinematics(calibrated, data.leg_lengths, initial=data.measured)
    report = {'data': str(args.data), 'geometry': str(args.geometry),
              'commanded_vs_measured': summarise_pose_errors(data.commanded, data.measured),
              'model_vs_measured': summarise_pose_errors(predicted, data.measured),
              'note': 'commanded_vs_measured: how far the machine was from the pose aimed at '
                      'with the leg lengths it was given; model_vs_measured: the pose the '
                      'geometry predicts for those leg lengths against the measured one, i.e. '
                      'the error left after compensating with this geometry (m, rad)'}
    print(f'{len(data)} poses')
    _print_pose_summary('commanded vs measured:', report['commanded_vs_measured'])
    _print_pose_summary('model vs measured:', report['model_vs_measured'])
    _write_json(args.json, report)
    return 0


def cmd_evaluate_alignment(args) -> int:
    """Plan each alignment recorded by the aligner again, from its recorded Mark
    measurements and the stage calibration it used, and compare the chain inputs."""
    from calib_core.bags import decode_bag
    from printer_alignment.core.alignment import replay_alignment
    from printer_alignment.core.stage_calibration import ParametricModel, models_from_dict
    from printer_alignment.core.records import ALIGNER_REPORT_TOPIC as REPORT_TOPIC, STAGE_RESULT_TOPIC
    from printer_alignment.core.stage import NOMINAL_STAGE
    models = {'nominal': ParametricModel(NOMINAL_STAGE)}
    alignments = []
    for topic, _, msg in decode_bag(args.bag):
        if topic == STAGE_RESULT_TOPIC and msg.success:
            models.update(models_from_dict(json.loads(msg.report_json)['models']))
        elif topic == REPORT_TOPIC:
            report = json.loads(msg.data)
            if report.get('model') not in models:
                raise MachineAlignmentError(
                    f'{args.bag}: an alignment used the {report.get("model")!r} model but the '
                    'bag holds no stage calibration with it')
            alignments.append(replay_alignment(report, models[report['model']]))
    if not alignments:
        raise MachineAlignmentError(f'{args.bag} holds no alignment report on {REPORT_TOPIC}')
    for a in alignments:
        v = a['verification'] or {}
        print(f'{a["model"]:>10}: inputs ' + ', '.join(f'{q * 1e3:+.4f}' for q in a['q_replayed_m'])
              + f' mm, |replayed - recorded| {a["max_difference_m"] * 1e9:.3g} nm; left after '
              f'the move (camera) {v.get("position_error_m", np.nan) * 1e6:.2f} um, '
              f'{np.rad2deg(v.get("orientation_error_rad", np.nan)) * 3600:.2f} arcsec')
    _write_json(args.json, {'bag': str(args.bag), 'alignments': alignments,
                            'max_difference_m': max(a['max_difference_m'] for a in alignments)})
    return 0


def cmd_simulate_hexapod(args) -> int:
    from hexapod_calib.core.geometry import nominal_geometry, write_geometry
    from hexapod_calib.core.kinematics import inverse_kinematics
    from hexapod_calib.core.procedure import HexapodPlan, measure_poses
    from hexapod_calib.sim.hexapod import HexapodSim, HexapodTruth, PoseSensorSim
    out = Path(args.out)
    nominal = nominal_geometry()
    sim = HexapodSim(HexapodTruth.default(nominal, args.seed), nominal, seed=args.seed + 1)
    sensor = PoseSensorSim(seed=args.seed + 2)
    targets, evaluation = HexapodPlan(num_poses=args.poses, num_evaluation=args.evaluation,
                                      num_candidates=max(400, 2 * (args.poses + args.evaluation)),
                                      seed=args.seed).poses(nominal)
    for name, poses in (('calibration', targets), ('evaluation', evaluation)):
        data = measure_poses(poses, inverse_kinematics(nominal, poses), sim.move_legs,
                             lambda: sensor.measure(sim.pose), name,
                             progress=lambda step, total, _: _progress(step, total, name))
        data.to_csv(out / f'{name}.csv')
    write_geometry(out / 'nominal.yaml', nominal)
    write_geometry(out / 'truth.yaml', sim.truth.geometry,
                   {'note': 'simulation truth, for checking a calibration only'})
    print(f'wrote {out}/nominal.yaml, calibration.csv ({len(targets)} poses), '
          f'evaluation.csv ({len(evaluation)} poses), truth.yaml')
    return 0


def _loop_machine(args, dropped: dict):
    """The closed loop's model of ``args.machine`` over ``args.data``."""
    if args.machine == 'axis':
        from calib_core.axis import AxisData, AxisModel
        return AxisModel(AxisData.from_csv(args.data, dropped))
    if args.machine == 'gantry':
        from printer_alignment.core.loop_models import GantryData, GantryLoopModel
        return GantryLoopModel(GantryData.from_csv(args.data, dropped))
    if args.machine == 'camera':
        from printer_alignment.core.camera_calibration import read_correspondences
        from printer_alignment.core.loop_models import CameraLoopModel
        size = _parse_size(args.image_size) if args.image_size else None
        return CameraLoopModel(read_correspondences(args.data), size)
    if args.machine == 'stage':
        from printer_alignment.core.stage_calibration import StageData
        from printer_alignment.core.stage_loop import StageLoopModel
        return StageLoopModel(StageData.from_csv(args.data, dropped))
    from hexapod_calib.core.calibration import PoseData
    from hexapod_calib.core.geometry import read_geometry
    from hexapod_calib.core.loop_model import HexapodLoopModel
    nominal = read_geometry(args.geometry)
    data = PoseData.from_csv(args.data, nominal, dropped)
    forces = None
    if args.payload:
        from hexapod_calib.core.statics import leg_forces
        mass, *centre = args.payload
        forces = leg_forces(nominal, data.commanded, mass, centre)
    return HexapodLoopModel(data, nominal, forces)


def _axis_figures(machine, result, report: dict, json_path) -> None:
    """ISO 230-2 figures before and after, into the report and printed; the
    compensation table beside the JSON."""
    from calib_core.axis import iso230_2_before_after, write_compensation_table
    from calib_core.iso230_2 import format_figures
    iso = iso230_2_before_after(machine, result.fit)
    table = iso.pop('compensation_table')
    report['iso230_2'] = iso
    for label, key in (('as measured', 'before'), ('after linear compensation', 'after_linear'),
                       ('after the extended model', 'after')):
        print('\n'.join(format_figures(label, iso[key])))
    print(f'  compensated figures: {iso["method"]}')
    if json_path:
        path = Path(json_path).with_name(Path(json_path).stem + '_compensation.csv')
        write_compensation_table(path, table)
        report['compensation_table'] = str(path)
        print(f'wrote {path} (position, correction_up, correction_down in m; '
              f'{len(table)} rows, reference state: mean time and temperature, first block)')


def cmd_analyze(args) -> int:
    from calib_core.closed_loop import LoopConfig, analyze, format_report
    from calib_core.loop_plots import plot_loop
    dropped = {}
    machine = _loop_machine(args, dropped)
    config = LoopConfig(holdout_fraction=args.holdout, alpha=args.alpha, seed=args.seed,
                        max_effects=args.max_effects, splits=args.splits,
                        min_effect=args.min_effect)
    result = analyze(machine, config, progress=_progress)
    report = dict(result.report, data=str(args.data), dropped_columns=dropped)
    print(format_report(report))
    for name, reason in dropped.items():
        print(f'  column {name}: {reason}')
    if args.machine == 'axis':
        _axis_figures(machine, result, report, args.json)
    if args.json:
        _write_json(args.json, report)
        plot = Path(args.json).with_suffix('.png')
        plot_loop(plot, machine, result)
        print(f'wrote {plot}')
    return 0


def cmd_simulate_axis(args) -> int:
    from printer_alignment.sim.axis import AxisTest, AxisTruth, simulate_axis_test
    truth = AxisTruth(backlash=args.backlash, periodic_amplitude=args.periodic,
                      pitch=args.pitch, expansion=args.expansion,
                      temperature_rise=args.temperature_rise)
    data = simulate_axis_test(truth, AxisTest(travel=args.travel, targets=args.targets,
                                              cycles=args.cycles), seed=args.seed)
    data.to_csv(args.out)
    print(f'wrote {args.out} ({len(data)} rows)')
    return 0


def cmd_simulate_stage(args) -> int:
    from printer_alignment.sim.stage import TRUE_STAGE, simulate_calibration_run
    truth = TRUE_STAGE.with_changes(backlash=(0.0, 0.0, 0.0)) if args.no_backlash else TRUE_STAGE
    data = simulate_calibration_run(truth, seed=args.seed)
    data.to_csv(args.out)
    print(f'wrote {args.out} ({len(data)} stops)')
    return 0


def cmd_launch(args) -> int:
    import time

    from calib_core.launcher import Graph, hexapod_graph, printer_graph, stage_graph
    spec = {'printer': lambda: printer_graph(args.scene, args.output_dir, args.record_dir),
            'stage': lambda: stage_graph(args.output_dir, args.record_dir),
            'hexapod': lambda: hexapod_graph(args.output_dir, args.record_dir)}[args.graph]()
    with Graph(spec) as graph:
        print(f'{args.graph} graph running (Ctrl-C to stop)')
        try:
            while all(graph.alive()):
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
    return 0


def cmd_demo(args) -> int:
    from calib_core.demo import run_demo
    return run_demo(Path(args.out))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='machine-align', description=__doc__)
    sub = parser.add_subparsers(dest='command', required=True)

    detect = sub.add_parser('detect', help='Mark centres (px) in image files')
    detect.add_argument('images', nargs='+')
    detect.add_argument('--json')
    detect.add_argument('--shape', default='', choices=['', 'circle', 'cross'])
    detect.add_argument('--expected', type=int, default=0)
    detect.add_argument('--polarity', default='auto', choices=['auto', 'dark', 'bright'])
    detect.add_argument('--min-size', type=float, default=2.5, help='px')
    detect.add_argument('--max-size', type=float, default=120.0, help='px')
    detect.set_defaults(func=cmd_detect)

    calibrate = sub.add_parser('calibrate', help='run a calibration offline')
    what = calibrate.add_subparsers(dest='what', required=True)
    camera = what.add_parser('camera', help='intrinsics and distortion (OpenCV)')
    source = camera.add_mutually_exclusive_group(required=True)
    source.add_argument('--data', help='CSV: view, model_x, model_y (m), u, v (px)')
    source.add_argument('--images', nargs='+', help='photos of a calibration target')
    source.add_argument('--bag', help='a vision_calibrator/calibrate_intrinsics run to rerun')
    camera.add_argument('--target', default='chessboard',
                        choices=['chessboard', 'circles', 'acircles', 'uchiya'],
                        help='uchiya: random-dot markers, matched by LLAH (needs --markers)')
    camera.add_argument('--markers', help='BoofCV descriptions.yaml of the random-dot markers')
    camera.add_argument('--cols', type=int, help='inner corners / circles per row')
    camera.add_argument('--rows', type=int)
    camera.add_argument('--spacing', type=float, help='square size or circle pitch, m')
    camera.add_argument('--image-size', help='WxH in px (default: from images or inferred)')
    camera.add_argument('--no-distortion', action='store_true')
    camera.add_argument('--radial-only', action='store_true', help='k1, k2; no p1, p2, k3')
    camera.add_argument('--reference', help='intrinsics to compare with (BoofCV intrinsic.yaml)')
    camera.add_argument('--json')
    camera.set_defaults(func=cmd_calibrate_camera)
    vision = what.add_parser('vision', help='pixel size and gantry model from a recorded run')
    vision.add_argument('--bag', required=True)
    vision.add_argument('--pitch', type=float, default=0.5e-3, help='dot pitch, m')
    vision.add_argument('--json')
    vision.set_defaults(func=cmd_calibrate_vision)

    stage = what.add_parser('stage', help='XY-Theta stage: stepwise and parametric, from a '
                                          'recorded run or a stage CSV')
    stage_source = stage.add_mutually_exclusive_group(required=True)
    stage_source.add_argument('--bag', help='a run recorded by stage_calibrator')
    stage_source.add_argument('--data', help='CSV: q1..q3 (m), direction1..3, mark1_x, '
                                             'mark1_y, mark2_x, mark2_y (m)')
    stage.add_argument('--json')
    stage.set_defaults(func=cmd_calibrate_stage)

    hexapod = what.add_parser('hexapod', help='42-parameter hexapod geometry from measured poses')
    hexapod_source = hexapod.add_mutually_exclusive_group(required=True)
    hexapod_source.add_argument('--data', help='CSV: x..yaw, meas_x..meas_yaw (m, rad), '
                                               'optional l1..l6 (m)')
    hexapod_source.add_argument('--bag', help='a run recorded by hexapod_calibrator')
    hexapod.add_argument('--geometry', help='nominal geometry YAML (with --bag: default the '
                                            'one the run recorded)')
    hexapod.add_argument('--out', help='calibrated geometry YAML to write')
    hexapod.add_argument('--fix', nargs='*', help='parameter names to keep at their nominal value')
    hexapod.add_argument('--json')
    hexapod.set_defaults(func=cmd_calibrate_hexapod)

    evaluate = sub.add_parser('evaluate', help='check a calibration on data not used to fit it')
    evaluated = evaluate.add_subparsers(dest='what', required=True)
    hexapod_eval = evaluated.add_parser('hexapod', help='pose errors of a geometry on a pose file')
    hexapod_eval.add_argument('--data', required=True, help='pose CSV (as for calibrate hexapod)')
    hexapod_eval.add_argument('--geometry', required=True, help='calibrated geometry YAML')
    hexapod_eval.add_argument('--nominal', help='geometry the controller used, when the CSV has '
                                                'no l1..l6 columns')
    hexapod_eval.add_argument('--json')
    hexapod_eval.set_defaults(func=cmd_evaluate_hexapod)
    alignment_eval = evaluated.add_parser(
        'alignment', help='plan recorded alignments again from their bag (aligner runs)')
    alignment_eval.add_argument('--bag', required=True, help='an alignment_<stamp> bag')
    alignment_eval.add_argument('--json')
    alignment_eval.set_defaults(func=cmd_evaluate_alignment)

    simulate = sub.add_parser('simulate', help='write datasets measured on a simulated machine')
    simulated = simulate.add_subparsers(dest='what', required=True)
    hexapod_sim = simulated.add_parser('hexapod', help='pose files from the simulated hexapod')
    hexapod_sim.add_argument('--out', required=True, help='directory')
    hexapod_sim.add_argument('--poses', type=int, default=30)
    hexapod_sim.add_argument('--evaluation', type=int, default=30)
    hexapod_sim.add_argument('--seed', type=int, default=2)
    hexapod_sim.set_defaults(func=cmd_simulate_hexapod)

    stage_sim = simulated.add_parser('stage', help='a calibration run of the simulated '
                                                    'XY-Theta stage (stage CSV)')
    stage_sim.add_argument('--out', required=True, help='CSV to write')
    stage_sim.add_argument('--no-backlash', action='store_true',
                           help='a stage without backlash (clean data for the closed loop)')
    stage_sim.add_argument('--seed', type=int, default=0)
    stage_sim.set_defaults(func=cmd_simulate_stage)

    axis_sim = simulated.add_parser('axis', help='an ISO 230-2 laser-interferometer test of '
                                                  'a simulated axis')
    axis_sim.add_argument('--out', required=True, help='CSV to write')
    axis_sim.add_argument('--backlash', type=float, default=0.0, help='m')
    axis_sim.add_argument('--periodic', type=float, default=0.0, help='amplitude, m')
    axis_sim.add_argument('--pitch', type=float, default=0.016, help='period, m')
    axis_sim.add_argument('--expansion', type=float, default=0.0, help='1/K')
    axis_sim.add_argument('--temperature-rise', type=float, default=0.0, help='K over the test')
    axis_sim.add_argument('--travel', type=float, default=0.2, help='m')
    axis_sim.add_argument('--targets', type=int, default=41)
    axis_sim.add_argument('--cycles', type=int, default=5)
    axis_sim.add_argument('--seed', type=int, default=0)
    axis_sim.set_defaults(func=cmd_simulate_axis)

    analyze = sub.add_parser('analyze', help='closed loop: find the effect a model lacks, '
                                             'refit, report before/after on held-out data')
    machines = analyze.add_subparsers(dest='machine', required=True)
    formats = {'axis': 'CSV: command, measured (m), direction (+1/-1); optional cycle, '
                       'sequence (approach number), block/setup/run (labels), time (s), '
                       'temperature (K)',
               'gantry': 'CSV: command_x, command_y, measured_x, measured_y (m); optional '
                         'direction_x, direction_y, time, temperature',
               'camera': 'CSV: view, model_x, model_y (m), u, v (px)',
               'stage': 'CSV: q1..q3 (m), mark1_x, mark1_y, mark2_x, mark2_y (m, plate '
                        'frame); optional direction1..3, time, temperature',
               'hexapod': 'CSV: x..yaw, meas_x..meas_yaw (m, rad); optional l1..l6 (m), '
                          'force1..force6 (N, compression positive), direction1..direction6, '
                          'time, temperature'}
    for name, help_text in formats.items():
        machine = machines.add_parser(name, help=help_text)
        machine.add_argument('--data', required=True, help=help_text)
        machine.add_argument('--json', help='report to write; the plot goes beside it (.png)')
        machine.add_argument('--holdout', type=float, default=0.3,
                             help='fraction of rows kept out of every fit')
        machine.add_argument('--alpha', type=float, default=1e-3, help='significance level')
        machine.add_argument('--max-effects', type=int, default=4)
        machine.add_argument('--seed', type=int, default=0, help='of the first hold-out split')
        machine.add_argument('--splits', type=int, default=5,
                             help='hold-out splits the selection is repeated over')
        machine.add_argument('--min-effect', type=float, default=None,
                             help='smallest effect worth adding, RMS in the residual unit '
                                  '(m; px for the camera); default: the machine\'s')
        if name == 'camera':
            machine.add_argument('--image-size', help='WxH in px (default: inferred from the data)')
        if name == 'hexapod':
            machine.add_argument('--geometry', required=True, help='nominal geometry YAML')
            machine.add_argument('--payload', type=float, nargs=4,
                                 metavar=('MASS', 'X', 'Y', 'Z'),
                                 help='payload mass (kg) and centre of mass (m, platform '
                                      'frame): leg forces for leg_play and compliance')
        machine.set_defaults(func=cmd_analyze)

    launch = sub.add_parser('launch', help='start a simulated machine graph from the venv')
    launch.add_argument('graph', choices=['printer', 'stage', 'hexapod'])
    launch.add_argument('--scene', default='dot_plate', choices=['dot_plate', 'substrate', 'stencil'])
    launch.add_argument('--output-dir', default='calibration')
    launch.add_argument('--record-dir', default='runs')
    launch.set_defaults(func=cmd_launch)

    demo = sub.add_parser('demo', help='calibrate the simulated printer end to end')
    demo.add_argument('--out', default='out/demo')
    demo.set_defaults(func=cmd_demo)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except MachineAlignmentError as exc:
        print(f'machine-align: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
