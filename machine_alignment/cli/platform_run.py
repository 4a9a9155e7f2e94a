"""The work of the subcommands ``platform.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_core.datasets import write_columns  # noqa: E402
from calib_core.errors import InvalidInputError  # noqa: E402
from calib_core.files import read_csv_rows  # noqa: E402
from machine_alignment.cli.common import (  # noqa: E402
    quantity, read_in_si, read_run, write_report)
from platform_calib.core.compensation import (  # noqa: E402
    SCREEN, PSOSettings, compensate, composite_error)
from platform_calib.core.description import likely_causes, read_description  # noqa: E402
from platform_calib.core.geometry import (  # noqa: E402
    geometry_from_mapping, nominal_geometry, read_geometry, write_geometry)
from platform_calib.core.identification import (  # noqa: E402
    FEED_COLUMNS, PoseData, check_identification, identify)
from platform_calib.core.kinematics import forward, inverse  # noqa: E402
from platform_calib.core.procedure import data_of, evaluate  # noqa: E402
from platform_calib.core.records import (  # noqa: E402
    MEASUREMENTS_TOPIC, RESULT_TOPIC, stop_from_message)
from platform_calib.sim.platform import (  # noqa: E402
    PlatformSim, measure_poses, plan_poses, true_geometry)


def cmd_simulate_platform(args) -> int:
    description = read_description(args.description) if args.description else None
    nominal = description.geometry if description else nominal_geometry()
    truth = true_geometry(args.seed, args.scale, nominal)
    if description:
        m = description.measurement
        sim = PlatformSim(truth, args.seed, np.hypot(m.actuators.sigma_m, m.repeatability_m),
                          (m.instrument.position_sigma_m,) * 2 + (m.instrument.angle_sigma_rad,),
                          (args.screw,) * 3, (args.backlash,) * 3, feed_scale=args.lead_ratio)
        targets = (read_targets(args.plan) if args.plan
                   else description.random_poses(args.poses, args.seed))
    else:
        sim = PlatformSim(truth, args.seed, screw_amplitude=(args.screw,) * 3,
                          backlash=(args.backlash,) * 3, feed_scale=args.lead_ratio)
        targets = read_targets(args.plan) if args.plan else plan_poses(args.poses, args.seed)
    # The feeds as the user's actuators report them.
    measure_poses(sim, targets, nominal).to_csv(
        args.out, description.measurement.actuators.m_per_unit if description else 1.0)
    where = ('within the described workspace' if description else 'within +-5 mm, +-5 deg')
    unit = description.measurement.actuators.unit if description else 'm'
    print(f'wrote {args.out} ({len(targets)} poses '
          + (f'planned in {args.plan}' if args.plan else where)
          + f': feeds from the sensors (in {unit}), poses from the tracker)')
    if args.truth:
        write_geometry(args.truth, truth)
        print(f'wrote {args.truth} (the simulation\'s true geometry)')
    return 0


def cmd_calibrate_platform(args) -> int:
    if args.geometry and args.description:
        raise InvalidInputError('give --geometry or --description (it holds the geometry), '
                                'not both')
    description = read_description(args.description) if args.description else None
    nominal = (description.geometry if description else
               read_geometry(args.geometry) if args.geometry else nominal_geometry())
    recorded = None
    if args.bag:
        stops, recorded = read_run(args.bag, MEASUREMENTS_TOPIC,
                                   'alignment_msgs/msg/PlatformMeasurement', stop_from_message,
                                   'platform measurements', RESULT_TOPIC)
        data = data_of([s for s in stops if s.phase == 'identify'])
        live = (recorded or {}).get('nominal_geometry')
        if live and not (description or args.geometry):
            # Solved from the nominal the live run started from, as it was recorded.
            nominal = geometry_from_mapping(live, f'{args.bag}: the recorded nominal')
            print(f'  nominal geometry: as recorded by the live run in {args.bag}')
        live_description = (recorded or {}).get('description')
        if live_description and not description:
            print(f'  the live run was gated by the machine description '
                  f'{live_description["file"]}: pass --description to gate this one the same '
                  f'way (here: the built-in gate)')
    else:
        data = (description.read(args.data) if description
                else read_in_si(PoseData.from_csv, args.data, actuators=FEED_COLUMNS))
    result = identify(data, nominal)
    report = result.report()
    if description:
        report['description'] = description.gate_report()
        print(f'  machine description {description.source}: {description.expected_text()}')
    if args.bag:
        report['evaluation'] = evaluate(stops)
        for phase, row in report['evaluation'].items():
            print(f'  {phase}: composite mark error (tracker) median {row["median_m"] * 1e6:.1f} '
                  f'um, max {row["max_m"] * 1e6:.1f} um over {row["poses"]} poses')
    if recorded is not None:
        live = np.array([recorded['parameters'][n] for n in report['parameters']])
        report['max_difference_to_live'] = float(np.abs(live - result.geometry.vector()).max())
        print(f'  same as the live run: max |difference| {report["max_difference_to_live"]:.3g} '
              '(SI units)')
    print(f'{len(data)} poses; closure residual RMS {report["residual_rms_m"] * 1e6:.2f} um, '
          f'max {report["residual_max_m"] * 1e6:.2f} um; condition per chain '
          + ', '.join(f'{c:.3g}' for c in result.condition))
    for name, value in report['parameters'].items():
        print(f'  {name:>7} = {quantity(value, report["std_devs"][name], report["units"][name])}')
    check_identification(result, nominal, description,
                         likely_causes(data, description) if description else None)
    if args.out:
        write_geometry(args.out, result.geometry, {'std_devs': report['std_devs']})
        print(f'wrote {args.out}')
    write_report(args.json, report)
    return 0


def read_targets(path) -> np.ndarray:
    """x, y (m), theta (rad) per row."""
    rows = read_csv_rows(path, 'a targets CSV', ('x', 'y', 'theta'))
    try:
        targets = np.array([[float(r['x']), float(r['y']), float(r['theta'])] for r in rows])
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInputError(f'{path} needs numeric columns x, y (m), theta (rad) ({exc!r})') from None
    if not len(targets) or not np.all(np.isfinite(targets)):
        raise InvalidInputError(f'{path}: no targets, or NaN in them')
    return targets


def _plot(path: Path, targets, before, after, method, history) -> None:
    """The composite error the model predicts before and after over the targets (um, one
    log scale), and, for the swarm, its best cost against iterations."""
    fig, axes = plt.subplots(1, 2 if history else 1, figsize=(12 if history else 7, 4.4),
                             squeeze=False)
    axis = axes[0, 0]
    order = np.argsort(before)
    axis.semilogy(np.arange(len(order)), before[order] * 1e6, 'o', color='C3',
                  label='nominal commands (model prediction)')
    shown = after[order] > 1e-9            # under a nanometre is the solver's round-off
    if np.any(shown):
        axis.semilogy(np.flatnonzero(shown), after[order][shown] * 1e6, 's', color='C2',
                      label=f'{method} feeds (model prediction)')
    if not np.all(shown):
        why = 'at 0 by construction' if method == 'exact' else 'predicted below 1 nm'
        axis.text(0.98, 0.04, f'{method} feeds: {np.sum(~shown)} target(s) {why}\n'
                              '(under 1 nm, not drawn)',
                  transform=axis.transAxes, fontsize=8, ha='right',
                  bbox={'facecolor': 'white', 'edgecolor': 'none'})
    axis.set_xlabel('target (sorted by the error with nominal commands)')
    axis.set_ylabel("composite mark error |AA'| + |BB'| (um, log)")
    axis.set_title('what the identified model predicts (not a measurement)', fontsize=10)
    axis.legend(fontsize=8)
    if history:
        for k, h in enumerate(history[:20]):
            axes[0, 1].semilogy(np.arange(1, len(h) + 1), np.maximum(h, 1e-12) * 1e6,
                                color='C0', alpha=0.4,
                                label='best cost, one target' if k == 0 else None)
        axes[0, 1].set_xlabel('swarm iteration')
        axes[0, 1].set_ylabel('best composite error (um, log)')
        axes[0, 1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def cmd_compensate_platform(args) -> int:
    nominal = read_geometry(args.nominal) if args.nominal else nominal_geometry()
    model = read_geometry(args.geometry)
    targets = read_targets(args.targets) if args.targets else plan_poses(args.count, args.seed)
    settings = (PSOSettings.stable(args.seed, args.iterations or 200) if args.swarm == 'stable'
                else PSOSettings(seed=args.seed, iterations=args.iterations or 4))
    rows, history = [], []
    for target in targets:
        result = compensate(model, nominal, target, args.method, pso=settings)
        before = composite_error(forward(model, inverse(nominal, target[None]), target[None]),
                                 target[None])[0]
        rows.append({'target': [float(v) for v in target],
                     'feeds_m': [float(v) for v in result.feeds],
                     'corrections_m': [float(v) for v in result.feeds
                                       - inverse(nominal, target[None])[0]],
                     'predicted_before_m': float(before),
                     'predicted_after_m': result.predicted_error,
                     'seconds': result.seconds, 'converged': result.converged,
                     'message': result.message})
        history.append(result.history)
    before = np.array([r['predicted_before_m'] for r in rows])
    after = np.array([r['predicted_after_m'] for r in rows])
    unconverged = [k for k, r in enumerate(rows) if not r['converged']]
    print(f'{len(rows)} targets, method {args.method}, {np.mean([r["seconds"] for r in rows]) * 1e3:.2f} '
          f'ms per target. The identified model predicts the marks (composite error) off by '
          f'{np.median(before) * 1e6:.1f} um (median) with the nominal commands and by '
          f'{np.median(after) * 1e6:.3f} um (worst {after.max() * 1e6:.3f} um) with these '
          'feeds: the model checking itself, not a measurement'
          + (' (0 by construction for the exact inverse)' if args.method == 'exact' else '')
          + '. On the machine the error left is the identification\'s: see calibrate '
          'platform\'s held-out evaluation or plan platform\'s prediction.')
    if unconverged:
        print(f'  NOT CONVERGED for {len(unconverged)} target(s) (e.g. target {unconverged[0]}: '
              f'{rows[unconverged[0]]["message"]}): do not use these feeds')
    report = {'method': args.method, 'screen_m': list(SCREEN), 'targets': rows,
              'pso': vars(settings) if args.method == 'pso' else None,
              'pso_order2_stable': settings.order2_stable() if args.method == 'pso' else None}
    write_report(args.json, report, lambda png: _plot(
        png, targets, before, after, args.method, [h for h in history if h]))
    if args.csv:
        write_columns(args.csv, ['x_m', 'y_m', 'theta_rad', 'feed1_m', 'feed2_m', 'feed3_m',
                                 'converged'],
                      [np.array([r['target'] for r in rows]),
                       np.array([r['feeds_m'] for r in rows]),
                       np.array([float(r['converged']) for r in rows])])
        print(f'wrote {args.csv} (per target: x, y in m, theta in rad, the three feeds in m, '
              f'converged 1 or 0)')
    return 2 if unconverged else 0
