"""Which stops determine the five-axis dispenser's E_B0A and E_B0C (issue 32): the
predicted 1-sigma of every ISO 230-7 location and orientation error and of the part's
placement at the working poses, for plan variants and for the planner's own choice of the
same number of stops (dispenser_calib.core.planning, planned at the nominal model), from
the identification Jacobian (dots detected to 0.1 px) before anything moves, and the same
plans measured on 20 simulated machines. Writes bench_results/plan_five_axis.{md,json,png}."""
import textwrap
import time
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from calib_core.figures import save_figure  # noqa: E402
from dispenser_calib.core.calibration import calibrate
from dispenser_calib.core.iso230 import ORIENTATION, iso230_7
from dispenser_calib.core.model import NAMES, DispenserModel, nominal_model, place
from dispenser_calib.core.planning import (
    DEPTH_OF_FIELD, WORKING_POSES, candidate_stops, placement_error, plan_five_axis, predict)
from dispenser_calib.core.procedure import (
    WORKING_DISTANCE, check_stroke, evaluation_stops, plan_stops)
from dispenser_calib.sim.machine import IMAGE_SIZE, observe, true_model
from machine_alignment.bench import main_with_out, write_results, write_table

NOISE_PX = 0.1
MACHINES = 20
WATCHED = ('E_B0A', 'E_B0C')
CENTRE = np.array([0.0, 0.0, WORKING_DISTANCE])


def _alone(a_values=(), c_values=(), a_for_c: float = 0.0) -> list:
    nominal = nominal_model(size=IMAGE_SIZE)
    return ([place(nominal, np.zeros(3), a, 0.0, CENTRE) for a in np.deg2rad(a_values)]
            + [place(nominal, np.zeros(3), np.deg2rad(a_for_c), c, CENTRE)
               for c in np.deg2rad(c_values)])


def _spread_z(linear: np.ndarray, reach: float) -> np.ndarray:
    """The linear stops with Z spread evenly over +-``reach`` (m) about where they were."""
    spread = linear.copy()
    spread[:, 2] += np.linspace(-reach, reach, len(linear))
    return spread


def plans() -> dict:
    nominal = nominal_model(size=IMAGE_SIZE)
    today = plan_stops(nominal, 0)
    linear = today[:12]
    c_turn = np.arange(30, 360, 30)
    variants = {
        "today's 27 stops (12 linear, A alone at 4 tilts, C alone at 11 angles)": today,
        'today + 6 stops with A and C both turned': np.vstack(
            [today, evaluation_stops(nominal, 6, 9)]),
        'today, A alone at 8 tilts up to +-80 deg (beyond the detector\'s view)': np.vstack(
            [linear, _alone((-80, -60, -40, -20, 20, 40, 60, 80), c_turn)]),
        'today, C turned again with A at +30 and -30 deg': np.vstack(
            [today, _alone((), c_turn, 30.0), _alone((), c_turn, -30.0)]),
        'today, the 12 linear stops spread over Z +-40 mm (out of focus)': np.vstack(
            [_spread_z(linear, 40e-3), today[12:]]),
        'today + 12 linear stops over Z +-40 mm (out of focus)': np.vstack(
            [today, _spread_z(linear, 40e-3)]),
        'today twice (54 stops, the noise halved in variance)': np.vstack([today, today]),
    }
    planning_seconds = {}
    for criterion, depth in (('I', DEPTH_OF_FIELD), ('D', DEPTH_OF_FIELD), ('I', 40e-3)):
        start = time.perf_counter()
        plan = plan_five_axis(nominal, len(today), IMAGE_SIZE, criterion, NOISE_PX,
                              depth_of_field=depth)
        if depth == DEPTH_OF_FIELD:
            planning_seconds[criterion] = time.perf_counter() - start
        kinds = ', '.join(f'{plan.kinds.count(k)} {k}' for k in ('linear', 'a', 'c', 'both'))
        beyond = '' if depth == DEPTH_OF_FIELD else f', Z +-{depth * 1e3:g} mm: out of focus'
        variants[f'planned {len(today)} stops, {criterion} ({kinds}{beyond})'] = plan.stops
    for stops in variants.values():
        for pose in stops:
            check_stroke(pose)
    return variants, planning_seconds


def predicted(truth: DispenserModel, stops) -> dict:
    """1-sigma of every ISO 230-7 error (rad, m) and parameter, and the working error's RMS
    (m)."""
    prediction = predict(truth, stops, IMAGE_SIZE, NOISE_PX)
    return {**prediction['iso230_7_sigmas'], 'working_m': prediction['working_error_m']['rms'],
            'parameters': prediction['parameter_sigmas']}


def realised(stops, machines: int = MACHINES) -> dict:
    """RMS over ``machines`` simulated machines of the identified minus true value of every
    ISO 230-7 error and parameter, and of the working error."""
    errors, parameters = {}, []
    for seed in range(machines):
        truth = true_model(seed)
        images, _ = observe(truth, stops, noise_px=NOISE_PX, seed=seed)
        _, result = calibrate(images, IMAGE_SIZE)
        found, true = iso230_7(result.model), iso230_7(truth)
        for name in found:
            errors.setdefault(name, []).append(found[name] - true[name])
        errors.setdefault('working_m', []).append(placement_error(result.model, truth))
        parameters.append(result.model.values - truth.values)
    rms = {name: float(np.sqrt(np.mean(np.square(v)))) for name, v in errors.items()}
    return {**rms, 'parameters': dict(zip(NAMES, np.sqrt(np.mean(np.square(parameters), 0))))}


