"""``machine-align calibrate camera``: intrinsics and distortion with OpenCV from
correspondences, photos of a target or random-dot markers, or a recorded
``vision_calibrator/calibrate_intrinsics`` run."""
from __future__ import annotations

from machine_alignment.cli import deferred


def add_parser(what) -> None:
    camera = what.add_parser('camera', help='intrinsics and distortion (OpenCV)')
    source = camera.add_mutually_exclusive_group(required=True)
    source.add_argument('--data', help='CSV: view, model_x, model_y (m), u, v (px)')
    source.add_argument('--images', nargs='+', help='photos of a calibration target')
    source.add_argument('--bag', help='a vision_calibrator/calibrate_intrinsics run to rerun')
    camera.add_argument('--target', default='chessboard',
                        choices=['chessboard', 'circles', 'acircles', 'uchiya'],
                        help='uchiya: random-dot markers, matched by LLAH (needs --markers)')
    camera.add_argument('--markers', help='BoofCV descriptions.yaml of the random-dot markers')
    camera.add_argument('--cols', type=int, help='inner corners / circles per row')
    camera.add_argument('--rows', type=int, help='inner corners / circles per column')
    camera.add_argument('--spacing', type=float, help='square size or circle pitch, m')
    camera.add_argument('--image-size', help='WxH in px (default: from images or inferred)')
    camera.add_argument('--length-unit', choices=('m', 'mm', 'um', 'inch'), default='m',
                        help='the unit of model_x, model_y in --data (default: m); the '
                             'report is in m')
    camera.add_argument('--no-distortion', action='store_true', help='fit the pinhole model only (no k1, k2, p1, p2, k3)')
    camera.add_argument('--radial-only', action='store_true', help='k1, k2; no p1, p2, k3')
    camera.add_argument('--reference', help='intrinsics to compare with (BoofCV intrinsic.yaml)')
    camera.add_argument('--json', help='report to write (JSON, SI units)')
    camera.set_defaults(func=deferred('camera_run', 'cmd_calibrate_camera'))
