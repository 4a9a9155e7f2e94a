"""`make demo`: calibrate the simulated machines end to end.

Printer vision system:
1. Start gantry_sim, camera_sim, mark_detector and vision_calibrator as separate processes
   (own ROS_DOMAIN_ID, localhost discovery) and trigger ``vision_calibrator/calibrate``,
   then the closed loop (``vision_calibrator/analyze_residuals``, applied).
2. Re-run the calibration offline from the bag the node recorded: same result.
3. Evaluate against the simulation's truth over the whole travel: camera-measured dot
   positions before (nominal model) and after calibration, as JSON and PNG.
XY-Theta stage (the dot plate removed, the vision calibration in force):
4. Start the stage graph, trigger ``stage_calibrator/calibrate`` (stepwise and
   parametric), align a substrate fixed 0.3 mm off with the nominal, stepwise and
   parametric models (stage sent home before each), then the closed loop on the run.
Hexapod:
5. Start hexapod_sim, pose_sensor_sim and hexapod_calibrator and trigger
   ``hexapod_calibrator/calibrate`` (plans poses, drives, measures, identifies, iterates,
   evaluates on separate poses), then the closed loop on its stops
   (``hexapod_calibrator/analyze_residuals``, applied).
6. Re-run the identification offline from its bag, and compare the 42 identified
   parameters with the simulation's truth.
The three machines after them:
7. Grid plate: the printer's camera gantry self-calibrated with an imperfect 5 x 5 mark
   grid plate over 2 regions (``grid_calibrator/calibrate``; the simulated operator places
   the plate as asked).
8. Platform: ``platform_calibrator/calibrate`` (20 poses by the laser tracker), then
   ``platform_calibrator/register`` (exact compensation, marks measured after the move).
9. Five-axis dispenser: ``five_axis_calibrator/calibrate`` on rendered camera frames,
   ``measure_needle`` from dispensed dots, ``locate`` a part and place its path.
Last, one summary table (machine, before, after, the paper's figure, the simulated
instruments' noise, the figure file), printed and written as ``summary.md`` and
``summary.json``.

The simulated instruments run at the noise the sources report (:data:`INSTRUMENTS`), so
the demo's numbers compare with the papers'; ``low_noise`` runs them ten times quieter,
and the table says so.
"""
from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from calib_core.figures import RUN_VARIABLE
from calib_core.storage import write_atomic
from machine_alignment.demo.common import DemoRun
from machine_alignment.demo.five_axis import five_axis
from machine_alignment.demo.grid import grid
from machine_alignment.demo.hexapod import hexapod
from machine_alignment.demo.printer import printer, stage
from machine_alignment.demo.registration_platform import registration_platform


def run_demo(out: Path, low_noise: bool = False) -> int:
    """Every step into ``out`` (emptied first), the summary printed and written; 0 when
    every machine calibrated, 1 at the first that did not (why is printed)."""
    out = out.resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    run = DemoRun(out, str(100 + os.getpid() % 100), low_noise)
    # The run every figure it draws names (nodes inherit it); `make figures` names its own.
    os.environ.setdefault(RUN_VARIABLE, time.strftime('make demo %Y-%m-%dT%H:%M:%SZ',
                                                      time.gmtime()))
    print(f'run: {os.environ[RUN_VARIABLE]}', flush=True)
    os.environ['ROS_DOMAIN_ID'] = run.domain
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    started = time.monotonic()
    for machine in (printer, stage, hexapod, grid, registration_platform, five_axis):
        if machine(run):
            return 1
    table = run.summary()
    write_atomic(out / 'summary.md', table)
    write_atomic(out / 'summary.json', json.dumps(run.rows, indent=2) + '\n')
    print(f'\nSummary ({time.monotonic() - started:.0f} s; figures and files in {out}):\n')
    print(table)
    return 0
