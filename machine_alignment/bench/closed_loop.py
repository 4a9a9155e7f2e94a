"""`make bench` part: the closed loop on every simulated machine, with the effect the
model lacks and without it. Writes bench_results/closed_loop.{json,md}.

For each case: the effects found, the held-out RMS before (base model) and after, and the
noise floor: the held-out RMS after on the same machine without the undeclared effects
(same seeds). False-positive rate: clean data over many seeds, any effect added or any
structure reported counts."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from calib_core.axis import AxisModel
from calib_core.closed_loop import LoopConfig, analyze
from calib_core.sim.axis import AxisTruth, simulate_axis_test
from calib_core.storage import write_atomic
from hexapod_calib.core.geometry import nominal_geometry
from hexapod_calib.core.loop_models import HexapodLoopModel
from hexapod_calib.sim.hexapod import TALL_PAYLOAD_CENTRE, HexapodTruth, measure_random_poses
from machine_alignment.bench import main_with_out, write_results
from printer_alignment.core.loop_models import CameraLoopModel, GantryLoopModel, StageLoopModel
from printer_alignment.sim.camera import tilted_plate_views
from printer_alignment.sim.gantry import GantryErrors, measure_random_positions
from printer_alignment.sim.stage import TRUE_STAGE, simulate_calibration_run


def _axis(truth_kwargs: dict, seed: int):
    return AxisModel(simulate_axis_test(AxisTruth(**truth_kwargs), seed=seed))


def _gantry(errors, seed: int):
    return GantryLoopModel(measure_random_positions(errors, seed=seed))


CAMERA = np.array([[800.0, 0, 322], [0, 805, 236], [0, 0, 1]])


def _camera(distortion, seed: int):
    return CameraLoopModel(tilted_plate_views(CAMERA, distortion, noise_px=0.05, seed=seed),
                           (640, 480))


def _hexapod(play: bool, seed: int, force_to_close_play: float = 5.0):
    nominal = nominal_geometry()
    truth = dataclasses.replace(HexapodTruth.default(nominal, 2),
                                payload_centre=TALL_PAYLOAD_CENTRE,
                                force_to_close_play=force_to_close_play)
    if not play:
        truth = dataclasses.replace(truth, leg_play=np.zeros(6))
    data, forces = measure_random_poses(truth, 200, seed, nominal)
    return HexapodLoopModel(data, nominal, forces)


def _stage(backlash: bool, seed: int):
    truth = TRUE_STAGE if backlash else dataclasses.replace(TRUE_STAGE, backlash=(0.0, 0.0, 0.0))
    return StageLoopModel(simulate_calibration_run(truth, seed=seed))


def _cases():
    ideal = GantryErrors.ideal()
    no_screw = dataclasses.replace(GantryErrors(), backlash_x=0.0, backlash_y=0.0,
                                   periodic_amplitude_x=0.0, periodic_amplitude_y=0.0,
                                   model=dataclasses.replace(GantryErrors().model,
                                                             non_orthogonality=0.0))
    return [
        ('axis', 'reversal (backlash 4 um)', lambda s: _axis({'backlash': 4e-6}, s),
         lambda s: _axis({}, s)),
        ('axis', 'periodic (1.5 um, 16 mm pitch)',
         lambda s: _axis({'periodic_amplitude': 1.5e-6}, s), lambda s: _axis({}, s)),
        ('axis', 'reversal + periodic', lambda s: _axis({'backlash': 3e-6,
                                                         'periodic_amplitude': 1e-6}, s),
         lambda s: _axis({}, s)),
        ('axis', 'drift_temperature (11.5e-6/K, 1 K)',
         lambda s: _axis({'expansion': 11.5e-6, 'temperature_rise': 1.0}, s),
         lambda s: _axis({'temperature_rise': 1.0}, s)),
        ('gantry', 'squareness + reversal (4 / 6 um) + periodic (1.5 / 2 um)',
         lambda s: _gantry(GantryErrors(), s), lambda s: _gantry(no_screw, s)),
        ('camera', 'radial_distortion (k1 -0.25, k2 0.08)',
         lambda s: _camera((-0.25, 0.08, 0, 0), s), lambda s: _camera((0, 0, 0, 0), s)),
        ('camera', 'radial + tangential_distortion',
         lambda s: _camera((-0.25, 0.08, 1e-3, -8e-4), s), lambda s: _camera((0, 0, 0, 0), s)),
        ('stage', 'reversal (chain backlash 3 / 4 / 2.5 um)', lambda s: _stage(True, s),
         lambda s: _stage(False, s)),
        ('hexapod', 'leg_play (8.3-9.9 um)', lambda s: _hexapod(True, s),
         lambda s: _hexapod(False, s)),
        ('hexapod', 'leg_play closed by the load sign alone (0 N)',
         lambda s: _hexapod(True, s, 0.0), lambda s: _hexapod(False, s, 0.0)),
    ], {'axis': (lambda s: _axis({'temperature_rise': 0.5}, s), 200),
        'gantry': (lambda s: _gantry(ideal, s), 30),
        'camera': (lambda s: _camera((0, 0, 0, 0), s), 15),
        'stage': (lambda s: _stage(False, s), 30),
        'hexapod': (lambda s: _hexapod(False, s), 10)}


def run(out: Path) -> dict:
    cases, clean = _cases()
    rows = []
    for machine, effect, with_effect, without in cases:
        report = analyze(with_effect(3)).report
        floor = analyze(without(3)).report
        rows.append({'machine': machine, 'effect': effect,
                     'found': [e['name'] for e in report['effects_added']],
                     'unit': report['unit'], 'rms_before': report['rms_before'],
                     'rms_after': report['rms_after'], 'noise_floor': floor['rms_after'],
                     'after_over_floor': report['rms_after'] / floor['rms_after'],
                     'held_out': report['rows']['held_out']})
        print(f'{machine:8} {effect:55} found {rows[-1]["found"]}, after/floor '
              f'{rows[-1]["after_over_floor"]:.2f}')
    false_positives = {}
    for machine, (make, seeds) in clean.items():
        hits = 0
        for seed in range(seeds):
            report = analyze(make(100 + seed), LoopConfig(seed=seed)).report
            hits += bool(report['effects_added'] or report['unexplained'])
        false_positives[machine] = {'runs': seeds, 'with_a_finding': hits}
        print(f'{machine:8} clean data: {hits} of {seeds} runs added or reported something')
    results = {'cases': rows, 'false_positives': false_positives,
               'note': 'held-out RMS: residual norm per row (axis, gantry: m; camera: px) or '
                       'per leg (hexapod: m); noise floor: the same seed without the '
                       'undeclared effects'}
    write_results(out, 'closed_loop', results)
    lines = ['| machine | undeclared effect | found | before | after | noise floor | after / floor | held-out rows |',
             '|---|---|---|---|---|---|---|---|']
    for r in rows:
        scale, unit = (1e6, 'um') if r['unit'] == 'm' else (1.0, 'px')
        lines.append(f'| {r["machine"]} | {r["effect"]} | {", ".join(r["found"]) or "nothing"} | '
                     f'{r["rms_before"] * scale:.3g} {unit} | {r["rms_after"] * scale:.3g} {unit} | '
                     f'{r["noise_floor"] * scale:.3g} {unit} | {r["after_over_floor"]:.2f} | '
                     f'{r["held_out"]} |')
    lines += ['', '| clean data | runs | runs with a finding |', '|---|---|---|']
    lines += [f'| {m} | {v["runs"]} | {v["with_a_finding"]} |' for m, v in false_positives.items()]
    write_atomic(out / 'closed_loop.md', '\n'.join(lines) + '\n')
    return results


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    raise SystemExit(main())
