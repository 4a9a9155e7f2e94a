"""The work of the subcommands ``simulate.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import yaml

from calib_core.errors import MachineAlignmentError
from calib_core.storage import write_atomic
from calib_core.sim.axis import AxisTest, AxisTruth, simulate_axis_test
from grid_calib.core.data import Region, write_marks
from grid_calib.core.description import read_description as read_grid_description
from grid_calib.core.model import Grid
from grid_calib.core.reference_map import write_reference
from grid_calib.sim.plate import default_travel, measure_travel
from hexapod_calib.core.geometry import nominal_geometry, write_geometry
from hexapod_calib.core.kinematics import inverse_kinematics
from hexapod_calib.core.procedure import HexapodPlan, measure_poses
from hexapod_calib.core.calibration import PoseData
from hexapod_calib.core.description import read_description
from hexapod_calib.sim.hexapod import (
    HexapodSim, HexapodTruth, PoseSensorSim, Stroke, true_geometry)
from machine_alignment.cli.common import progress
from printer_alignment.core.camera_calibration import write_correspondences
from printer_alignment.sim.camera import tilted_plate_views
from printer_alignment.sim.gantry import GantryErrors, measure_random_positions
from printer_alignment.core.stage_calibration import StagePlan, read_stage_plan
from printer_alignment.core.stage_description import read_description as read_stage_description
from printer_alignment.sim.stage import TRUE_STAGE, random_stage, simulate_calibration_run


def cmd_simulate_hexapod(args) -> int:
    """The shipped simulated hexapod, or with ``--description`` a model of the user's: its
    geometry, workspace, strokes, instrument and actuator noise, legs written in its
    actuators' unit, with the error sources asked for."""
    out = Path(args.out)
    description = read_description(args.description) if args.description else None
    nominal = description.geometry if description else nominal_geometry()
    truth = HexapodTruth.default(nominal, args.seed)
    if args.joint_error is not None:
        truth = dataclasses.replace(truth, geometry=true_geometry(
            nominal, args.seed, args.joint_error, args.joint_error))
    if args.lead_ratio:
        truth = dataclasses.replace(truth, lead_ratio=tuple(args.lead_ratio))
    if args.no_play:
        truth = dataclasses.replace(truth, leg_play=np.zeros(6))
    settings = dict(num_poses=args.poses, num_evaluation=args.evaluation, seed=args.seed,
                    num_candidates=max(400, 2 * (args.poses + args.evaluation)))
    per_unit = 1.0
    if description:
        measured_by = description.measurement
        truth = dataclasses.replace(truth, actuator_noise=measured_by.actuators.sigma_m)
        plan = description.plan(**settings)
        sensor = PoseSensorSim(measured_by.instrument.position_sigma_m,
                               measured_by.instrument.angle_sigma_rad, seed=args.seed + 2)
        sim = HexapodSim(truth, nominal, Stroke(*plan.stroke), seed=args.seed + 1,
                         home=plan.home)
        per_unit = measured_by.actuators.m_per_unit
    else:
        plan, sensor = HexapodPlan(**settings), PoseSensorSim(seed=args.seed + 2)
        sim = HexapodSim(truth, nominal, seed=args.seed + 1)
    targets, evaluation = plan.poses(nominal)
    for name, poses in (('calibration', targets), ('evaluation', evaluation)):
        data = measure_poses(poses, inverse_kinematics(nominal, poses), sim.move_legs,
                             lambda: sensor.measure(sim.pose), name,
                             progress=lambda step, total, _: progress(step, total, name))
        PoseData(data.commanded, data.measured, data.leg_lengths / per_unit,
                 data.covariates).to_csv(out / f'{name}.csv')
    write_geometry(out / 'nominal.yaml', nominal)
    write_geometry(out / 'truth.yaml', sim.truth.geometry,
                   {'note': 'simulation truth, for checking a calibration only',
                    'lead_ratio': list(map(float, sim.truth.lead_ratio)),
                    'leg_play_m': sim.truth.leg_play.tolist()})
    unit = description.measurement.actuators.unit if description else 'm'
    print(f'wrote {out}/nominal.yaml, calibration.csv ({len(targets)} poses), '
          f'evaluation.csv ({len(evaluation)} poses; legs l1..l6 in {unit}), truth.yaml')
    return 0


