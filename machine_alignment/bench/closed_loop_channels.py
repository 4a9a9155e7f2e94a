"""`make bench` part: the closed loop's decisions per channel on the 3-PRR platform
(issue 30), over 20 seeds each. Writes bench_results/closed_loop_channels.{json,md}.

Cases (200 poses, 10 um of ball-screw periodic error with a 3.2 mm lead where present,
the platform's own noise): the error on feed 2 only, on every feed, and none. Counted per
run: whether the periodic error was added on exactly the feeds that have it (detection),
any effect or channel claimed where the truth has none (wrong claims), the period's error
against its own sigma, and the held-out RMS after over the clean run's (same seed)."""
from __future__ import annotations

from pathlib import Path

from calib_core.closed_loop import LoopConfig, analyze
from machine_alignment.bench import detection_case, main_with_out, write_results, write_table
from platform_calib.core.geometry import nominal_geometry
from platform_calib.core.loop_model import PlatformLoopModel
from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry

SEEDS = range(20)
POSES = 200
LEAD = 3.2e-3
AMPLITUDE = 10e-6
CASES = {'feed 2 only': (0.0, AMPLITUDE, 0.0), 'every feed': (AMPLITUDE,) * 3,
         'clean': (0.0, 0.0, 0.0)}
FEEDS = ('feed1', 'feed2', 'feed3')


def _report(seed: int, amplitudes) -> dict:
    nominal = nominal_geometry()
    sim = PlatformSim(true_geometry(seed, 0.15), seed, lead=LEAD, screw_amplitude=amplitudes)
    data = measure_poses(sim, plan_poses(POSES, seed), nominal)
    return analyze(PlatformLoopModel(data, nominal), LoopConfig()).report


def _judge(report: dict, amplitudes) -> dict:
    truth = {f for f, a in zip(FEEDS, amplitudes) if a}
    added = {e['name']: e for e in report['effects_added']}
    periodic = added.get('periodic')
    feeds = {f for f in FEEDS if periodic and f'period_{f}' in periodic['parameters']}
    period_sigmas = [abs(periodic['parameters'][f'period_{f}'] - LEAD)
                     / periodic['std_devs'][f'period_{f}'] for f in feeds & truth]
    return {'found': bool(truth) and feeds == truth,
            'wrong_claims': len(feeds - truth) + len(set(added) - {'periodic'})
            + (0 if truth else len(added)),
            'feeds_missed': sorted(truth - feeds),
            'period_error_sigmas': period_sigmas,
            'rms_after': report['rms_after'], 'rms_before': report['rms_before']}


def run(out: Path) -> dict:
    results = {}
    clean_after = {}
    for case, amplitudes in sorted(CASES.items(), key=lambda c: c[0] != 'clean'):
        summary = detection_case(case, SEEDS, lambda seed: _report(seed, amplitudes),
                                 lambda report: _judge(report, amplitudes), clean_after)
        sigmas = [s for r in summary['per_run'] for s in r['period_error_sigmas']]
        results[case] = dict(
            summary, feeds_missed=sum(len(r['feeds_missed']) for r in summary['per_run']),
            largest_period_error_sigmas=max(sigmas) if sigmas else None)
    write_results(out, 'closed_loop_channels', results)
    lines = [f'Platform, {POSES} poses, ball-screw periodic error {AMPLITUDE * 1e6:g} um with a '
             f'{LEAD * 1e3:g} mm lead; {len(SEEDS)} seeds per case (seeds {SEEDS.start}-'
             f'{SEEDS.stop - 1}).', '',
             '| case | found on exactly the true feeds | wrong claims | feeds missed | '
             'largest period error (sigma) | held-out RMS after / clean floor (median) | '
             'CPU per run (median) |', '|---|---|---|---|---|---|---|']
    for case, r in results.items():
        found = '' if case == 'clean' else f'{r["found"]} of {r["runs"]}'
        largest = ('' if r['largest_period_error_sigmas'] is None
                   else f'{r["largest_period_error_sigmas"]:.2f}')
        lines.append(f'| {case} | {found} | {r["wrong_claims"]} | {r["feeds_missed"]} | '
                     f'{largest} | {r["median_after_over_floor"]:.3f} | '
                     f'{r["median_cpu_s"]:.1f} s |')
    write_table(out, 'closed_loop_channels', lines)
    return results


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    raise SystemExit(main())
