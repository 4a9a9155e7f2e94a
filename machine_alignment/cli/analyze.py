"""``machine-align analyze <machine>``: the closed loop on a dataset. Find the effect the
model lacks, refit, report before and after on held-out rows; for an axis also the ISO
230-2 figures and a compensation table."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calib_core.axis import AxisData, AxisModel, iso230_2_before_after, write_compensation_table
from calib_core.closed_loop import LoopConfig, analyze, format_report
from calib_core.controller_formats import (
    LINUXCNC_MAX_ENTRIES, resampled_for_linuxcnc, write_linuxcnc_comp)
from calib_core.datasets import write_columns
from calib_core.effects.smooth_map import compensation_grid
from calib_core.iso230_2_plot import plot_iso230_2
from calib_core.errors import MachineAlignmentError
from dispenser_calib.core.loop_model import RotaryLoopModel
from dispenser_calib.core.data import read_observations
from dispenser_calib.core.model import read_model
from dispenser_calib.core.rotary import LEVER
from dispenser_calib.core.target_poses import poses_from_images, read_target_poses
from grid_calib.core.data import read_marks
from grid_calib.core.loop_plot import plot_grid_loop
from grid_calib.core.residual_loop import analyze_travel
from calib_core.iso230_2 import format_figures
from calib_core.loop_plots import plot_loop
from hexapod_calib.core.calibration import PoseData
from hexapod_calib.core.description import read_description
from hexapod_calib.core.geometry import read_geometry
from hexapod_calib.core.loop_models import HexapodLoopModel
from hexapod_calib.core.statics import leg_forces
from machine_alignment.cli import command_help
from machine_alignment.cli.common import (
    parse_size, progress, ranged, write_json_and_plot)
from platform_calib.core.geometry import nominal_geometry as nominal_platform
from platform_calib.core.geometry import read_geometry as read_platform
from platform_calib.core.identification import PoseData as PlatformPoseData
from platform_calib.core.loop_model import PlatformLoopModel
from printer_alignment.core.camera_calibration import read_correspondences
from printer_alignment.core.loop_models import (
    CameraLoopModel, GantryData, GantryLoopModel, StageLoopModel)
from printer_alignment.core.stage_calibration import StageData

FORMATS = {'axis': 'CSV: command, measured (m), direction (+1/-1); optional cycle, '
                   'sequence (approach number), block/setup/run (labels), time (s), '
                   'temperature (K)',
           'gantry': 'CSV: command_x, command_y, measured_x, measured_y (m); optional '
                     'direction_x, direction_y, time, temperature',
           'camera': 'CSV: view, model_x, model_y (m), u, v (px)',
           'stage': 'CSV: q1..q3 (m), mark1_x, mark1_y, mark2_x, mark2_y (m, plate '
                    'frame); optional direction1..3, time, temperature',
           'platform': 'CSV: feed1..feed3 (m), x, y (m), theta (rad); optional '
                       'direction1..direction3, time, temperature',
           'hexapod': 'CSV: x..yaw, meas_x..meas_yaw (m, rad); optional l1..l6 (m), '
                      'force1..force6 (N, compression positive), direction1..direction6, '
                      'time, temperature',
           'rotary': 'CSV: a, c (rad; other names with --a-column, --c-column), x, y, z (m, '
                     'target origin in the instrument frame), qw, qx, qy, qz (instrument to '
                     'target); optional time (s), temperature (K)'}


def _loop_machine(args, dropped: dict):
    """The closed loop's model of ``args.machine`` over ``args.data``."""
    if args.machine == 'axis':
        return AxisModel(AxisData.from_csv(args.data, dropped))
    if args.machine == 'gantry':
        return GantryLoopModel(GantryData.from_csv(args.data, dropped))
    if args.machine == 'camera':
        size = parse_size(args.image_size) if args.image_size else None
        return CameraLoopModel(read_correspondences(args.data), size)
    if args.machine == 'stage':
        return StageLoopModel(StageData.from_csv(args.data, dropped))
    if args.machine == 'platform':
        nominal = read_platform(args.geometry) if args.geometry else nominal_platform()
        return PlatformLoopModel(PlatformPoseData.from_csv(args.data, dropped), nominal)
    if args.machine == 'rotary' and args.calibration:
        return RotaryLoopModel(poses_from_images(read_model(args.calibration),
                                                 read_observations(args.data)))
    if args.machine == 'rotary':
        return RotaryLoopModel(read_target_poses(args.data, args.a_column, args.c_column),
                               args.lever)
    description = read_description(args.description) if args.description else None
    nominal = description.geometry if description else read_geometry(args.geometry)
    data = PoseData.from_csv(args.data, nominal, dropped, leg_m_per_unit=(
        description.measurement.actuators.m_per_unit if description else 1.0))
    forces = None
    if args.payload:
        mass, *centre = args.payload
        forces = leg_forces(nominal, data.commanded, mass, centre)
    return HexapodLoopModel(data, nominal, forces)


