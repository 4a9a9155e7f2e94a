"""Deliberate, realistic bugs applied one at a time to a scratch copy of the tree, each
against the test modules that cover its code: which do the tests miss? (`make mutants`)

A bug the tests miss is a number a user could read wrong without any test failing. The
list grows with each new module; ``EQUIVALENT`` ones are shown not to change anything on
today's data and are reported apart. Prints one line per bug and the count caught.

Usage: python tools/mutants.py [--only SUBSTRING] [--keep]
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# (label, file, text, replacement, test modules)
ISO = ['test/test_iso230_2.py']
PLAN = ['test/test_planning_formulas.py',
        'test/test_planning.py::test_d_optimal_quadratic_on_an_interval_is_its_ends_and_middle',
        'test/test_planning.py::test_i_optimal_goes_where_the_user_works']
GATES = ['test/test_gate_limits.py']
SIGNIFICANCE = ['test/test_significance.py', 'test/test_loop_channels.py']
MUTANTS = [
    ('ISO 230-2: unidirectional R = 2 s', 'calib_core/iso230_2.py',
     "entry['R'] = float(np.nanmax(4 * s))", "entry['R'] = float(np.nanmax(2 * s))", ISO),
    ('ISO 230-2: M computed as E', 'calib_core/iso230_2.py',
     "bidirectional['M'] = _range(mean[both].mean(axis=1))", "bidirectional['M'] = _range(mean)",
     ISO),
    ('ISO 230-2: A from min(x + 2 s)', 'calib_core/iso230_2.py',
     "np.nanmin(mean[:, k] - 2 * s)", "np.nanmin(mean[:, k] + 2 * s)", ISO),
    ('ISO 230-2: bidirectional A from min(x + 2 s)', 'calib_core/iso230_2.py',
     "np.nanmin(mean - 2 * spread)", "np.nanmin(mean + 2 * spread)", ISO),
    ('ISO 230-2: s with ddof 0', 'calib_core/iso230_2.py', 'values.std(ddof=1)',
     'values.std(ddof=0)', ISO),
    ('ISO 230-2: B_i sign flipped', 'calib_core/iso230_2.py',
     'reversal = mean[:, 0] - mean[:, 1]', 'reversal = mean[:, 1] - mean[:, 0]', ISO),
    ('ISO 230-2: bidirectional R without |B_i|', 'calib_core/iso230_2.py',
     '+ np.abs(reversal[repeat]),', '+ 0 * reversal[repeat],', ISO),
    ('planning: whiten by the covariance, not its Cholesky factor', 'calib_core/planning.py',
     'np.linalg.solve(np.linalg.cholesky(noise), rows)', 'np.linalg.solve(noise, rows)', PLAN),
    ('planning: the exchange skips its last slot', 'calib_core/planning.py',
     'for slot in range(count):', 'for slot in range(count - 1):', PLAN),
    ('planning: the I score without its update factor', 'calib_core/planning.py',
     "return np.einsum('mii->m', np.linalg.solve(s, q))", "return np.einsum('mii->m', q)", PLAN),
    ('planning: the sandwich with one inverse', 'calib_core/planning.py',
     "return inverse @ np.einsum('kip,kij,kjq->pq', rows, noise, rows) @ inverse",
     "return inverse @ np.einsum('kip,kij,kjq->pq', rows, noise, rows)", PLAN),
    ('planning: the platform noise covariance doubled', 'platform_calib/core/planning.py',
     'covariance = sandwich_covariance(rows, noise)',
     'covariance = sandwich_covariance(rows, 2 * noise)',
     ['test/test_planning.py::test_platform_prediction_holds_and_twelve_planned_poses_beat_'
      'twelve_random']),
    ('planning: the stage camera noise dropped', 'printer_alignment/core/stage_planning.py',
     '+ camera_noise ** 2 * np.eye(4))', '+ 0 * camera_noise * np.eye(4))',
     ['test/test_stage_planning.py::test_the_prediction_carries_both_noises_and_its_maximum_'
      'is_over_the_working_inputs']),
    ('planning: the stage maximum taken as a mean', 'printer_alignment/core/stage_planning.py',
     'float(per_mark.max()),', 'float(per_mark.mean()),',
     ['test/test_stage_planning.py::test_the_prediction_carries_both_noises_and_its_maximum_'
      'is_over_the_working_inputs']),
    ('planning: the stage maximum over the other axis',
     'printer_alignment/core/stage_planning.py',
     'per_mark = np.linalg.norm(errors.reshape(len(working), 2, 2), axis=2)',
     'per_mark = np.linalg.norm(errors.reshape(len(working), 2, 2), axis=1)',
     ['test/test_stage_planning.py::test_the_predicted_maximum_is_the_worst_marks_displacement']),
    ('gate: platform closure limit 10x', 'platform_calib/core/identification.py',
     'MAX_CLOSURE_RMS_M = 100e-6', 'MAX_CLOSURE_RMS_M = 1000e-6', GATES),
    ('gate: five-axis reprojection limit 10x', 'dispenser_calib/core/calibration.py',
     'MAX_REPROJECTION_RMS_PX = 3.0', 'MAX_REPROJECTION_RMS_PX = 30.0', GATES),
    ('gate: stage skew limit 10x', 'printer_alignment/core/stage_calibration/both.py',
     'MAX_SKEW_RAD = 0.1', 'MAX_SKEW_RAD = 1.0', GATES),
    ('gate: stage skew checked on one side', 'printer_alignment/core/stage_calibration/both.py',
     'np.pi / 2 + MAX_SKEW_RAD, ', 'np.inf, ', GATES),
    ('gate: +-inf standard deviations let through', 'calib_core/sanity.py',
     'if not np.isfinite(s)]', 'if np.isnan(s)]', GATES),
    ('significance: no Bonferroni over channels', 'calib_core/closed_loop/channels.py',
     'p * prepared.trials_of(channel) * len(groups)', 'p * prepared.trials_of(channel)',
     SIGNIFICANCE),
    ('significance: Wald statistic not divided by its dof', 'calib_core/closed_loop/channels.py',
     'stats.f.sf(wald / q, q, max(dof, 1))', 'stats.f.sf(wald, q, max(dof, 1))', SIGNIFICANCE),
    ('significance: structure tests without Bonferroni over the tests',
     'calib_core/loop_structure.py', "if t['p_value'] * count < alpha]",
     "if t['p_value'] < alpha]", SIGNIFICANCE),
    ('significance: a periodogram counts one alternative per resolution',
     'calib_core/effects/periodic.py', 'SEARCH_TRIALS_PER_RESOLUTION = 3.0',
     'SEARCH_TRIALS_PER_RESOLUTION = 1.0', SIGNIFICANCE),
    ('significance: rotary orders without Bonferroni over the orders scanned',
     'calib_core/effects/rotary.py', 'float(stats.f.sf(f_stat, 2 * q, dof)) * len(left))',
     'float(stats.f.sf(f_stat, 2 * q, dof)))', ['test/test_significance.py']),
    ('significance: rotary order dof off by one', 'calib_core/effects/rotary.py',
     'dof = q * (n - 1 - 2 * (len(chosen) + 1))', 'dof = q * (n - 2 * (len(chosen) + 1))',
     ['test/test_significance.py']),
    ('printed words: an adaptive floor in mm labelled um', 'calib_core/planning.py',
     '{floor * 1e6:.2f} um', '{floor * 1e3:.2f} um',
     ['test/test_planning.py::test_adaptive_platform_says_when_the_limits_cannot_meet_the_target']),
    ('outliers: z-scores not centred on the median', 'calib_core/closed_loop/outliers.py',
     'z = (r - np.median(r, axis=0)) / scale', 'z = r / scale',
     ['test/test_significance.py', 'test/test_loop_outliers.py']),
    ('temperature: gap to the farther sample', 'calib_core/temperature.py',
     'gap = np.minimum(', 'gap = np.maximum(', ['test/test_temperature.py']),
    ('loop: a single split vetoes an effect', 'calib_core/closed_loop/evidence.py',
     "return gain['gain'] >= MIN_HELDOUT_GAIN and",
     "return gain['max_ratios'][0] <= 1 and gain['gain'] >= MIN_HELDOUT_GAIN and",
     ['test/test_loop_evidence.py']),
    ('loop: what was seen is dropped', 'calib_core/closed_loop/evidence.py',
     'out.append(entry)', 'pass', ['test/test_loop_evidence.py']),
    ('printed words: arc-minutes labelled arcsec', 'machine_alignment/cli/call.py',
     'np.degrees(orientation_error) * 3600', 'np.degrees(orientation_error) * 60',
     ['test/test_call_services.py']),
    ('printed words: a clean exit as signal 0', 'machine_alignment/launcher.py',
     '    if code < 0:\n        try:', '    if code <= 0:\n        try:',
     ['test/test_call_services.py']),
    ('call: a served service missing from the list', 'calib_core/nodes/services.py',
     "    'grid_calibrator/analyze_residuals': ('AnalyzeResiduals', None, 'options'),\n", '',
     ['test/test_call_services.py']),
    ('loop: scale on the hexapod legs not tried', 'hexapod_calib/core/loop_models.py',
     "'reversal', 'scale', ", "'reversal', ", ['test/test_loop_user_machines.py']),
]
EQUIVALENT = {}


def _scratch() -> Path:
    """A copy of the tracked tree (the working copy's files) in a temporary folder."""
    target = Path(tempfile.mkdtemp(prefix='mutants-'))
    files = subprocess.run(['git', 'ls-files', '-co', '--exclude-standard'], cwd=ROOT,
                           check=True, capture_output=True, text=True).stdout.split('\n')
    for name in filter(None, files):
        source = ROOT / name
        if source.is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target / name)
    return target


