"""How long each job takes and how much memory, how that grows with its size, and the ratio
to a baseline timed in the same process on the same data (issue 34). Each job at two or
three sizes, each size in a fresh process (its own peak resident memory). Baselines:
OpenCV where OpenCV does the job (Mark detection: a SimpleBlobDetector tuned to the frame;
localisation: cv2.triangulatePoints), the source's own route where a paper gives one (the
grid's difference equations, the platform's particle swarm), the route the suite replaced
where it replaced one (numerical derivatives where the identification has analytic ones;
the closed loop's full fits), and none where the suite has the only route (today's time is
then the reference for later changes). Writes bench_results/performance.{md,json}."""
import argparse
import functools
import json
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from machine_alignment.bench import write_results, write_table


@dataclass
class Work:
    """A job built at one size: ``job`` and ``baseline`` (or None) are called without
    arguments on the same data; ``error(result)`` (or None) scores a result against the
    truth in ``error_unit``, so that a faster baseline is seen at its accuracy."""

    job: Callable
    baseline: Callable | None = None
    error: Callable | None = None
    error_unit: str = ''


def _dots_rms(found, truth: np.ndarray) -> float:
    """RMS per coordinate (px) of the true dots' nearest found ones, those within 3 px, as
    bench_results/results.md reports it; NaN when none is found."""
    from machine_alignment.bench.vision import _match
    error = _match(np.asarray(found, float).reshape(-1, 2), truth)
    good = error[~np.isnan(error).any(axis=1)]
    return float(np.sqrt(np.mean(good ** 2))) if len(good) else float('nan')


def _dot_frame(width: int, height: int, columns, rows, polarity: str = 'auto') -> Work:
    """A ``width`` x ``height`` frame of dots (10 px radius, 1 px blur, 3 DN noise) at the
    grid of ``columns`` and ``rows`` (px), each moved by up to 0.5 px, detected with the
    Marks' ``polarity`` (auto: chosen from the frame); the baseline: SimpleBlobDetector with
    thresholds and areas set for the frame, which looks for dark blobs
    (bench_results/results.md compares it at every radius, blur and noise)."""
    from calib_core.marks import DetectorConfig, detect_marks
    from calib_core.sim.render import MarkShape, render
    from machine_alignment.bench.vision import BACKGROUND, CONTRAST, _blob_detector
    rng = np.random.default_rng(1)
    marks = [MarkShape('circle', u + rng.uniform(-0.5, 0.5), v + rng.uniform(-0.5, 0.5), 10.0)
             for v in rows for u in columns]
    image = render(marks, width, height, 1.0, BACKGROUND, CONTRAST)
    image = np.clip(np.round(image + rng.normal(0, 3.0, image.shape)), 0, 255).astype(np.uint8)
    tuned = _blob_detector(BACKGROUND + CONTRAST + 10, BACKGROUND - 10, np.pi * 20.0 ** 2)
    truth = np.array([[m.u, m.v] for m in marks])
    config = DetectorConfig(polarity=polarity)
    return Work(lambda: [[m.u, m.v] for m in detect_marks(image, config).marks],
                lambda: [k.pt for k in tuned.detect(image)],
                lambda found: _dots_rms(found, truth), 'px RMS')


def _detection(size: int, polarity: str = 'auto') -> Work:
    """One 640 x 480 frame of ``size`` dots on a square grid (_dot_frame)."""
    side = int(round(np.sqrt(size)))
    return _dot_frame(640, 480, np.linspace(45, 595, side), np.linspace(45, 435, side),
                      polarity)


# The frame sizes of the frame-size job, by pixel count: VGA, full HD (whose 1080 rows are
# no multiple of the detector's 16 px trend blocks) and a 5 MP sensor.
FRAMES = {640 * 480: (640, 480), 1920 * 1080: (1920, 1080), 2592 * 1944: (2592, 1944)}


def _frame_size(size: int) -> Work:
    """One frame of ``size`` pixels (FRAMES) with 9 dots spread over it (_dot_frame),
    detected choosing the polarity. Both detectors pass over every pixel of the frame,
    whatever the dots."""
    width, height = FRAMES[size]
    spread = np.linspace(0.15, 0.85, 3)
    return _dot_frame(width, height, spread * width, spread * height)


