"""Which stops determine the five-axis dispenser's E_B0A and E_B0C (issue 32): the
predicted 1-sigma of every ISO 230-7 location and orientation error for plan variants,
from the identification Jacobian at the simulated machine's true model (dots detected to
0.1 px), before anything moves, and the same plans measured on 10 simulated machines.
Writes bench_results/plan_five_axis.{md,json}."""
from pathlib import Path

import numpy as np

from dispenser_calib.core.calibration import _board_of, calibrate
from dispenser_calib.core.data import DOT_RADIUS
from dispenser_calib.core.iso230 import iso230_7, iso230_7_report
from dispenser_calib.core.model import DispenserModel, nominal_model, place, project_rows
from dispenser_calib.core.procedure import (
    WORKING_DISTANCE, check_stroke, evaluation_stops, plan_stops)
from dispenser_calib.sim.machine import IMAGE_SIZE, observe, true_model
from machine_alignment.bench import main_with_out, write_results, write_table

NOISE_PX = 0.1
WATCHED = ('E_B0A', 'E_B0C')
CENTRE = np.array([0.0, 0.0, WORKING_DISTANCE])


def _alone(a_values=(), c_values=(), a_for_c: float = 0.0) -> list:
    nominal = nominal_model()
    return ([place(nominal, np.zeros(3), a, 0.0, CENTRE) for a in np.deg2rad(a_values)]
            + [place(nominal, np.zeros(3), np.deg2rad(a_for_c), c, CENTRE)
               for c in np.deg2rad(c_values)])


def _spread_z(linear: np.ndarray, reach: float) -> np.ndarray:
    """The linear stops with Z spread evenly over +-``reach`` (m) about where they were."""
    spread = linear.copy()
    spread[:, 2] += np.linspace(-reach, reach, len(linear))
    return spread


def plans() -> dict:
    today = plan_stops(nominal_model(), 0)
    linear = today[:12]
    c_turn = np.arange(30, 360, 30)
    variants = {
        "today's 27 stops (12 linear, A alone at 4 tilts, C alone at 11 angles)": today,
        'today + 6 stops with A and C both turned': np.vstack(
            [today, evaluation_stops(nominal_model(), 6, 9)]),
        'today, A alone at 8 tilts up to +-80 deg': np.vstack(
            [linear, _alone((-80, -60, -40, -20, 20, 40, 60, 80), c_turn)]),
        'today, C turned again with A at +30 and -30 deg': np.vstack(
            [today, _alone((), c_turn, 30.0), _alone((), c_turn, -30.0)]),
        'today, the 12 linear stops spread over Z +-40 mm': np.vstack(
            [_spread_z(linear, 40e-3), today[12:]]),
        'today + 12 linear stops over Z +-40 mm': np.vstack([today, _spread_z(linear, 40e-3)]),
        'today twice (54 stops, the noise halved in variance)': np.vstack([today, today]),
    }
    for stops in variants.values():
        for pose in stops:
            check_stroke(pose)
    return variants


def _jacobian(model: DispenserModel, images) -> np.ndarray:
    """d(pixels)/d(parameters) (2k, p) at ``model`` by central differences."""
    points = np.concatenate([_board_of(im) for im in images])
    poses = np.concatenate([np.repeat(im.pose[None], len(im.indices), 0) for im in images])
    columns = []
    for j in range(len(model.values)):
        step = 1e-6 * max(1.0, abs(model.values[j]))
        up, down = model.values.copy(), model.values.copy()
        up[j] += step
        down[j] -= step
        columns.append((project_rows(DispenserModel(up), points, poses, DOT_RADIUS)
                        - project_rows(DispenserModel(down), points, poses, DOT_RADIUS)).ravel()
                       / (2 * step))
    return np.column_stack(columns)


def predicted(truth: DispenserModel, stops) -> dict:
    images, _ = observe(truth, stops, noise_px=0.0, seed=0)
    jacobian = _jacobian(truth, images)
    covariance = np.linalg.pinv(jacobian.T @ jacobian) * NOISE_PX ** 2
    return iso230_7_report(truth, covariance)['std_devs']


def realised(stops, machines: int = 10) -> dict:
    """RMS over ``machines`` simulated machines of the identified minus true value."""
    errors = {name: [] for name in WATCHED}
    for seed in range(machines):
        truth = true_model(seed)
        images, _ = observe(truth, stops, noise_px=NOISE_PX, seed=seed)
        model, _ = calibrate(images, IMAGE_SIZE)
        found, true = iso230_7(model), iso230_7(truth)
        for name in WATCHED:
            errors[name].append(found[name] - true[name])
    return {name: float(np.sqrt(np.mean(np.square(v)))) for name, v in errors.items()}


def run(out: Path) -> dict:
    truth = true_model(0)
    results = {}
    for name, stops in plans().items():
        sigma = predicted(truth, stops)
        results[name] = {'stops': len(stops), 'predicted_sigma_rad': {k: sigma[k] for k in WATCHED},
                         'realised_rms_rad': realised(stops)}
        r = results[name]
        print(f'{name}: ' + ', '.join(
            f'{k} predicted {r["predicted_sigma_rad"][k] * 1e3:.3f} mrad, realised '
            f'{r["realised_rms_rad"][k] * 1e3:.3f}' for k in WATCHED), flush=True)
    lines = ['Five-axis dispenser: E_B0A (A\'s axis tilt about Y) and E_B0C (C\'s) for plan '
             f'variants. Predicted: 1-sigma from the identification Jacobian at the true '
             f'model with dots detected to {NOISE_PX} px, before anything moves. Realised: '
             'RMS of identified minus true over 10 simulated machines (noise '
             f'{NOISE_PX} px). Strokes: A +-90 deg, C +-360 deg, Z +-50 mm.', '',
             '| plan | stops | E_B0A predicted | realised | E_B0C predicted | realised |',
             '|---|---|---|---|---|---|']
    for name, r in results.items():
        p, q = r['predicted_sigma_rad'], r['realised_rms_rad']
        lines.append(f'| {name} | {r["stops"]} | {p["E_B0A"] * 1e3:.3f} mrad | '
                     f'{q["E_B0A"] * 1e3:.3f} mrad | {p["E_B0C"] * 1e3:.3f} mrad | '
                     f'{q["E_B0C"] * 1e3:.3f} mrad |')
    write_results(out, 'plan_five_axis', results)
    write_table(out, 'plan_five_axis', lines)
    return results


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    main()
