"""`make bench` part: CPU time of the closed loop per machine, the first-order fits
(calib_core.closed_loop.linearised, today's default where the machine asks for it)
against the full model's fits in the same run (the loop as it was before), and whether
both decide the same. Writes bench_results/closed_loop_speed.{json,md}.

Each case is one recorded or simulated run of the suite: the CPU time is
``time.process_time`` of :func:`analyze` with its default configuration (5 hold-out
splits, 5 folds), the model built beforehand."""
from __future__ import annotations

import time
from pathlib import Path


from calib_core.axis import AxisData, AxisModel
from calib_core.closed_loop import LoopConfig, MachineModel, analyze
from calib_core.storage import write_atomic
from dispenser_calib.core.loop_model import RotaryLoopModel
from dispenser_calib.core.target_poses import read_target_poses
from machine_alignment.bench import main_with_out, write_results
from machine_alignment.bench.closed_loop import _camera, _gantry, _hexapod, _stage
from platform_calib.core.geometry import nominal_geometry
from platform_calib.core.loop_model import PlatformLoopModel
from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry
from printer_alignment.sim.gantry import GantryErrors

MEASURED = Path(__file__).resolve().parents[2] / 'test' / 'data' / 'measured'


def _platform():
    nominal = nominal_geometry()
    sim = PlatformSim(true_geometry(1, 0.15), 1, lead=3.2e-3, screw_amplitude=(0, 10e-6, 0))
    return PlatformLoopModel(measure_poses(sim, plan_poses(200, 1), nominal), nominal)


CASES = [
    ('stage', 'simulated calibration run, chain backlash 3 / 4 / 2.5 um',
     lambda: _stage(True, 3)),
    ('rotary axes', 'real two-axis positioner, 205 poses (ric_two_axis_positioner)',
     lambda: RotaryLoopModel(read_target_poses(
         MEASURED / 'ric_two_axis_positioner' / 'positioner_poses.csv', 'j1', 'j2'))),
    ('hexapod', '200 simulated poses, leg play 8.3-9.9 um', lambda: _hexapod(True, 3)),
    ('platform', '200 simulated poses, 10 um screw error on feed 2', _platform),
    ('axis', 'real ISO 230-2 run a (ecmc_iso230_2)',
     lambda: AxisModel(AxisData.from_csv(MEASURED / 'ecmc_iso230_2' / 'mcu1025_run_a.csv'))),
    ('gantry', 'simulated positions, squareness, backlash, screw error',
     lambda: _gantry(GantryErrors(), 3)),
    ('camera', 'simulated plate views, radial distortion',
     lambda: _camera((-0.25, 0.08, 0, 0), 3)),
]


def analyze_as_before(machine: MachineModel):
    """The loop before the speed work on ``machine``: full fits with dense finite
    differences (the machine's Jacobian sparsity withheld, which changes ``machine``)."""
    machine.base_sparsity = lambda base, rows: None
    return analyze(machine, LoopConfig(linearise=False))


def _timed(machine, fast: bool):
    """CPU s and report of the loop; not ``fast``: :func:`analyze_as_before`."""
    start = time.process_time()
    report = (analyze(machine) if fast else analyze_as_before(machine)).report
    return time.process_time() - start, report


def _largest_difference(fast: dict, full: dict) -> float | None:
    """Largest |fast - full| over the parameters of the effects both added, in the full
    fit's sigmas; None when they added different effects."""
    if [e['name'] for e in fast['effects_added']] != [e['name'] for e in full['effects_added']]:
        return None
    ratios = [abs(a['parameters'][n] - v) / b['std_devs'][n]
              for a, b in zip(fast['effects_added'], full['effects_added'])
              for n, v in b['parameters'].items() if b['std_devs'][n] > 0]
    return float(max(ratios, default=0.0))


def run(out: Path) -> dict:
    rows = []
    for machine_name, data, make in CASES:
        machine = make()
        fast_time, fast = _timed(machine, True)
        full_time, full = _timed(make(), False)
        sparse = type(machine).base_sparsity is not MachineModel.base_sparsity
        rows.append({'machine': machine_name, 'data': data, 'rows': len(machine),
                     'linearised': bool(machine.linearise), 'sparse_jacobian': sparse,
                     'cpu_s': fast_time, 'cpu_s_full_fits': full_time,
                     'speed_up': full_time / fast_time,
                     'added': [e['name'] for e in fast['effects_added']],
                     'added_full_fits': [e['name'] for e in full['effects_added']],
                     'largest_difference_sigma': _largest_difference(fast, full),
                     'rms_after': fast['rms_after'], 'rms_after_full_fits': full['rms_after'],
                     'unit': fast['unit']})
        print(f'{machine_name:12} {len(machine):4} rows: {fast_time:6.1f} s CPU, full fits '
              f'{full_time:6.1f} s ({full_time / fast_time:.1f}x), added {rows[-1]["added"]}',
              flush=True)
    results = {'cases': rows, 'cores': 2,
               'note': 'CPU seconds of analyze() with LoopConfig() defaults; full fits: '
                       'LoopConfig(linearise=False) and dense finite differences, the loop '
                       'before the first-order and sparse fits'}
    write_results(out, 'closed_loop_speed', results)
    lines = ['| machine | data | rows | fits | CPU s | CPU s, full fits | ratio | added (both) | '
             'largest difference | held-out RMS after |', '|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        scale, unit = (1e6, 'um') if r['unit'] == 'm' else (1.0, r['unit'])
        same = ', '.join(r['added']) or 'nothing'
        if r['added'] != r['added_full_fits']:
            same = f'{same} (full fits: {", ".join(r["added_full_fits"]) or "nothing"})'
        difference = ('effects differ' if r['largest_difference_sigma'] is None
                      else f'{r["largest_difference_sigma"]:.3f} sigma')
        how = ('first order' if r['linearised'] else 'grouped differences'
               if r['sparse_jacobian'] else 'as before')
        lines.append(f'| {r["machine"]} | {r["data"]} | {r["rows"]} | {how} | {r["cpu_s"]:.1f} | '
                     f'{r["cpu_s_full_fits"]:.1f} | {r["speed_up"]:.1f} | {same} | {difference} | '
                     f'{r["rms_after"] * scale:.3g} {unit} |')
    write_atomic(out / 'closed_loop_speed.md', '\n'.join(lines) + '\n')
    return results


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    raise SystemExit(main())