def cmd_simulate_stage(args) -> int:
    described = read_stage_description(args.description) if args.description else None
    truth = random_stage(args.seed, described.d) if described else TRUE_STAGE
    if args.no_backlash:
        truth = truth.with_changes(backlash=(0.0, 0.0, 0.0))
    if described:
        plan = (read_stage_plan(args.plan, described.stroke) if args.plan
                else StagePlan(stroke=described.stroke))
        data = simulate_calibration_run(truth, plan, seed=args.seed, stroke=described.stroke,
                                        marks=described.marks, **described.noise())
        described.write(args.out, data)
    else:
        plan = read_stage_plan(args.plan) if args.plan else None
        data = simulate_calibration_run(truth, plan=plan, seed=args.seed)
        data.to_csv(args.out)
    unit = described.measurement.actuators.unit if described else 'm'
    print(f'wrote {args.out} ({len(data)} stops{f" of {args.plan}" if args.plan else ""}; '
          f'q1..q3 in {unit})')
    if args.truth:
        write_atomic(args.truth, yaml.safe_dump(
            {'parameters': {k: float(v) for k, v in truth.as_dict().items()}}, sort_keys=False))
        print(f'wrote {args.truth} (the true stage geometry, SI units)')
    return 0


def cmd_simulate_axis(args) -> int:
    truth = AxisTruth(backlash=args.backlash, periodic_amplitude=args.periodic,
                      pitch=args.pitch, expansion=args.expansion,
                      temperature_rise=args.temperature_rise)
    data = simulate_axis_test(truth, AxisTest(travel=args.travel, targets=args.targets,
                                              cycles=args.cycles), seed=args.seed)
    data.to_csv(args.out)
    print(f'wrote {args.out} ({len(data)} rows)')
    return 0


def cmd_simulate_gantry(args) -> int:
    errors = GantryErrors.ideal() if args.ideal else GantryErrors()
    data = measure_random_positions(errors, count=args.count, seed=args.seed)
    data.to_csv(args.out)
    print(f'wrote {args.out} ({len(data)} positions; '
          f'{"an ideal gantry" if args.ideal else "backlash, screw error and squareness"})')
    return 0


def cmd_simulate_camera(args) -> int:
    camera = np.array([[args.focal, 0, 319.5], [0, args.focal, 239.5], [0, 0, 1]])
    views = tilted_plate_views(camera, (args.k1, args.k2, args.p1, args.p2),
                               views=args.views, noise_px=args.noise, seed=args.seed)
    write_correspondences(args.out, views)
    print(f'wrote {args.out} ({len(views)} views of a 9 x 7 grid, 10 mm pitch; 640x480 px)')
    return 0


def cmd_simulate_grid(args) -> int:
    described = read_grid_description(args.description) if args.description else None
    grid = described.grid if described else Grid(args.half, args.pitch)
    columns, rows = described.regions if described else args.regions
    noise = described.expected_reading_rms() if described else args.noise
    if columns < 1 or rows < 1:
        raise MachineAlignmentError(f'--regions needs at least 1 x 1, not {columns} x {rows}')
    truth = default_travel(grid, columns, rows, args.seed, plate_error=args.plate_error,
                           isotropic_scale=args.isotropic_scale)
    measured = measure_travel(grid, truth, noise, args.seed, args.expansion, args.warm_up)
    regions = {r: Region(truth.origins[r], p) for r, p in measured.items()}
    if described:
        described.write(args.out, regions)
    else:
        write_marks(args.out, grid, regions)
    if args.truth:
        sites = np.unique(np.vstack([grid.sites + np.asarray(o) for o in truth.origins.values()]),
                          axis=0) * grid.pitch
        write_reference(args.truth, sites, truth.error_at(sites))
        print(f'wrote {args.truth} (the true stage error at the {len(sites)} sites: '
              f'evaluate grid --reference reads it)')
    print(f'wrote {args.out} ({2 * grid.half + 1} x {2 * grid.half + 1} marks, 3 placements, '
          f'{columns} x {rows} region(s) sharing one row/column; true non-orthogonality '
          f'{truth.non_orthogonality * 1e6:g} urad, scale difference '
          f'{truth.scale_difference * 1e6:g} ppm, isotropic scale '
          f'{truth.isotropic_scale * 1e6:g} ppm; the plate\'s mean pitch (its certificate) '
          f'{truth.mean_pitch(grid):.12g} m)')
    return 0
