"""``machine-align detect``: Mark centres (px) in image files."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calib_core.errors import MachineAlignmentError
from machine_alignment.cli import command_help
from machine_alignment.cli.common import progress, write_json
from calib_core.marks import DetectorConfig, detect_marks
from calib_core.marks.pixels import read_grey_image


def cmd_detect(args) -> int:
    config = DetectorConfig(min_size_px=args.min_size, max_size_px=args.max_size,
                            polarity=args.polarity)
    results, failures = [], 0
    for k, path in enumerate(args.images):
        # Checked first: OpenCV would print its own warning for a missing file.
        image = read_grey_image(path) if Path(path).is_file() else None
        entry = {'image': str(path)}
        if image is None:
            entry['error'] = ('no such file' if not Path(path).exists() else
                              'a folder' if Path(path).is_dir() else 'not a readable image')
        else:
            try:
                detection = detect_marks(image, config, '' if args.shape == 'any' else args.shape,
                                         args.expected)
                entry['marks'] = [{'shape': m.shape, 'u_px': m.u, 'v_px': m.v,
                                   'covariance_px2': m.covariance.tolist(), 'size_px': m.size,
                                   'contrast': m.contrast, 'quality': m.quality}
                                  for m in detection.marks]
                entry['rejected'] = detection.rejected
                entry['noise_sigma'] = detection.noise_sigma
            except MachineAlignmentError as exc:
                entry['error'] = str(exc)
        failures += 'error' in entry
        results.append(entry)
        progress(k + 1, len(args.images), 'detect')
        if 'error' in entry:
            print(f'{path}: {entry["error"]}')
        else:
            sigma = np.median([np.sqrt(max(m['covariance_px2'][0][0], m['covariance_px2'][1][1]))
                               for m in entry['marks']])
            print(f'{path}: {len(entry["marks"])} Mark(s), median centre sigma {sigma:.4f} px')
    write_json(args.json, {'images': results})
    if failures == len(args.images):
        raise MachineAlignmentError(f'no Mark detected in any of the {failures} image(s)')
    return 0


def add_parser(sub) -> None:
    detect = sub.add_parser('detect', help=command_help('detect'))
    detect.add_argument('images', nargs='+', help='image files (any format OpenCV reads)')
    detect.add_argument('--json', help='report to write (JSON, SI units)')
    detect.add_argument('--shape', default='any', choices=['any', 'circle', 'cross'],
                        help='the Mark shape to report')
    detect.add_argument('--expected', type=int, default=0, help='exactly this many Marks must be found (0: any number)')
    detect.add_argument('--polarity', default='auto', choices=['auto', 'dark', 'bright'], help='dark Marks on a bright background, bright on dark, or find out')
    detect.add_argument('--min-size', type=float, default=2.5, help='px')
    detect.add_argument('--max-size', type=float, default=120.0, help='px')
    detect.set_defaults(func=cmd_detect)
