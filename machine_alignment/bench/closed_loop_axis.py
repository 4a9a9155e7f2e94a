"""`make bench` part: the closed loop on real ISO 230-2 runs and on real-world-shaped
simulated axis tests. Writes bench_results/closed_loop_axis.{json,md}.

- Real runs (test/data/measured/ecmc_iso230_2): what the loop names, each effect's
  selection frequency over the hold-out splits, held-out RMS and max before and after,
  what it declares not identifiable or rejects, and the ISO 230-2 figures before and after.
- Sparse regular grids (5, 8, 12 targets over 200 mm, 5 bidirectional cycles) with no
  screw error, a 16 mm one (unresolvable on every grid) and an 80 mm one (resolvable on 8
  and 12 targets), 100 seeds each: how often a periodic error is claimed.
- Clean data: 200 runs of the default axis test, 100 of encoder-like data (10 nm noise).
"""
from __future__ import annotations

import argparse
from pathlib import Path

from calib_core.axis import AxisData, AxisModel, iso230_2_before_after
from calib_core.closed_loop import LoopConfig, analyze
from calib_core.sim.axis import AxisTest, AxisTruth, simulate_axis_test
from calib_core.storage import write_atomic
from machine_alignment.bench import write_results

MEASURED = Path(__file__).resolve().parents[2] / 'test' / 'data' / 'measured' / 'ecmc_iso230_2'
REAL_RUNS = {'mcu1025_run_a': 'stepper axis, laser triangulation sensor, 5 targets x 5 cycles',
             'mcu1025_run_b': 'the same axis, a second run',
             'sls_encoder_vs_encoder': 'encoder read against an encoder (nothing physical)'}


def _real(name: str) -> dict:
    model = AxisModel(AxisData.from_csv(MEASURED / f'{name}.csv'))
    result = analyze(model)
    report = result.report
    iso = iso230_2_before_after(model, result.fit)
    return {'data': name, 'what': REAL_RUNS[name],
            'added': {e['name']: e['evidence']['selection_frequency']
                      for e in report['effects_added']},
            'selection_frequency': report['selection_frequency'],
            'rms_before': report['rms_before'], 'rms_after': report['rms_after'],
            'max_before': report['max_before'], 'max_after': report['max_after'],
            'held_out_by_split': report['held_out_by_split'],
            'not_identifiable': report['not_identifiable'], 'rejected': report['rejected'],
            'not_tested': report['skipped'], 'outlier_rows': [o['row'] for o in report['outliers']['rows']],
            'unexplained': [f'{u["kind"]} against {u["covariate"]}' for u in report['unexplained']],
            'iso230_2': {k: iso[k]['bidirectional'] for k in ('before', 'after_linear', 'after')},
            'iso_method': iso['method']}


def _simulated(truth_kwargs: dict, test_kwargs: dict, seeds) -> list:
    out = []
    for seed in seeds:
        data = simulate_axis_test(AxisTruth(**truth_kwargs), AxisTest(**test_kwargs), seed=seed)
        report = analyze(AxisModel(data), LoopConfig(seed=seed)).report
        out.append({'added': [e['name'] for e in report['effects_added']],
                    'periods': [e['parameters'].get('period_axis') for e in report['effects_added']
                                if e['name'] == 'periodic'],
                    'unexplained': len(report['unexplained']),
                    'rms_after': report['rms_after']})
    return out


