"""The work of the subcommands ``calibrate.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

import numpy as np

from calib_core.errors import MachineAlignmentError
from hexapod_calib.core.calibration import (
    DETERMINED_SIGMAS, LEG_NAMES, PoseData, check_identification, identify, summarise_pose_errors,
    undetermined_beyond)
from hexapod_calib.core.description import likely_causes, read_description
from hexapod_calib.core.geometry import HexapodGeometry, read_geometry, write_geometry
from hexapod_calib.core.procedure import identify_from_records
from hexapod_calib.core.records import (
    HEXAPOD_RESULT_TOPIC, MEASUREMENTS_TOPIC, measurement_record)
from machine_alignment.cli.common import (
    print_pose_summary, quantity, read_in_si, read_run, write_report)
from printer_alignment.core.geometry import CameraToPlate, GantryModel
from printer_alignment.core.records import (
    STAGE_OBSERVATIONS_TOPIC, STAGE_RESULT_TOPIC, VISION_OBSERVATIONS_TOPIC, VISION_RESULT_TOPIC,
    stage_data_from_records, stage_record)
from printer_alignment.core.stage_calibration import (
    StageData, calibrate_stage, check_stage_calibration, models_as_dict)
from printer_alignment.core.stage_calibration.data import INPUT_COLUMNS
from printer_alignment.core.stage_description import likely_causes as stage_likely_causes
from printer_alignment.core.stage_description import read_description as read_stage_description
from printer_alignment.core.vision_description import (
    read_description as read_vision_description)
from printer_alignment.core.vision_procedure import (
    calibrate_from_observations, observation_from_message)


def cmd_calibrate_vision(args) -> int:
    observations, recorded = read_run(args.bag, VISION_OBSERVATIONS_TOPIC,
                                      'alignment_msgs/msg/VisionObservation',
                                      observation_from_message,
                                      'vision calibration observations', VISION_RESULT_TOPIC)
    described = read_vision_description(args.description) if args.description else None
    if described:
        camera, gantry, pitch = (described.nominal_camera(), described.nominal_gantry(),
                                 described.pitch)
    else:
        # Gated against the nominal lens and screws the live run recorded (a user's gantry
        # has its own leads), else the shipped gantry's.
        nominal = (recorded or {}).get('nominal', {})
        camera = (CameraToPlate(nominal['pixel_size_m']) if 'pixel_size_m' in nominal
                  else CameraToPlate())
        gantry = (GantryModel(*nominal['leads_m_per_rev']) if 'leads_m_per_rev' in nominal
                  else GantryModel())
        pitch = args.pitch if args.pitch is not None else (recorded or {}).get('pitch_m', 0.5e-3)
    calibration = calibrate_from_observations(observations, pitch, camera, gantry)
    report = dict(calibration.report, description=described.source if described else None)
    g = report['gantry']
    print(f'{len(observations)} positions; pixel size '
          f'{report["pixel_size"]["pixel_size_m"] * 1e6:.5f} um')
    for name, value in g['parameters'].items():
        print(f'  {name:>17} = {quantity(value, g["std_devs"][name], g["units"][name])}')
    if recorded is not None:
        live = recorded['gantry']['parameters']
        report['max_difference_to_live'] = {n: abs(live[n] - v) for n, v in g['parameters'].items()}
        print('same as the live run: max |difference| '
              f'{max(report["max_difference_to_live"].values()):.3g} (SI units)')
    write_report(args.json, report)
    return 0


def cmd_calibrate_stage(args) -> int:
    """Rerun both stage calibrations from a run recorded by stage_calibrator (--bag) or a
    stage CSV (--data); with --description, q1..q3 in its actuators' unit (a bag's are in
    m) and the gate from its noise."""
    recorded = None
    described = read_stage_description(args.description) if args.description else None
    if args.bag:
        records, recorded = read_run(args.bag, STAGE_OBSERVATIONS_TOPIC,
                                     'alignment_msgs/msg/StageObservation', stage_record,
                                     'stage calibration observations', STAGE_RESULT_TOPIC)
        data = stage_data_from_records(records)
        live_description = (recorded or {}).get('description', {}).get('file')
        if live_description and not described:
            print(f'the live run was calibrated with the stage description {live_description} '
                  '(its guides start the stepwise calibration, its noise sets the gate); this '
                  'replay with the shipped stage\'s: give --description to replay it as it ran')
    else:
        data = (described.read(args.data) if described
                else read_in_si(StageData.from_csv, args.data, actuators=INPUT_COLUMNS))
    models, report = calibrate_stage(data, *((described.d,) if described else ()))
    s, p = report['stepwise'], report['parametric']
    print(f'{len(data)} stops. Stepwise: R1..R3 {s["R1"] * 1e3:.5f}, {s["R2"] * 1e3:.5f}, '
          f'{s["R3"] * 1e3:.5f} mm/rev, alpha1 {s["alpha1"]:.6f} rad ({np.rad2deg(s["alpha1"]):.4f} deg), '
          f'd3 - d2 {s["d3_minus_d2"] * 1e3:.3f} mm')
    print(f'Parametric: Mark residual RMS {p["residual_rms_m"] * 1e6:.2f} um, max '
          f'{p["residual_max_m"] * 1e6:.2f} um, condition number {p["condition_number"]:.3g}')
    for name in p['parameters']:
        if name not in p['fixed']:
            print(f'  {name:>16} = '
                  f'{quantity(p["parameters"][name], p["std_devs"][name], p["units"][name])}')
    for name, why in p['weakly_determined'].items():
        print(f'  weakly determined: {name}: {why}')
    if described:
        report['description'] = described.gate_report()
        print(f'  machine description {described.source}: {described.expected_text()}')
        check_stage_calibration(report, described, stage_likely_causes(data, described))
    else:
        check_stage_calibration(report)
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
    write_report(args.json, report)
    return 0


def cmd_calibrate_hexapod(args) -> int:
    if args.bag:
        return _calibrate_hexapod_from_bag(args)
    if bool(args.geometry) == bool(args.description):
        raise MachineAlignmentError('--data needs --geometry NOMINAL.yaml or --description '
                                    'MACHINE.yaml (one of them)')
    description = read_description(args.description) if args.description else None
    nominal = description.geometry if description else read_geometry(args.geometry)
    data = read_in_si(PoseData.from_csv, args.data, nominal, actuators=LEG_NAMES,
                      leg_m_per_unit=(description.measurement.actuators.m_per_unit
                                      if description else 1.0))
    identification = identify(data, nominal, fixed=args.fix or ())
    report = identification.report()
    report['data'] = str(args.data)
    report['commanded_vs_measured'] = summarise_pose_errors(data.commanded, data.measured)
    print(f'{len(data)} poses, 42 parameters ({len(args.fix or [])} fixed); leg-length residual '
          f'RMS {report["residual_rms_m"] * 1e6:.3f} um, max {report["residual_max_m"] * 1e6:.3f} um, '
          f'condition number {report["condition_number"]:.3g}')
    print_pose_summary('commanded vs measured:', report['commanded_vs_measured'])
    changes = report['change_from_initial']
    for name in sorted(changes, key=lambda n: -abs(changes[n]))[:6]:
        print(f'  {name:>12} changed {changes[name] * 1e6:+9.1f} um '
              f'(+- {report["std_devs"].get(name, 0.0) * 1e6:.1f} um)')
    if description:
        report['description'] = description.gate_report()
        print(f'  machine description {description.source}: {description.expected_text()}')
        loose = undetermined_beyond(report, nominal, description.parameter_bound())
        report['description']['not_determined_beyond_bound'] = loose
        if loose:
            print(f'  NOT DETERMINED by these poses, moved beyond the '
                  f'{description.parameter_bound() * 1e3:.3g} mm bound within '
                  f'{DETERMINED_SIGMAS:g} sigma: ' + ', '.join(
                      f'{name} {change * 1e3:+.1f} +- {sigma * 1e3:.1f} mm'
                      for name, (change, sigma) in loose.items())
                  + ' (poses over a larger workspace or tilt determine them)')
    _write_hexapod_outputs(args, identification.geometry, report, nominal, description,
                           likely_causes(data, description) if description else None)
    return 0


def _write_hexapod_outputs(args, geometry, report, nominal, description=None,
                           causes=None) -> None:
    check_identification(report, nominal, description, causes)
    if args.out:
        write_geometry(args.out, geometry, {'std_devs': report['std_devs'],
                                            'residual_rms_m': report['residual_rms_m']})
        print(f'wrote {args.out}')
    write_report(args.json, report)


def _calibrate_hexapod_from_bag(args) -> int:
    """Rerun the identification of a run recorded by hexapod_calibrator."""
    records, recorded = read_run(args.bag, MEASUREMENTS_TOPIC,
                                 'alignment_msgs/msg/HexapodMeasurement', measurement_record,
                                 'hexapod calibration measurements', HEXAPOD_RESULT_TOPIC)
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
    _write_hexapod_outputs(args, identification.geometry, report, nominal)
    return 0
