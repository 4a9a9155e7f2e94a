"""The work of the subcommands ``evaluate.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

import json

import numpy as np

from calib_core.bags import decode_bag
from calib_core.errors import MachineAlignmentError
from calib_core.files import read_text
from dispenser_calib.core.calibration import reprojection
from dispenser_calib.core.description import read_description as read_five_axis_description
from dispenser_calib.core.model import nominal_model as dispenser_nominal
from dispenser_calib.core.model import read_model as read_dispenser_model
from dispenser_calib.core.procedure import SHIPPED_WORKSPACE, evaluation_stops
from dispenser_calib.sim.machine import observe
from grid_calib.core.reference_map import compare, read_reference
from hexapod_calib.core.calibration import PoseData, summarise_pose_errors
from hexapod_calib.core.description import read_description
from hexapod_calib.core.geometry import read_geometry
from hexapod_calib.core.kinematics import forward_kinematics
from machine_alignment.cli.common import print_pose_summary, write_json
from machine_alignment.cli.platform_run import read_targets
from platform_calib.core.compensation import mark_errors
from platform_calib.core.geometry import nominal_geometry as platform_nominal
from platform_calib.core.geometry import read_geometry as read_platform_geometry
from platform_calib.core.kinematics import forward, inverse
from platform_calib.core.planning import WORKING_SPAN
from printer_alignment.core.alignment import replay_alignment
from printer_alignment.core.records import ALIGNER_REPORT_TOPIC, STAGE_RESULT_TOPIC
from printer_alignment.core.stage import NOMINAL_STAGE
from printer_alignment.core.stage_calibration import ParametricModel, models_from_dict


def cmd_evaluate_hexapod(args) -> int:
    calibrated = read_geometry(args.geometry)
    nominal = read_geometry(args.nominal) if args.nominal else None
    description = read_description(args.description) if args.description else None
    data = PoseData.from_csv(args.data, nominal if nominal is not None else calibrated,
                             leg_m_per_unit=(description.measurement.actuators.m_per_unit
                                             if description else 1.0))
    predicted = forward_kinematics(calibrated, data.leg_lengths, initial=data.measured)
    report = {'data': str(args.data), 'geometry': str(args.geometry),
              'commanded_vs_measured': summarise_pose_errors(data.commanded, data.measured),
              'model_vs_measured': summarise_pose_errors(predicted, data.measured),
              'note': 'commanded_vs_measured: how far the machine was from the pose aimed at '
                      'with the leg lengths it was given; model_vs_measured: the pose the '
                      'geometry predicts for those leg lengths against the measured one, i.e. '
                      'the error left after compensating with this geometry (m, rad)'}
    print(f'{len(data)} poses')
    print_pose_summary('commanded vs measured:', report['commanded_vs_measured'])
    print_pose_summary('model vs measured:', report['model_vs_measured'])
    write_json(args.json, report)
    return 0


def _summary(errors: np.ndarray, unit: str) -> dict:
    """RMS, median and max of ``errors`` (any shape), keys suffixed with ``unit``."""
    return {f'rms_{unit}': float(np.sqrt(np.mean(np.square(errors)))),
            f'median_{unit}': float(np.median(errors)), f'max_{unit}': float(np.max(errors))}


def cmd_evaluate_platform(args) -> int:
    """Register at working poses with the nominal and with the identified geometry, on the
    true platform (a simulation's truth file), and measure where the marks land."""
    identified = read_platform_geometry(args.geometry)
    truth = read_platform_geometry(args.truth)
    nominal = read_platform_geometry(args.nominal) if args.nominal else platform_nominal()
    working = (read_targets(args.working) if args.working else
               np.random.default_rng(args.seed).uniform(-1, 1, (args.count, 3))
               * np.asarray(WORKING_SPAN))
    report = {'geometry': str(args.geometry), 'truth': str(args.truth), 'poses': len(working),
              'note': 'each mark\'s position error at the working poses when the feeds come '
                      'from the geometry\'s inverse kinematics and the platform is the truth '
                      '(m); measured against the truth, not the model\'s own prediction'}
    for name, model in (('nominal', nominal), ('identified', identified)):
        reached = forward(truth, inverse(model, working), working)
        report[name] = _summary(mark_errors(reached, working), 'm')
    n, c = report['nominal'], report['identified']
    print(f'{len(working)} working poses on the true platform, each mark\'s error: nominal '
          f'geometry RMS {n["rms_m"] * 1e6:.1f} um (max {n["max_m"] * 1e6:.1f} um); identified '
          f'RMS {c["rms_m"] * 1e6:.2f} um (max {c["max_m"] * 1e6:.2f} um)')
    write_json(args.json, report)
    return 0


def cmd_evaluate_five_axis(args) -> int:
    """The board imaged by the true machine (noise-free) at stops with A and C both turned,
    none of them a calibration stop, against what the nominal and the calibrated model
    predict there; with a description, the described machine's nominal, camera and
    strokes."""
    described = read_five_axis_description(args.description) if args.description else None
    nominal = described.nominal() if described else dispenser_nominal()
    calibrated = read_dispenser_model(args.calibration)
    truth = read_dispenser_model(args.truth)
    workspace = described.workspace() if described else SHIPPED_WORKSPACE
    stops = evaluation_stops(nominal, args.count, args.seed + 1000, workspace)
    images, _ = observe(truth, stops, noise_px=0.0, seed=args.seed, workspace=workspace,
                        **({'image_size': described.image_size} if described else {}))
    report = {'calibration': str(args.calibration), 'truth': str(args.truth),
              'images': len(images),
              'note': 'reprojection of the dots imaged by the true machine, without noise, '
                      'at stops with A and C turned (not calibration stops), px'}
    for name, model in (('nominal', nominal), ('calibrated', calibrated)):
        report[name] = _summary(np.linalg.norm(np.concatenate(reprojection(model, images)),
                                               axis=1), 'px')
    n, c = report['nominal'], report['calibrated']
    print(f'{len(images)} stops imaged by the true machine: nominal model RMS {n["rms_px"]:.1f} '
          f'px (max {n["max_px"]:.1f}); calibrated RMS {c["rms_px"]:.4f} px (max '
          f'{c["max_px"]:.4f})')
    write_json(args.json, report)
    return 0


def cmd_evaluate_alignment(args) -> int:
    """Plan each alignment recorded by the aligner again, from its recorded Mark
    measurements and the stage calibration it used, and compare the chain inputs."""
    models = {'nominal': ParametricModel(NOMINAL_STAGE)}
    alignments = []
    for topic, _, msg in decode_bag(args.bag):
        if topic == STAGE_RESULT_TOPIC and msg.success:
            models.update(models_from_dict(json.loads(msg.report_json)['models']))
        elif topic == ALIGNER_REPORT_TOPIC:
            report = json.loads(msg.data)
            if report.get('model') not in models:
                raise MachineAlignmentError(
                    f'{args.bag}: an alignment used the {report.get("model")!r} model but the '
                    'bag holds no stage calibration with it')
            alignments.append(replay_alignment(report, models[report['model']]))
    if not alignments:
        raise MachineAlignmentError(f'{args.bag} holds no alignment report on {ALIGNER_REPORT_TOPIC}')
    for a in alignments:
        v = a['verification'] or {}
        print(f'{a["model"]:>10}: inputs ' + ', '.join(f'{q * 1e3:+.4f}' for q in a['q_replayed_m'])
              + f' mm, |replayed - recorded| {a["max_difference_m"] * 1e9:.3g} nm; left after '
              f'the move (camera) {v.get("position_error_m", np.nan) * 1e6:.2f} um, '
              f'{np.rad2deg(v.get("orientation_error_rad", np.nan)) * 3600:.2f} arcsec')
    write_json(args.json, {'bag': str(args.bag), 'alignments': alignments,
                            'max_difference_m': max(a['max_difference_m'] for a in alignments)})
    return 0


def cmd_evaluate_grid(args) -> int:
    """The stage error map of ``calibrate grid --json`` against a reference map (an
    interferometer's, a certified plate's, or ``simulate grid --truth``), in one gauge."""
    text = read_text(args.report, 'the JSON report of calibrate grid')
    try:
        report = json.loads(text)
        sites = report['sites']
        positions = np.array([[s['x'], s['y']] for s in sites], float)
        errors = np.array([[s['error_x'], s['error_y']] for s in sites], float)
        sigmas = (np.array([[s['sigma_x'], s['sigma_y']] for s in sites], float)
                  if sites and 'sigma_x' in sites[0] else None)
    except (ValueError, KeyError, TypeError) as exc:
        raise MachineAlignmentError(f'{args.report} is not the JSON report of calibrate grid '
                                    f'({exc.__class__.__name__}: {exc})') from None
    if sigmas is not None and not np.all(np.isfinite(sigmas)):
        sigmas = None
    pitch = float(np.min(np.diff(np.unique(np.round(positions[:, 0], 12))))) \
        if len(np.unique(positions[:, 0])) > 1 else 1.0
    reference_positions, reference_errors = read_reference(args.reference)
    result = compare(positions, errors, sigmas, reference_positions, reference_errors, pitch,
                     keep_scale=report.get('isotropic_scale') is not None)
    result.update(report=str(args.report), reference=str(args.reference))
    before, after = result['stage_error_m'], result['map_minus_reference_m']
    print(f'{result["sites_compared"]} sites compared ({result["gauge"]}): the stage error '
          f'itself RMS {before["rms"] * 1e9:.1f} nm (max {before["max"] * 1e9:.1f} nm); the '
          f'map against the reference RMS {after["rms"] * 1e9:.2f} nm (max '
          f'{after["max"] * 1e9:.2f} nm)')
    if 'in_sigma' in result:
        print(f'  in the map\'s stated sigma: RMS {result["in_sigma"]["rms"]:.2f}, '
              f'{result["in_sigma"]["within_2_sigma"]:.0%} within 2 sigma (1 and 95 % when the '
              f'uncertainty is right and the reference exact)')
    write_json(args.json, result)
    return 0