def _run(tree: Path, tests: list) -> bool:
    """Whether the tests pass on ``tree`` (the bug is missed)."""
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS='1',
               NUMBA_CACHE_DIR=str(tree / '.numba_cache'))
    result = subprocess.run([sys.executable, '-m', 'pytest', '-x', '-q', '-p', 'no:cacheprovider',
                             *tests], cwd=tree, env=env, capture_output=True, text=True,
                            timeout=900)
    return result.returncode == 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--only', default='', help='run the bugs whose label contains this')
    parser.add_argument('--keep', action='store_true', help='keep the scratch copy')
    args = parser.parse_args(argv)
    chosen = [m for m in MUTANTS if args.only in m[0]]
    tree = _scratch()
    caught = missed = 0
    try:
        for label, name, text, replacement, tests in chosen:
            path = tree / name
            original = path.read_text()
            if original.count(text) != 1:
                print(f'STALE   {label}: the text to change is not in {name} once')
                continue
            path.write_text(original.replace(text, replacement))
            start = time.time()
            try:
                passed = _run(tree, tests)
            finally:
                path.write_text(original)
            status = 'MISSED ' if passed else 'caught '
            caught += not passed
            missed += passed
            print(f'{status} {label} ({time.time() - start:.0f} s)', flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(tree, ignore_errors=True)
    print(f'{caught} of {caught + missed} deliberate bugs caught, {missed} missed')
    return 0 if missed == 0 else 1


if __name__ == '__main__':
    raise SystemExit(main())