def run(out: Path, seeds: int = 100) -> dict:
    real = [_real(name) for name in REAL_RUNS]
    for r in real:
        print(f'{r["data"]:24} added {r["added"]}, held-out RMS {r["rms_before"] * 1e6:.3g} -> '
              f'{r["rms_after"] * 1e6:.3g} um')
    sparse = []
    for targets in (5, 8, 12):
        for label, truth in (('none', {}), ('16 mm, 2 um', {'periodic_amplitude': 2e-6, 'pitch': 0.016}),
                             ('80 mm, 3 um', {'periodic_amplitude': 3e-6, 'pitch': 0.08})):
            runs = _simulated(truth, {'targets': targets, 'irregular': False}, range(seeds))
            spacing = 0.2 / (targets - 1)
            resolvable = label.startswith('80') and 2 * spacing <= 0.08
            claimed = sum('periodic' in r['added'] for r in runs)
            right = sum(any(abs(p - 0.08) < 0.004 for p in r['periods']) for r in runs)
            sparse.append({'targets': targets, 'screw_error': label, 'resolvable': resolvable,
                           'runs': len(runs), 'periodic_claimed': claimed,
                           'periodic_right_period': right,
                           'wrong_claims': claimed - (right if resolvable else 0)})
            print(f'{targets:2} targets, screw error {label:12}: periodic claimed in {claimed} '
                  f'of {len(runs)} ({right} at the true period)')
    clean = {}
    for label, truth, count in (('default test (0.3 um noise, 0.5 K rise)', {'temperature_rise': 0.5}, 2 * seeds),
                                ('encoder-like (10 nm noise)', {'offset': 0.0, 'scale': 0.0, 'noise': 10e-9}, seeds)):
        runs = _simulated(truth, {}, range(1000, 1000 + count))
        clean[label] = {'runs': count, 'with_an_effect': sum(bool(r['added']) for r in runs),
                        'with_unexplained': sum(bool(r['unexplained']) for r in runs)}
        print(f'clean, {label}: {clean[label]}')
    results = {'real': real, 'sparse_grids': sparse, 'clean': clean}
    write_results(out, 'closed_loop_axis', results)
    write_atomic(out / 'closed_loop_axis.md', _markdown(results))
    return results


def _um(value) -> str:
    return 'n/a' if value is None else f'{value * 1e6:.3g}'


def _markdown(results: dict) -> str:
    lines = ['| real run | added (chosen in splits) | held-out RMS before -> after | held-out max before -> after | ISO 230-2 B / E / M / R as measured -> after (um) | not identifiable, rejected, not tested |',
             '|---|---|---|---|---|---|']
    for r in results['real']:
        added = ', '.join(f'{k} ({v:.0%})' for k, v in r['added'].items()) or 'nothing'
        before, after = r['iso230_2']['before'], r['iso230_2']['after']
        notes = [f'{k}: not identifiable' for k in r['not_identifiable']]
        notes += [f'{k}: rejected' for k in r['rejected']]
        notes += [f'{k}: {v.split(":")[0]}' for k, v in r['not_tested'].items()]
        lines.append(f'| {r["data"]} ({r["what"]}) | {added} | {_um(r["rms_before"])} -> '
                     f'{_um(r["rms_after"])} um | {_um(r["max_before"])} -> {_um(r["max_after"])} um | '
                     + ' / '.join(_um(before[k]) for k in 'BEMR') + ' -> '
                     + ' / '.join(_um(after[k]) for k in 'BEMR') + f' | {"; ".join(notes)} |')
    lines += ['', '| targets (regular, 200 mm) | screw error | resolvable | runs | periodic claimed | at the true period | wrong claims |',
              '|---|---|---|---|---|---|---|']
    lines += [f'| {s["targets"]} | {s["screw_error"]} | {"yes" if s["resolvable"] else "no"} | '
              f'{s["runs"]} | {s["periodic_claimed"]} | {s["periodic_right_period"]} | '
              f'{s["wrong_claims"]} |' for s in results['sparse_grids']]
    lines += ['', '| clean axis data | runs | with an effect added | with unexplained structure |',
              '|---|---|---|---|']
    lines += [f'| {k} | {v["runs"]} | {v["with_an_effect"]} | {v["with_unexplained"]} |'
              for k, v in results['clean'].items()]
    return '\n'.join(lines) + '\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--out', default='bench_results')
    parser.add_argument('--seeds', type=int, default=100)
    args = parser.parse_args(argv)
    run(Path(args.out), args.seeds)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