def _vision(size: int) -> Work:
    """Pixel size and gantry model from ``size`` positions over the dot plate (the frames
    rendered and detected beforehand: bench_results/results.md times the detection)."""
    from calib_core.marks import detect_marks
    from printer_alignment.core.geometry import NOMINAL_LEADS
    from printer_alignment.core.vision_procedure import (
        VisionPlan, calibrate_from_observations, run_vision_calibration)
    from printer_alignment.sim.camera import CameraSim
    from printer_alignment.sim.gantry import GantrySim
    from printer_alignment.sim.scenes import make_scene
    gantry, camera = GantrySim(), CameraSim(make_scene('dot_plate'), seed=7)
    ny = 3 if size <= 12 else 6
    plan = VisionPlan(nx=size // ny, ny=ny)
    observations, _ = run_vision_calibration(
        plan, lambda x, y: gantry.move(x, y) / NOMINAL_LEADS,
        lambda: np.array([[m.u, m.v] for m in detect_marks(
            camera.capture(gantry.true_camera_position())).marks]))
    return Work(lambda: calibrate_from_observations(observations, plan.pitch))


def _stage(size: int) -> Work:
    """The paper's 130-stop run (its plan fixes the size)."""
    from printer_alignment.core.stage_calibration import calibrate_stage
    from printer_alignment.sim.stage import simulate_calibration_run
    data = simulate_calibration_run(seed=1)
    return Work(lambda: calibrate_stage(data))


def _hexapod(size: int) -> Work:
    """The 42 parameters from ``size`` random poses; the baseline differentiates the same
    residuals numerically (scipy's 2-point) instead of the analytic leg Jacobian."""
    from calib_core.least_squares import fit
    from hexapod_calib.core.calibration import identification_residuals, identify
    from hexapod_calib.core.geometry import HexapodGeometry, nominal_geometry
    from hexapod_calib.sim.hexapod import HexapodTruth, measure_random_poses
    truth = HexapodTruth.default()
    data, _ = measure_random_poses(truth, size, seed=1)
    nominal = nominal_geometry()
    return Work(lambda: identify(data, nominal),
                lambda: fit(lambda p: identification_residuals(
                    HexapodGeometry.from_parameters(p), data).ravel(),
                    nominal.parameters(), max_condition=1e6))


def _platform(size: int) -> Work:
    """The 18 parameters from ``size`` poses; the baseline: numerical derivatives."""
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.core.identification import identify
    from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry
    data = measure_poses(PlatformSim(true_geometry(0)), plan_poses(size, 0), nominal_geometry())
    return Work(lambda: identify(data, nominal_geometry()),
                lambda: identify(data, nominal_geometry(), derivatives='2-point'))


def _compensation(size: int) -> Work:
    """Feeds for ``size`` targets with the identified geometry by the exact inverse; the
    baseline: the source's particle swarm (pymoo, the stable settings)."""
    from platform_calib.core.compensation import PSOSettings, compensate
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.sim.platform import plan_poses, true_geometry
    targets = plan_poses(size, 1)
    model, nominal = true_geometry(0), nominal_geometry()
    return Work(lambda: [compensate(model, nominal, t, 'exact') for t in targets],
                lambda: [compensate(model, nominal, t, 'pso', pso=PSOSettings.stable())
                         for t in targets])


def _plan(size: int) -> Work:
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.core.planning import plan_platform
    return Work(lambda: plan_platform(nominal_geometry(), 12, candidates=size))


def _grid(size: int) -> Work:
    """One region of a 100 mm plate, ``size`` marks a side, three placements, 20 nm
    noise, with the per-site uncertainty (exact to N = 21, sampled beyond); the baseline:
    the source's difference equations (no uncertainty)."""
    from grid_calib.core.model import Grid
    from grid_calib.core.reference import solve_by_differences
    from grid_calib.core.selfcal import self_calibrate
    from grid_calib.sim.plate import default_truth, measure_placements
    half = (size - 1) // 2
    grid = Grid(half, 0.05 / half)
    truth = default_truth(grid, 1)
    placements = measure_placements(grid, truth, 20e-9, 1)
    g = truth.stage_error(grid)
    return Work(lambda: self_calibrate(grid, placements),
                lambda: solve_by_differences(grid, placements),
                lambda result: float(np.sqrt(np.mean((result.stage_error - g) ** 2)) * 1e9),
                'nm RMS')


def _five_axis(size: int) -> Work:
    from dispenser_calib.core.calibration import calibrate
    from dispenser_calib.core.model import nominal_model
    from dispenser_calib.core.procedure import evaluation_stops, plan_stops
    from dispenser_calib.sim.machine import IMAGE_SIZE, observe, true_model
    stops = np.vstack([plan_stops(nominal_model(), 0),
                       evaluation_stops(nominal_model(), max(size - 27, 0), 5)])[:size]
    images, _ = observe(true_model(0), stops, seed=1)
    return Work(lambda: calibrate(images, IMAGE_SIZE))


def _localisation(size: int) -> Work:
    """``size`` features of a part, each seen in two views (the table at two tilts), located
    through the true model with 0.1 px of noise; the baseline: OpenCV's linear
    triangulation (cv2.triangulatePoints) of the undistorted pixels with each view's
    projection matrix, the same two views."""
    import cv2
    from dispenser_calib.core.localisation import locate
    from dispenser_calib.core.model import camera_points
    from dispenser_calib.core.procedure import view_plan
    from dispenser_calib.sim.machine import points_in_view, true_model
    model = true_model(0)
    rng = np.random.default_rng(2)
    features = np.column_stack([rng.uniform(-0.01, 0.01, (size, 2)), np.zeros(size)])
    views = {}
    for k, pose in view_plan(model, features, [(0.0, 0.0), (0.3, 0.5)]):
        _, pixels = points_in_view(model, features[k], pose, 0.1, rng)
        views.setdefault(k, []).append((pose, pixels[0]))
    k_matrix, distortion = model.camera_matrix, np.r_[model.distortion, 0.0]

    def projection(pose):
        """K [R | t] of the board-to-camera map at ``pose``, read off the model."""
        frame = camera_points(model, np.vstack([np.zeros(3), np.eye(3)]), pose)[0]
        return k_matrix @ np.column_stack([(frame[1:] - frame[0]).T, frame[0]])

    def opencv():
        located = []
        for (pose_1, pixel_1), (pose_2, pixel_2) in views.values():
            ideal = [cv2.undistortPoints(p.reshape(1, 1, 2), k_matrix, distortion, P=k_matrix)
                     .reshape(2, 1) for p in (pixel_1, pixel_2)]
            point = cv2.triangulatePoints(projection(pose_1), projection(pose_2), *ideal)
            located.append(point[:3, 0] / point[3, 0])
        return located

    def ours():
        return [locate(model, np.array([p for p, _ in seen]), np.array([u for _, u in seen]))[0]
                for seen in views.values()]
    return Work(ours, opencv,
                lambda located: float(np.sqrt(np.mean((np.array(located) - features) ** 2)) * 1e6),
                'um RMS')


def _loop(case: str) -> Callable[[int], Work]:
    """The closed loop on one case of bench_results/closed_loop_speed.md (its data fix
    the size); the baseline: the loop's full fits with dense differences, the route the
    first-order fits replaced."""
    def build(size: int) -> Work:
        from calib_core.closed_loop import analyze
        from machine_alignment.bench.closed_loop_speed import CASES, analyze_as_before
        make = next(build for name, _, build in CASES if name == case)
        fast, full = make(), make()
        return Work(lambda: analyze(fast), lambda: analyze_as_before(full))
    return build


def _platform_loop(size: int) -> Work:
    """The platform's loop at ``size`` poses (a 10 um screw error on feed 2)."""
    from calib_core.closed_loop import analyze
    from machine_alignment.bench.closed_loop_speed import analyze_as_before
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.core.loop_model import PlatformLoopModel
    from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry
    sim = PlatformSim(true_geometry(0), screw_amplitude=(0.0, 10e-6, 0.0))
    data = measure_poses(sim, plan_poses(size, 0), nominal_geometry())
    fast, full = (PlatformLoopModel(data, nominal_geometry()) for _ in range(2))
    return Work(lambda: analyze(fast), lambda: analyze_as_before(full))


@dataclass(frozen=True)
class Job:
    what: str
    unit: str                   # of the size
    sizes: tuple
    build: Callable[[int], Work]
    baseline: str = 'none: the suite has the only route'


_FULL_FITS = 'full fits, dense differences'
JOBS = {
    'Mark detection, one frame': Job('640 x 480, 10 px dots, 3 DN noise', 'Marks', (9, 81),
                                     _detection, 'OpenCV SimpleBlobDetector, tuned'),
    'Mark detection, polarity set': Job('the same frames, told the Marks are dark', 'Marks',
                                        (9, 81), functools.partial(_detection, polarity='dark'),
                                        'OpenCV SimpleBlobDetector, tuned'),
    'Mark detection, frame size': Job('9 dots of 10 px over 640 x 480, 1920 x 1080 and '
                                      '2592 x 1944 frames', 'pixels', tuple(FRAMES),
                                      _frame_size, 'OpenCV SimpleBlobDetector, tuned'),
    'vision calibration': Job('pixel size and gantry (13 parameters)', 'positions', (12, 42),
                              _vision),
    'stage calibration': Job('stepwise + parametric, the paper\'s plan', 'stops', (130,),
                             _stage),
    'hexapod identification': Job('42 parameters', 'poses', (13, 200), _hexapod,
                                  'numerical derivatives'),
    'platform identification': Job('18 parameters', 'poses', (20, 200), _platform,
                                   'numerical derivatives'),
    'platform compensation': Job('feeds per target, exact inverse', 'targets', (2, 8),
                                 _compensation, 'the source\'s particle swarm'),
    'platform plan': Job('12 poses, I-optimal exchange', 'candidates', (1000, 4000), _plan),
    'grid self-calibration': Job('one region, 3 placements, per-site sigma',
                                 'marks a side (N)', (11, 41, 101), _grid,
                                 'the source\'s difference equations (no sigma)'),
    'five-axis calibration': Job('31 parameters, RANSAC', 'images', (27, 60), _five_axis),
    'five-axis localisation': Job('features seen in two views', 'features', (4, 16),
                                  _localisation, 'cv2.triangulatePoints'),
    'closed loop, stage': Job('chain backlash', 'rows', (130,), _loop('stage'), _FULL_FITS),
    'closed loop, rotary axes': Job('real positioner', 'poses', (205,), _loop('rotary axes'),
                                    _FULL_FITS),
    'closed loop, hexapod': Job('leg play', 'poses', (200,), _loop('hexapod'), _FULL_FITS),
    'closed loop, platform': Job('screw error on feed 2', 'poses', (100, 200), _platform_loop,
                                 _FULL_FITS),
    'closed loop, axis': Job('real ISO 230-2 run', 'readings', (50,), _loop('axis'),
                             _FULL_FITS),
    'closed loop, gantry': Job('squareness, backlash, screw error', 'positions', (200,),
                               _loop('gantry'), _FULL_FITS),
    'closed loop, camera': Job('radial distortion', 'dots', (723,), _loop('camera'),
                               _FULL_FITS),
}


def _peak_mib() -> float:
    """This process's peak resident memory so far, MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _timed(works: list[Callable], budget: float = 1.0, repeats: int = 50):
    """Wall time (s) of each of ``works``: one run, or for a work under ``budget`` seconds
    the shortest of up to ``repeats`` within it, the run least disturbed by the machine.
    The works take turns, so that a slower spell of the machine reaches the job and its
    baseline alike: timed one after the other, a 1 ms baseline once read 2.3 ms, the job's
    ratio to it half its usual.

    Returns
    -------
    best, cpu : list of float
        Each work's shortest wall time and its first run's CPU time, s.
    results : list
        Each work's result.
    peak : float
        Peak resident memory (MiB) after the first work's first run, before the others.
    """
    best, cpu, results, spent, peak = [], [], [], [], None
    for work in works:
        start, start_cpu = time.perf_counter(), time.process_time()
        results.append(work())
        best.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
        spent.append(best[-1])
        peak = _peak_mib() if peak is None else peak
    for _ in range(repeats - 1):
        turns = [k for k in range(len(works)) if spent[k] <= budget]
        if not turns:
            break
        for k in turns:
            start = time.perf_counter()
            works[k]()
            took = time.perf_counter() - start
            best[k], spent[k] = min(best[k], took), spent[k] + took
    return best, cpu, results, peak


def measure(job: str, size: int) -> dict:
    """In this process: build the job at ``size``, time it and its baseline on the same
    data, in turns; peak resident memory (MiB) before the job and after its first run
    (before the baseline's)."""
    work = JOBS[job].build(size)
    before = _peak_mib()
    works = [work.job] + ([work.baseline] if work.baseline is not None else [])
    best, cpu, results, peak = _timed(works)
    row = {'seconds': best[0], 'cpu_seconds': cpu[0], 'peak_mib_before': before,
           'peak_mib': peak}
    if work.error is not None:
        row['error'], row['error_unit'] = work.error(results[0]), work.error_unit
    if work.baseline is not None:
        row['baseline_seconds'] = best[1]
        row['ratio_to_baseline'] = best[0] / best[1]
        if work.error is not None:
            row['baseline_error'] = work.error(results[1])
    return row


def _cell(row: dict, key: str, unit: str = '') -> str:
    value = row.get(key)
    return '' if value is None else f'{value:.3g}{unit}'


def run(out: Path) -> list:
    rows = []
    for name, job in JOBS.items():
        results = []
        for size in job.sizes:
            done = subprocess.run([sys.executable, '-m', 'machine_alignment.bench.performance',
                                   '--job', name, '--size', str(size)],
                                  capture_output=True, text=True, check=True)
            results.append({'size': size, **json.loads(done.stdout.strip().splitlines()[-1])})
            r = results[-1]
            print(f'{name} at {size} {job.unit}: {r["seconds"]:.4f} s'
                  + (f', baseline {r["baseline_seconds"]:.4f} s' if 'baseline_seconds' in r
                     else '') + f', peak {r["peak_mib"]:.0f} MiB', flush=True)
        growth = None
        if len(results) >= 2 and results[0]['seconds'] > 0:
            growth = float(np.log(results[-1]['seconds'] / results[0]['seconds'])
                           / np.log(results[-1]['size'] / results[0]['size']))
        rows.append({'job': name, 'what': job.what, 'unit': job.unit, 'baseline': job.baseline,
                     'results': results, 'growth_exponent': growth})
    lines = ['Each job at one to three sizes, each size in a fresh process on this 2-core '
             'machine: wall time of the job alone (for jobs under 1 s the shortest of up to 50 '
             'runs within 1 s, taking turns with the baseline), the peak resident memory of '
             'the process (in brackets: before the job, the imports and the data), the growth '
             '(exponent of time against size, first to last '
             'size), and the baseline timed in the same process on the same data, with both '
             'results\' error against the truth where the job has one.', '',
             '| job | what | size | time | peak memory (before) | growth | baseline | '
             'baseline time | time / baseline | error (baseline\'s) |',
             '|---|---|---|---|---|---|---|---|---|---|']
    for row in rows:
        for k, r in enumerate(row['results']):
            first = k == 0
            growth = (f't ~ size^{row["growth_exponent"]:.2f}'
                      if first and row['growth_exponent'] is not None else '')
            error = (f'{r["error"]:.3g} ({r.get("baseline_error", float("nan")):.3g}) '
                     f'{r["error_unit"]}' if 'error' in r else '')
            lines.append(f'| {row["job"] if first else ""} | {row["what"] if first else ""} | '
                         f'{r["size"]} {row["unit"]} | {r["seconds"]:.3g} s | '
                         f'{r["peak_mib"]:.0f} MiB ({r["peak_mib_before"]:.0f}) | {growth} | '
                         f'{row["baseline"] if first else ""} | '
                         f'{_cell(r, "baseline_seconds", " s")} | '
                         f'{_cell(r, "ratio_to_baseline")} | {error} |')
    write_results(out, 'performance', rows)
    write_table(out, 'performance', lines)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--out', default='bench_results', help='folder for the results files')
    parser.add_argument('--job', choices=sorted(JOBS), help='(internal) one job, one size')
    parser.add_argument('--size', type=int)
    args = parser.parse_args(argv)
    if args.job:
        print(json.dumps(measure(args.job, args.size)))
    else:
        run(Path(args.out))
    return 0


if __name__ == '__main__':
    main()