def _axis_figures(machine, result, report: dict, json_path, units: str = 'mm') -> None:
    """ISO 230-2 figures before and after, into the report and printed; the
    compensation table beside the JSON."""
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
        comp = Path(json_path).with_name(Path(json_path).stem + '_linuxcnc.comp')
        # An export never fails the analysis it belongs to: a dense scan's table is
        # resampled to what LinuxCNC takes, and any other refusal is said, not raised.
        entries, resampled = resampled_for_linuxcnc(table)
        try:
            write_linuxcnc_comp(comp, entries, units)
        except MachineAlignmentError as error:
            report['linuxcnc_comp_file'] = f'not written: {error}'
            print(f'LinuxCNC compensation file not written: {error}')
        else:
            report['linuxcnc_comp_file'] = str(comp)
            if resampled:
                report['linuxcnc_comp_resampled'] = (
                    f'{len(table)} entries resampled to {LINUXCNC_MAX_ENTRIES}, LinuxCNC\'s '
                    f'limit per joint, linearly between the table\'s positions')
            print(f'wrote {comp} (LinuxCNC: [JOINT_n] COMP_FILE = {comp.name}, COMP_FILE_TYPE '
                  f'= 1; values in {units}, the machine units; BACKLASH is then ignored, the '
                  f'two directions carry it'
                  + (f'; {report["linuxcnc_comp_resampled"]}' if resampled else '') + ')')
        figure = Path(json_path).with_name(Path(json_path).stem + '_iso230_2.png')
        held = iso['method'].startswith('leave one cycle out')
        plot_iso230_2(figure, iso['before'], iso['after'], 'after the extended model, '
                      + ('each cycle held out' if held else 'in-sample'))
        report['iso230_2_figure'] = str(figure)
        print(f'wrote {figure} (mean +- 2 s per direction against target, before and after)')


MAP_GRID_POINTS = 11
"""Points per axis of the 2-D compensation grid written for a smooth map."""


def _map_grid(result, report: dict, json_path) -> None:
    """The smooth 2-D map the loop added, as the compensation grid a controller loads,
    beside the JSON (x, y, correction_x, correction_y in m over the travel measured)."""
    names = result.fit.names()
    if 'smooth_map' not in names or not json_path:
        return
    k = names.index('smooth_map')
    prepared = result.fit.effects[k]
    low, high = (np.array(v) for v in prepared.notes['map_travel_m'])
    step = float(np.min(high - low)) / (MAP_GRID_POINTS - 1)
    grid = compensation_grid(prepared.term, result.fit.values[k], low, high, step)
    path = Path(json_path).with_name(Path(json_path).stem + '_map.csv')
    write_columns(path, ['x', 'y', 'correction_x', 'correction_y'], list(grid.T))
    report['compensation_map'] = str(path)
    print(f'wrote {path} (x, y, correction_x, correction_y in m; {len(grid)} points '
          f'{step * 1e3:.4g} mm apart over the travel measured; add the correction to the '
          f'command)')


def cmd_analyze(args) -> int:
    dropped = {}
    machine = _loop_machine(args, dropped)
    config = LoopConfig(holdout_fraction=args.holdout, alpha=args.alpha, seed=args.seed,
                        max_effects=args.max_effects, splits=args.splits,
                        min_effect=args.min_effect)
    result = analyze(machine, config, progress=progress)
    report = dict(result.report, data=str(args.data), dropped_columns=dropped)
    print(format_report(report))
    for name, reason in dropped.items():
        print(f'  column {name}: {reason}')
    if args.machine == 'axis':
        _axis_figures(machine, result, report, args.json, args.machine_units)
    if args.machine == 'gantry':
        _map_grid(result, report, args.json)
    if args.machine == 'rotary':
        report['identification'] = identified = machine.identified.report()
        print(f'  all poses, base model: A and C {90 - np.degrees(identified["squareness_a_c_rad"]):.4f}'
              f' deg apart (+- {np.degrees(identified["squareness_std_rad"]):.4f} deg); position '
              f'error RMS {identified["position_error_m"]["rms"] * 1e6:.0f} um, orientation '
              f'{identified["orientation_error_rad"]["rms"] * 1e6:.0f} urad')
    write_json_and_plot(args.json, report, lambda png: plot_loop(png, machine, result))
    return 0


