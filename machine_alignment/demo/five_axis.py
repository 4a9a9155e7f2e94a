"""The demo's five-axis step: calibration from rendered frames, the needle, a part
located and its path placed."""
from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from alignment_msgs.srv import LocateWorkpiece, MeasureNeedle

from calib_core.bags import decode_bag
from calib_core.figures import arrow_key, save_figure
from calib_core.storage import read_calibration
from dispenser_calib.core.calibration import reprojection
from dispenser_calib.core.model import NAMES, DispenserModel, nominal_model
from dispenser_calib.core.records import OBSERVATIONS_TOPIC as FIVE_AXIS_OBSERVATIONS
from dispenser_calib.core.records import image_from_message
from dispenser_calib.sim.machine import IMAGE_SIZE as FIVE_AXIS_IMAGE
from machine_alignment.demo.common import DemoRun, calibrated, graph_of
from machine_alignment.launcher import five_axis_graph
from machine_alignment.live import LiveClient

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)


def five_axis(run: DemoRun) -> int:
    out, domain = run.out, run.domain
    run.step('the five-axis dispenser: calibration from rendered camera frames, the needle '
          'measured from dispensed dots, a part located and its path placed')
    spec = run.noisy('five_axis', five_axis_graph(str(out / 'calibration'), str(out / 'runs')))
    with graph_of('five_axis', spec, out, domain) as graph:
        report = calibrated(graph, 'five-axis', 'five_axis_calibrator/calibrate',
                             '{frames: true}')
        if report is None:
            return 1
        held = report['held_out']
        print(f'      reprojection {report["mean_reprojection_px"]:.4f} px mean; held out '
              f'{held["rms_px_calibrated"]:.4f} px RMS calibrated, {held["rms_px_nominal"]:.1f} px '
              f'nominal; set aside {sorted(report["bad_images"]) or "none"}')
        with LiveClient('demo_five_axis_client') as client:
            needle = client.call(MeasureNeedle, 'five_axis_calibrator/measure_needle',
                                 MeasureNeedle.Request(), timeout=120.0)
            if not needle.success:
                print(f'      needle measurement failed: {needle.message}')
                return 1
            part = client.call(LocateWorkpiece, 'five_axis_calibrator/locate',
                               LocateWorkpiece.Request(), timeout=120.0)
    if not part.success:
        print(f'      localisation failed: {part.message}')
        return 1
    print(f'      needle tip {", ".join(f"{v * 1e3:.4f}" for v in needle.tip)} mm (camera frame; '
          f'one dot alone within {needle.spread * 1e6:.1f} um)')
    print(f'      part found at {", ".join(f"{v * 1e3:.4f}" for v in part.pose[:3])} mm, '
          f'{part.pose[5] * 1e3:.3f} mrad (placed at 1.5, -1, 0 mm, 30 mrad); '
          f'{len(part.path_poses) // 5} path poses')
    figure = out / 'five_axis_evaluation.png'
    _plot_five_axis_evaluation(figure, read_calibration(out / 'calibration', 'five_axis'))
    print(f'      wrote {figure}')
    run.row(f'five-axis dispenser ({report["held_out"]["images"]} held-out images)',
            f'{report["held_out"]["rms_px_nominal"]:.1f} px RMS (nominal model)',
            f'{report["held_out"]["rms_px_calibrated"]:.4f} px RMS', '0.17 px',
            figure.name, run.noise_text('five_axis'))
    return 0


def _plot_five_axis_evaluation(path: Path, calibration: dict) -> None:
    """The held-out images of the run (A and C both turned, not calibrated on): each
    image's RMS reprojection with the nominal and the calibrated model on one log scale,
    and the calibrated model's residual vectors over the image with a key."""
    stops = [stop for _, _, msg in decode_bag(calibration['bag'], [FIVE_AXIS_OBSERVATIONS])
             for stop in [image_from_message(msg)] if stop[1] == 'evaluate']
    images = [image for image, _ in stops]
    calibrated = DispenserModel(np.array([calibration['parameters'][n] for n in NAMES]))
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.6))
    for model, colour, label in ((nominal_model(), 'tab:red', 'nominal model'),
                                 (calibrated, 'tab:blue', 'calibrated')):
        per_image = [float(np.sqrt(np.mean(e ** 2))) for e in reprojection(model, images)]
        left.semilogy(np.arange(1, len(images) + 1), per_image, 'o', color=colour,
                      label=f'{label}: median {np.median(per_image):.3g} px')
    left.set_xlabel('held-out image (A and C both turned)')
    left.set_ylabel('RMS reprojection (px, log)')
    left.legend(fontsize=8)
    left.grid(alpha=0.3, which='both')
    uv = np.concatenate([im.pixels for im in images])
    r = np.concatenate(reprojection(calibrated, images))
    longest = max(float(np.linalg.norm(r, axis=1).max()), 1e-9)
    arrows = right.quiver(uv[:, 0], uv[:, 1], r[:, 0], r[:, 1], angles='xy',
                          scale_units='xy', scale=longest / 60.0, width=0.002)
    arrow_key(right, arrows, longest / 2, 'px')
    right.set_xlim(0, FIVE_AXIS_IMAGE[0])
    right.set_ylim(FIVE_AXIS_IMAGE[1], 0)
    right.set_aspect('equal')
    right.set_xlabel('u (px)')
    right.set_ylabel('v (px)')
    right.set_title(f'calibrated residuals, held-out dots (longest {longest:.3g} px)',
                    fontsize=10)
    fig.suptitle('five-axis dispenser: held-out images, nominal against calibrated', fontsize=11)
    fig.tight_layout(rect=(0, 0.08, 1, 1))      # room for the arrow key below the axes
    save_figure(fig, path, [__file__])
    plt.close(fig)
