"""The work of ``machine-align analyze``: datasets read, the loop run, reports, figures and
compensation tables written. Imported when the command runs, so that ``--help`` does not
pay for the science stack; each machine's modules are imported when that machine is
analysed, so that one machine's command does not load the others' (up to a second)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calib_core.closed_loop import LoopConfig, analyze, format_report
from calib_core.errors import MachineAlignmentError
from machine_alignment.cli.common import (
    parse_size, progress, read_in_si, unit_hint, write_report)


def _axis(args, dropped):
    from calib_core.axis import AxisData, AxisModel
    with unit_hint(args):
        return AxisModel(AxisData.from_csv(args.data, dropped, args.length_unit,
                                           args.error_unit))


def _gantry(args, dropped):
    from printer_alignment.core.loop_models import GantryData, GantryLoopModel
    with unit_hint(args):
        return GantryLoopModel(GantryData.from_csv(args.data, dropped, args.length_unit))


def _camera(args, dropped):
    from printer_alignment.core.camera_calibration import read_correspondences
    from printer_alignment.core.loop_models import CameraLoopModel
    size = parse_size(args.image_size) if args.image_size else None
    with unit_hint(args):
        views = read_correspondences(args.data, args.length_unit)
    return CameraLoopModel(views, size)


def _stage(args, dropped):
    from printer_alignment.core.loop_models import StageLoopModel
    from printer_alignment.core.stage_calibration.data import INPUT_COLUMNS, StageData
    if args.description:
        from printer_alignment.core.stage_description import read_description
        described = read_description(args.description)
        return StageLoopModel(described.read(args.data, dropped), described.d)
    return StageLoopModel(read_in_si(StageData.from_csv, args.data, dropped,
                                     actuators=INPUT_COLUMNS))


def _platform(args, dropped):
    from calib_core.description import refuse_unit_slip
    from platform_calib.core.description import read_description, travel_ratio
    from platform_calib.core.geometry import nominal_geometry, read_geometry
    from platform_calib.core.identification import FEED_COLUMNS, PoseData
    from platform_calib.core.loop_model import PlatformLoopModel
    if args.description:
        platform = read_description(args.description)
        data = platform.read(args.data, dropped)
        # The loop on readings in another unit would explain nothing worth saying.
        refuse_unit_slip(travel_ratio(data, platform), platform.measurement.actuators,
                         'feeds', f'{args.data} read by {platform.source}')
        return PlatformLoopModel(data, platform.geometry)
    nominal = read_geometry(args.geometry) if args.geometry else nominal_geometry()
    return PlatformLoopModel(read_in_si(PoseData.from_csv, args.data, dropped,
                                        actuators=FEED_COLUMNS), nominal)


def _rotary(args, dropped):
    from dispenser_calib.core.loop_model import RotaryLoopModel
    if args.calibration:
        from calib_core.files import read_yaml
        from dispenser_calib.core.data import SHIPPED_BOARD, board_from_dict, read_observations
        from dispenser_calib.core.model import covariance_from, model_from
        from dispenser_calib.core.target_poses import pose_variants, poses_from_images
        content = read_yaml(args.calibration, 'a five-axis calibration')
        model = model_from(content, args.calibration)
        covariance = covariance_from(content, args.calibration)
        # The board the calibration was made on (a file from before it was kept: the
        # shipped one); the sweep is of the same board.
        recorded = content.get('board')
        board = SHIPPED_BOARD if recorded is None else board_from_dict(recorded)
        images = read_observations(args.data, board=board)
        variants = (None if covariance is None else
                    pose_variants(model, covariance, images))
        return RotaryLoopModel(poses_from_images(model, images), variants=variants)
    from dispenser_calib.core.rotary import LEVER
    from dispenser_calib.core.target_poses import read_target_poses
    with unit_hint(args):
        poses = read_target_poses(args.data, args.a_column, args.c_column, args.angle_unit,
                                  args.length_unit)
    return RotaryLoopModel(poses, LEVER if args.lever is None else args.lever)


def _hexapod(args, dropped):
    from calib_core.description import refuse_unit_slip
    from hexapod_calib.core.calibration import LEG_NAMES, PoseData
    from hexapod_calib.core.description import read_description, travel_ratio
    from hexapod_calib.core.geometry import read_geometry
    from hexapod_calib.core.loop_models import HexapodLoopModel
    description = read_description(args.description) if args.description else None
    nominal = description.geometry if description else read_geometry(args.geometry)
    data = (PoseData.from_csv(args.data, nominal, dropped, leg_m_per_unit=(
        description.measurement.actuators.m_per_unit)) if description
            else read_in_si(PoseData.from_csv, args.data, nominal, dropped, actuators=LEG_NAMES))
    if description:
        refuse_unit_slip(travel_ratio(data, description), description.measurement.actuators,
                         'legs', f'{args.data} read by {description.source}')
    forces = None
    if args.payload:
        from hexapod_calib.core.statics import leg_forces
        mass, *centre = args.payload
        forces = leg_forces(nominal, data.commanded, mass, centre)
    return HexapodLoopModel(data, nominal, forces)


LOOP_MACHINES = {'axis': _axis, 'gantry': _gantry, 'camera': _camera, 'stage': _stage,
                 'platform': _platform, 'rotary': _rotary, 'hexapod': _hexapod}
"""The closed loop's model of each machine over ``args.data``, its modules imported when
it is asked for."""


def _axis_figures(machine, result, report: dict, json_path, units: str = 'mm') -> None:
    """ISO 230-2 figures before and after, into the report and printed; the
    compensation table beside the JSON."""
    from calib_core.axis import iso230_2_before_after, write_compensation_table
    from calib_core.controller_formats import (
        LINUXCNC_MAX_ENTRIES, resampled_for_linuxcnc, write_linuxcnc_comp)
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
        from calib_core.iso230_2_plot import plot_iso230_2   # matplotlib: only for a figure
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
    from calib_core.datasets import write_columns
    from calib_core.effects.smooth_map import compensation_grid
    k = names.index('smooth_map')
    prepared = result.fit.effects[k]
    low, high = (np.array(v) for v in prepared.notes['map_travel_m'])
    step = float(np.min(high - low)) / (MAP_GRID_POINTS - 1)
    grid = compensation_grid(result.fit.values[k], prepared.notes['map_degree'], low, high,
                             step)
    path = Path(json_path).with_name(Path(json_path).stem + '_map.csv')
    write_columns(path, ['x', 'y', 'correction_x', 'correction_y'], list(grid.T))
    report['compensation_map'] = str(path)
    print(f'wrote {path} (x, y, correction_x, correction_y in m, in '
          f'{prepared.notes["map_frame"]}; {len(grid)} points {step * 1e3:.4g} mm apart over '
          f'the travel measured; add the correction to the target)')


def _draw_loop(png, machine, result) -> None:
    # Imported here: matplotlib (0.3 s) only when a figure is written (--json).
    from calib_core.loop_plots import plot_loop
    plot_loop(png, machine, result)


def _draw_grid_loop(png, summary, details) -> None:
    from grid_calib.core.loop_plot import plot_grid_loop     # matplotlib, as above
    plot_grid_loop(png, summary, details)


def cmd_analyze(args) -> int:
    dropped = {}
    machine = LOOP_MACHINES[args.machine](args, dropped)
    config = LoopConfig(holdout_fraction=args.holdout, alpha=args.alpha, seed=args.seed,
                        max_effects=args.max_effects, splits=args.splits,
                        min_effect=args.min_effect)
    result = analyze(machine, config, progress=progress)
    report = dict(result.report, data=str(args.data), dropped_columns=dropped)
    units = {key: getattr(args, f'{key}_unit', None) for key in ('length', 'error', 'angle')}
    if any(units.values()):
        report['data_units'] = {key: unit for key, unit in units.items() if unit}
    print(format_report(report))
    for name, reason in dropped.items():
        print(f'  column {name}: {reason}')
    if set(report.get('data_units', {}).values()) - {'m', 'rad'}:
        print('  data read in ' + ', '.join(f'{unit} ({key})' for key, unit
                                            in report['data_units'].items())
              + ('; the report is in m and px' if args.machine == 'camera'
                 else '; the report is in m and rad'))
    if args.machine == 'axis':
        _axis_figures(machine, result, report, args.json, args.machine_units)
    if args.machine in ('gantry', 'stage'):
        _map_grid(result, report, args.json)
    if args.machine == 'rotary':
        report['identification'] = identified = machine.identified.report()
        print(f'  all poses, base model: A and C {90 - np.degrees(identified["squareness_a_c_rad"]):.4f}'
              f' deg apart (+- {np.degrees(identified["squareness_std_rad"]):.4f} deg); position '
              f'error RMS {identified["position_error_m"]["rms"] * 1e6:.0f} um, orientation '
              f'{identified["orientation_error_rad"]["rms"] * 1e6:.0f} urad')
    write_report(args.json, report, lambda png: _draw_loop(png, machine, result),
                 format_report(report))
    return 0


def cmd_analyze_grid(args) -> int:
    """The closed loop on each region's self-calibration (its own method: the base model
    holds a value per site and per mark, too many for the general loop's hold-out)."""
    from grid_calib.core.data import read_marks
    from grid_calib.core.description import read_description
    from grid_calib.core.residual_loop import analyze_travel
    grid, regions = (read_description(args.description).read(args.data) if args.description
                     else read_marks(args.data, args.pitch))
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
    write_report(args.json, dict(summary, data=str(args.data)),
                 lambda png: _draw_grid_loop(png, summary, details))
    return 0