def cmd_analyze_grid(args) -> int:
    """The closed loop on each region's self-calibration (its own method: the base model
    holds a value per site and per mark, too many for the general loop's hold-out)."""
    grid, regions = read_marks(args.data, args.pitch)
    chosen = regions if args.region is None else {args.region: regions.get(args.region)}
    if None in chosen.values():
        raise MachineAlignmentError(f'{args.data} has no region {args.region}; it has '
                                    f'{sorted(regions)}')
    details = {}
    summary = analyze_travel(grid, chosen, args.min_effect, details=details)
    for r, report in summary['regions'].items():
        before, after = report['held_out']['before'], report['held_out']['after']
        print(f'region {r}: {report["base_model"]}')
        for effect in report['effects']:
            values = ', '.join(f'{n} {v:.4g} +- {effect["std_devs"][n]:.2g} '
                               f'{effect["units"][n]}' for n, v in effect['parameters'].items()
                               if n not in effect['not_determined'])
            held = (f'; not determined (held at 0): {", ".join(effect["not_determined"])}'
                    if effect['not_determined'] else '')
            print(f'  added {effect["name"]} ({effect["meaning"]}): {values}{held}')
        for name, verdict in report['verdicts'].items():
            if verdict != 'added':
                print(f'  {name}: {verdict}')
        for name, reason in report['skipped'].items():
            print(f'  {name}: not tested ({reason})')
        print(f'  held-out (leave-one-out, {before["predicted"]} readings; '
              f'{before["unpredictable"]} no other reading predicts): RMS '
              f'{before["rms_m"] * 1e9:.2f} -> {after["rms_m"] * 1e9:.2f} nm, max '
              f'{before["max_m"] * 1e9:.2f} -> {after["max_m"] * 1e9:.2f} nm; G changes by up '
              f'to {report["stage_error_change_m"] * 1e9:.2f} nm')
    if len(summary['regions']) > 1:
        print(f'all regions, held out: RMS {summary["rms_before"] * 1e9:.2f} -> '
              f'{summary["rms_after"] * 1e9:.2f} nm, max {summary["max_before"] * 1e9:.2f} -> '
              f'{summary["max_after"] * 1e9:.2f} nm')
    write_json_and_plot(args.json, dict(summary, data=str(args.data)),
                        lambda png: plot_grid_loop(png, summary, details))
    return 0


def add_parser(sub) -> None:
    analyze_parser = sub.add_parser('analyze', help=command_help('analyze'))
    machines = analyze_parser.add_subparsers(dest='machine', required=True)
    for name, help_text in FORMATS.items():
        machine = machines.add_parser(name, help=help_text)
        machine.add_argument('--data', required=True, help=help_text)
        machine.add_argument('--json', help='report to write; the plot goes beside it (.png), '
                                            'for an axis also the ISO 230-2 plot and the '
                                            'compensation table (CSV and LinuxCNC file)')
        machine.add_argument('--holdout', type=ranged(float, 0.05, 0.6), default=0.3,
                             help='fraction of rows kept out of every fit')
        machine.add_argument('--alpha', type=ranged(float, 1e-12, 0.5), default=1e-3, help='significance level')
        machine.add_argument('--max-effects', type=ranged(int, 0, 20), default=4, help='most effects the loop may add')
        machine.add_argument('--seed', type=ranged(int, 0), default=0, help='of the first hold-out split')
        machine.add_argument('--splits', type=ranged(int, 1, 50), default=5,
                             help='hold-out splits the selection is repeated over')
        machine.add_argument('--min-effect', type=ranged(float, 0), default=None,
                             help='smallest effect worth adding, RMS in the residual unit '
                                  '(m; px for the camera); default: the machine\'s')
        if name == 'camera':
            machine.add_argument('--image-size', help='WxH in px (default: inferred from the data)')
        if name == 'axis':
            machine.add_argument('--machine-units', choices=('mm', 'inch'), default='mm',
                                 help='units of the LinuxCNC compensation file written beside '
                                      'the JSON (the machine\'s units)')
        if name == 'platform':
            machine.add_argument('--geometry', help='nominal geometry YAML (default: built-in)')
        if name == 'rotary':
            machine.add_argument('--a-column', default='a', help='the tilt axis A\'s column')
            machine.add_argument('--c-column', default='c', help='the rotary table C\'s column')
            machine.add_argument('--calibration',
                                 help='five-axis calibration YAML: --data is then a five-axis '
                                      'observations CSV of a sweep with the linear axes held '
                                      '(simulate five-axis --sweep), the board\'s pose in '
                                      'each image is the target pose')
            machine.add_argument('--lever', type=ranged(float, 1e-3, 10.0, 'm'), default=LEVER,
                                 help='m: orientation errors count as the displacement of a '
                                      'point this far from the target origin')
        if name == 'hexapod':
            described = machine.add_mutually_exclusive_group(required=True)
            described.add_argument('--geometry', help='nominal geometry YAML')
            described.add_argument('--description', help='your machine\'s description YAML '
                                                          '(l1..l6 in its actuators\' unit)')
            machine.add_argument('--payload', type=float, nargs=4,
                                 metavar=('MASS', 'X', 'Y', 'Z'),
                                 help='payload mass (kg) and centre of mass (m, platform '
                                      'frame): leg forces for leg_play and compliance')
        machine.set_defaults(func=cmd_analyze)
    grid = machines.add_parser('grid', help='the closed loop on a grid self-calibration '
                                            '(marks CSV, optional time and temperature)')
    grid.add_argument('--data', required=True, help='marks CSV of calibrate grid, with time '
                                                    '(s) and temperature (K) if logged')
    grid.add_argument('--pitch', type=ranged(float, 1e-6, 1.0, 'm', 'the format is SI metres'), required=True, help='nominal plate pitch, m')
    grid.add_argument('--region', type=ranged(int, 0), help='one region (default: each)')
    grid.add_argument('--min-effect', type=ranged(float, 0), default=5e-9,
                      help='smallest effect worth adding, RMS over the readings, m')
    grid.add_argument('--json', help='report to write')
    grid.set_defaults(func=cmd_analyze_grid)
