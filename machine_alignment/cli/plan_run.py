"""The work of the subcommands ``plan.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

import numpy as np

from calib_core.errors import MachineAlignmentError
from dispenser_calib.core.description import read_description as read_five_axis_description
from dispenser_calib.core.model import nominal_model as dispenser_nominal
from dispenser_calib.core.model import read_model as read_dispenser_model
from dispenser_calib.core.part_files import write_plan
from dispenser_calib.core.procedure import SHIPPED_WORKSPACE
from dispenser_calib.core.planning import (
    MAX_VIEW_DEG, plan_five_axis, todays_prediction)
from hexapod_calib.core.geometry import POSE_NAMES, nominal_geometry as hexapod_nominal
from hexapod_calib.core.description import read_description as read_hexapod_description
from hexapod_calib.core.geometry import read_geometry as read_hexapod_geometry
from hexapod_calib.core.planning import ACTUATOR_NOISE as HEXAPOD_ACTUATOR_NOISE
from hexapod_calib.core.planning import ANGLE_NOISE as HEXAPOD_ANGLE_NOISE
from hexapod_calib.core.planning import POSITION_NOISE as HEXAPOD_POSITION_NOISE
from hexapod_calib.core.planning import predict as predict_hexapod
from hexapod_calib.core.procedure import HexapodPlan
from machine_alignment.cli.common import check_writable, parse_size, write_json
from machine_alignment.cli.platform_run import read_targets
from platform_calib.core.geometry import nominal_geometry, read_geometry
from platform_calib.core.description import read_description as read_platform_description
from platform_calib.core.planning import (
    HOME, WORKING_SPAN, candidate_poses, default_working, plan_platform, predict_platform)
from printer_alignment.core.stage import CAMERA_NOISE, LANDING_SIGMA, NOMINAL_STAGE
from printer_alignment.core.stage import STROKE as STAGE_STROKE
from printer_alignment.core.stage_calibration import StagePlan, write_stage_plan
from printer_alignment.core.stage_planning import (
    TAUGHT_HOME_MARKS, plan_stage, platform_marks, predict_stage_plan)
from printer_alignment.core.stage_description import read_description as read_stage_description


def cmd_plan_platform(args) -> int:
    check_writable(args.out, '--out')
    if args.geometry and args.description:
        raise MachineAlignmentError('give --geometry or --description, not both')
    description = read_platform_description(args.description) if args.description else None
    settings, noise_text = {}, 'tracker 10 um / 20 urad, feeds 1 um'
    if description:
        m, box = description.measurement, description.box()
        settings = {'span': (*box['translation'], box['rotation']), 'home': box['home'],
                    'tracker_noise': (m.instrument.position_sigma_m,) * 2
                    + (m.instrument.angle_sigma_rad,),
                    'feed_noise': float(np.hypot(m.actuators.sigma_m, m.repeatability_m))}
        noise_text = (f'{m.instrument.name} {m.instrument.position_sigma_m * 1e6:.3g} um / '
                      f'{m.instrument.angle_sigma_rad * 1e6:.3g} urad, feeds '
                      f'{settings["feed_noise"] * 1e6:.3g} um, as described')
    nominal = (description.geometry if description else
               read_geometry(args.geometry) if args.geometry else nominal_geometry())
    working = read_targets(args.working) if args.working else None
    plan = plan_platform(nominal, args.poses, working, args.criterion, args.candidates,
                         margin=args.margin, seed=args.seed, **settings)
    report = plan.report()
    errors = report['predicted_mark_error_m']
    sigmas = report['predicted_parameter_sigmas']
    worst = max(sigmas, key=sigmas.get)
    print(f'{args.poses} poses chosen ({"test-pose (I)" if args.criterion == "I" else "D"}-'
          f'optimal) from {plan.candidates} candidates with the feeds {args.margin * 1e3:g} mm '
          'inside the stroke')
    print(f'predicted before anything moves ({noise_text}, first '
          f'order): mark error at the {"given" if working is not None else "200 random"} '
          f'working poses RMS {errors["rms"] * 1e6:.2f} um, median {errors["median"] * 1e6:.2f} '
          f'um, max {errors["max"] * 1e6:.2f} um (1 sigma); least determined parameter '
          f'{worst} +- {sigmas[worst] * 1e6:.0f} {"urad" if worst.startswith("alpha") else "um"}')
    with open(args.out, 'w') as f:
        f.write('x,y,theta\n')
        f.writelines(f'{x:.12g},{y:.12g},{t:.12g}\n' for x, y, t in plan.poses)
    print(f'wrote {args.out} (x, y m, theta rad: the targets simulate platform --plan and the '
          'calibrator measure)')
    box = {'home': list(settings.get('home', HOME)),
           'half_widths_x_y_theta': list(settings.get('span', WORKING_SPAN))}
    if working is None:
        working = default_working(box['half_widths_x_y_theta'], args.seed, box['home'])
    # For comparison: the calibrator's default, as many random poses of the same box
    # (inside the stroke), predicted the same way.
    random = candidate_poses(nominal, 20 * args.poses, box['half_widths_x_y_theta'],
                             args.margin, args.seed + 500, box['home'])[:args.poses]
    noise = {k: settings[k] for k in ('tracker_noise', 'feed_noise') if k in settings}
    default = predict_platform(nominal, random, working, **noise).report()
    print(f'the default plan ({len(random)} random poses of the same box) is predicted at '
          f'{default["predicted_mark_error_m"]["rms"] * 1e6:.2f} um RMS')
    write_json(args.json, {**report, 'poses': plan.poses.tolist(), 'box': box,
                           'working_poses': np.asarray(working).tolist(), 'noise': noise_text,
                           'default_plan': {**default, 'design': 'random',
                                            'poses': random.tolist()}})
    return 0


def cmd_plan_hexapod(args) -> int:
    check_writable(args.out, '--out')
    if args.geometry and args.description:
        raise MachineAlignmentError('give --geometry or --description, not both')
    description = read_hexapod_description(args.description) if args.description else None
    settings = dict(num_poses=args.poses, num_candidates=args.candidates, seed=args.seed,
                    design=args.criterion)
    if description:
        nominal, plan = description.geometry, description.plan(**settings)
        declared = description.measurement
        noise = (declared.instrument.position_sigma_m, declared.instrument.angle_sigma_rad,
                 declared.actuators.sigma_m)
    else:
        nominal = read_hexapod_geometry(args.geometry) if args.geometry else hexapod_nominal()
        plan = HexapodPlan(**settings)
        noise = (HEXAPOD_POSITION_NOISE, HEXAPOD_ANGLE_NOISE, HEXAPOD_ACTUATOR_NOISE)
    # An option given on the command line overrides the description's or built-in figure.
    args.position_noise, args.angle_noise, args.actuator_noise = (
        given if given is not None else figure for given, figure in zip(
            (args.position_noise, args.angle_noise, args.actuator_noise), noise))
    poses, working = plan.poses(nominal)
    prediction = predict_hexapod(nominal, poses, working, args.position_noise,
                                 args.angle_noise, args.actuator_noise)
    prediction['working_poses_m_rad'] = working.tolist()
    prediction['workspace'] = {'home': list(plan.home), 'translation_m': list(plan.translation),
                               'rotation_rad': list(plan.rotation),
                               'stroke_m': list(plan.stroke),
                               'from': description.source if description else 'built-in'}
    moved, turned = prediction['predicted_displacement_m'], prediction['predicted_rotation_rad']
    how = {'greedy': 'each leg\'s information determinant, greedily',
           'I': 'least pose error over the box, exchange', 'D': 'D-optimal, exchange'}
    print(f'{args.poses} poses chosen ({how[args.criterion]}) from {args.candidates} '
          'candidates inside the strokes')
    print(f'predicted before anything moves (pose sensor {args.position_noise * 1e6:g} um / '
          f'{args.angle_noise * 1e6:g} urad, actuators {args.actuator_noise * 1e6:g} um, first '
          f'order) at {len(working)} other poses: displacement RMS {moved["rms"] * 1e6:.2f} um, '
          f'max {moved["max"] * 1e6:.2f} um; rotation RMS {turned["rms"] * 1e6:.1f} urad, max '
          f'{turned["max"] * 1e6:.1f} urad (1 sigma)')
    with open(args.out, 'w') as f:
        f.write(','.join(POSE_NAMES) + '\n')
        f.writelines(','.join(f'{v:.12g}' for v in pose) + '\n' for pose in poses)
    print(f'wrote {args.out} ({", ".join(POSE_NAMES)}: m, rad)')
    write_json(args.json, {**prediction, 'poses_m_rad': poses.tolist()})
    return 0


def cmd_plan_five_axis(args) -> int:
    check_writable(args.out, '--out')
    described = read_five_axis_description(args.description) if args.description else None
    size = (described.image_size if described else
            parse_size(args.image_size) if args.image_size else (2448, 2048))
    model = (read_dispenser_model(args.calibration) if args.calibration
             else described.nominal() if described else dispenser_nominal(size=size))
    workspace = described.workspace() if described else SHIPPED_WORKSPACE
    noise_px = args.noise_px if args.noise_px is not None else (
        described.centroid_sigma_px if described else 0.1)
    plan = plan_five_axis(model, args.stops, size, args.criterion, noise_px, args.seed,
                          args.depth_of_field, workspace)
    today = todays_prediction(model, size, noise_px, args.seed, workspace)
    report = plan.report()
    print(f'{args.stops} stops chosen ({"test-pose (I)" if args.criterion == "I" else "D"}-'
          f'optimal) from {plan.candidates} candidates inside the strokes with the board in '
          f'view, seen at {MAX_VIEW_DEG:g} degrees or less, the linear ones within '
          f'+-{args.depth_of_field * 1e3:g} mm of focus: '
          + ', '.join(f'{n} {kind}' for kind, n in report['kinds'].items())
          + ' (linear; A alone; C alone; A and C both turned)')
    print(f'predicted before anything moves (dots to {noise_px:g} px, first order), '
          f'against today\'s {today["stops"]}-stop stepwise plan:')
    for label, ours, theirs, unit, factor in (
            ('part placement at the working poses, RMS', plan.working_error_m['rms'],
             today['working_error_m']['rms'], 'um', 1e6),
            ('E_B0A (A\'s tilt about Y)', plan.iso230_7_sigmas['E_B0A'],
             today['iso230_7_sigmas']['E_B0A'], 'urad', 1e6),
            ('E_B0C (C\'s tilt about Y)', plan.iso230_7_sigmas['E_B0C'],
             today['iso230_7_sigmas']['E_B0C'], 'urad', 1e6)):
        print(f'  {label}: {ours * factor:.3g} {unit} (today {theirs * factor:.3g} {unit}, '
              '1 sigma)')
    numbers = {kind: 0 for kind in report['kinds']}
    names = []
    for kind in plan.kinds:
        numbers[kind] += 1
        names.append(f'{kind}_{numbers[kind]:02d}')
    write_plan(args.out, names, plan.stops)
    print(f'wrote {args.out} (stop, x_m, y_m, z_m, a_rad, c_rad: simulate five-axis --plan '
          'measures it)')
    today_report = {k: v for k, v in today.items() if k != 'covariance'}
    write_json(args.json, {**report, 'stops_m_rad': plan.stops.tolist(), 'names': names,
                           'todays_plan': today_report, 'strokes': workspace.strokes,
                           'working_distance_m': workspace.working_distance,
                           'description': described.source if described else None})
    return 0


def cmd_plan_stage(args) -> int:
    check_writable(args.out, '--out')
    described = read_stage_description(args.description) if args.description else None
    nominal = described.nominal() if described else NOMINAL_STAGE
    stroke = described.stroke if described else STAGE_STROKE
    if args.marks is not None:
        marks = platform_marks(np.reshape(args.marks, (2, 2)), nominal)
    else:
        marks = (described.marks if described
                 else platform_marks(np.reshape(TAUGHT_HOME_MARKS, (2, 2))))
    declared = described.noise() if described else {'landing_sigma': LANDING_SIGMA,
                                                    'camera_noise': CAMERA_NOISE}
    noise = {'landing_sigma': declared['landing_sigma'] if args.landing_sigma is None
             else args.landing_sigma,
             'camera_noise': declared['camera_noise'] if args.camera_noise is None
             else args.camera_noise}
    plan = plan_stage(nominal, marks, args.stops, args.sweep_points,
                      criterion=args.criterion, stroke=stroke, **noise)
    today = predict_stage_plan(nominal, marks, StagePlan(stroke=stroke).targets(),
                               stroke=stroke, **noise)
    print(f'{len(plan.targets)} stops: home, sweeps of {args.sweep_points} points each way and '
          f'{args.stops} chosen ({"test-pose (I)" if args.criterion == "I" else "D"}-optimal) '
          f'from {plan.candidates} candidates inside the stroke')
    print(f'predicted before anything moves (landing {noise["landing_sigma"] * 1e6:g} um per '
          f'chain, camera {noise["camera_noise"] * 1e6:g} um, first order): the calibration '
          f'Marks\' plate positions at 40 working inputs RMS {plan.predicted_rms_m * 1e6:.3f} '
          f'um, max {plan.predicted_max_m * 1e6:.3f} um (1 sigma); today\'s '
          f'{len(today.targets)}-stop run {today.predicted_rms_m * 1e6:.3f} um, max '
          f'{today.predicted_max_m * 1e6:.3f} um')
    write_stage_plan(args.out, plan.targets)
    print(f'wrote {args.out} (q1, q2, q3 m in visiting order: simulate stage --plan and the '
          'calibrator\'s targets key measure it)')
    write_json(args.json, {**plan.report(), 'targets_m': plan.targets.tolist(),
                           'todays_run': {**today.report(), 'targets_m': today.targets.tolist()},
                           'stroke_m': stroke, 'marks_platform_m': np.asarray(marks).tolist(),
                           'noise_m': noise,
                           'description': described.source if described else None})
    return 0