def _ratio_range(r: dict) -> tuple[float, float, float]:
    """Realised over predicted per parameter: median, smallest, largest."""
    ratio = [r['realised_rms']['parameters'][n] / r['predicted']['parameters'][n]
             for n in NAMES]
    return float(np.median(ratio)), float(np.min(ratio)), float(np.max(ratio))


def plot(path: Path, results: dict) -> None:
    """Predicted against realised per plan, E_B0A (mrad) and the part's placement (um),
    each on one scale for every plan."""
    names = [n for n in results if n != 'planning_seconds']
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.55 * len(names) + 1.6), sharey=True)
    rows = np.arange(len(names))
    for ax, key, factor, unit in ((axes[0], 'E_B0A', 1e3, 'mrad'),
                                  (axes[1], 'working_m', 1e6, 'um')):
        predicted = [results[n]['predicted'][key] * factor for n in names]
        realised = [results[n]['realised_rms'][key] * factor for n in names]
        ax.barh(rows - 0.2, predicted, 0.4, label='predicted before anything moves (1 sigma)',
                color='0.7')
        ax.barh(rows + 0.2, realised, 0.4, label=f'realised, RMS over {MACHINES} machines',
                color='tab:blue')
        ax.set_xlabel(f'{"E_B0A" if key == "E_B0A" else "part placement at the working poses"}'
                      f' ({unit})')
        ax.grid(axis='x', alpha=0.3)
    axes[0].set_yticks(rows, [textwrap.fill(n, 48) for n in names], fontsize=8)
    axes[0].invert_yaxis()
    axes[1].legend(loc='lower right', fontsize=8)
    fig.suptitle('Five-axis plans: E_B0A and the part\'s placement, predicted before anything '
                 'moves and realised')
    fig.tight_layout()
    save_figure(fig, path, [__file__])
    plt.close(fig)


def run(out: Path) -> dict:
    truth = true_model(0)
    results = {}
    variants, planning_seconds = plans()
    for name, stops in variants.items():
        results[name] = {'stops': len(stops), 'predicted': predicted(truth, stops),
                         'realised_rms': realised(stops)}
        r = results[name]
        print(f'{name}: ' + ', '.join(
            f'{k} predicted {r["predicted"][k] * 1e3:.3f} m(rad), realised '
            f'{r["realised_rms"][k] * 1e3:.3f}' for k in (*WATCHED, 'working_m')), flush=True)
    lines = ['Five-axis dispenser: E_B0A (A\'s axis tilt about Y), E_B0C (C\'s) and the '
             'part\'s placement at the working poses (the path\'s 12 points brought to the '
             f'needle tip at {WORKING_POSES} poses, A within +-45 deg, C anywhere; the offset '
             'common to all taken out) for plan variants and the planner\'s own choice. '
             'Predicted: 1-sigma from the identification Jacobian at the true model with '
             f'dots detected to {NOISE_PX} px, before anything moves (the planner chose its '
             'stops at the nominal model). Realised: RMS of identified minus true over '
             f'{MACHINES} simulated machines (noise {NOISE_PX} px). Strokes: A +-90 deg, C '
             '+-360 deg, Z +-50 mm.', '',
             '| plan | stops | E_B0A predicted | E_B0A realised | E_B0C predicted | '
             'E_B0C realised | placement predicted | placement realised |',
             '|---|---|---|---|---|---|---|---|']
    for name, r in results.items():
        p, q = r['predicted'], r['realised_rms']
        lines.append(f'| {name} | {r["stops"]} | {p["E_B0A"] * 1e3:.3f} mrad | '
                     f'{q["E_B0A"] * 1e3:.3f} mrad | {p["E_B0C"] * 1e3:.3f} mrad | '
                     f'{q["E_B0C"] * 1e3:.3f} mrad | {p["working_m"] * 1e6:.2f} um | '
                     f'{q["working_m"] * 1e6:.2f} um |')
    today, planned = next(iter(results)), next(n for n in results if n.startswith('planned'))
    candidates = len(candidate_stops(nominal_model(size=IMAGE_SIZE), IMAGE_SIZE)[0])
    lines += ['', f'Every ISO 230-7 error, today\'s plan against the planner\'s (I) at the same '
              f'{results[today]["stops"]} stops:', '',
              '| ISO 230-7 error | today predicted | today realised | planned predicted | '
              'planned realised |', '|---|---|---|---|---|']
    for error in iso230_7(truth):
        unit = 'urad' if error in ORIENTATION else 'um'
        cells = [f'{results[plan][kind][error] * 1e6:.3g} {unit}' for plan in (today, planned)
                 for kind in ('predicted', 'realised_rms')]
        lines.append(f'| {error} | ' + ' | '.join(cells) + ' |')
    lines += ['', 'Realised over predicted per parameter (31 parameters): ' + '; '.join(
        f'{name}: median {m:.2f}, {lo:.2f}-{hi:.2f}' for name, (m, lo, hi) in
        ((n, _ratio_range(results[n])) for n in (today, planned))) + '.',
              '', f'Planning time ({candidates} candidates, '
              f'{results[today]["stops"]} stops): ' + ', '.join(
                  f'{c} {t:.2f} s' for c, t in planning_seconds.items()) + '.']
    write_results(out, 'plan_five_axis', {**results, 'planning_seconds': planning_seconds})
    plot(out / 'plan_five_axis.png', results)
    write_table(out, 'plan_five_axis', lines)
    return results


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    main()
