"""What every subcommand shares: progress on a terminal, JSON output, the image-size
option and reading a calibrator's recorded run from its bag."""
from __future__ import annotations

import json
import sys

from calib_core.bags import decode_bag
from calib_core.errors import MachineAlignmentError
from calib_core.storage import write_atomic


def progress(done: int, total: int, label: str) -> None:
    if not sys.stderr.isatty():
        return
    width = 30
    filled = int(width * done / max(total, 1))
    sys.stderr.write(f'\r{label} [{"#" * filled}{"." * (width - filled)}] {done}/{total}')
    if done == total:
        sys.stderr.write('\n')
    sys.stderr.flush()


def write_json(path, content) -> None:
    if path:
        write_atomic(path, json.dumps(content, indent=2) + '\n')
        print(f'wrote {path}')


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split('x'))
    except ValueError:
        raise MachineAlignmentError(f'--image-size must look like 640x480, not {text!r}') from None
    return w, h


def read_run(bag, stop_suffix: str, convert, what: str,
             result_suffix: str = '/result') -> tuple[list, dict | None]:
    """The stops of a calibrator's recorded run (messages on the topic ending in
    ``stop_suffix``, each passed through ``convert``) and the report of its successful
    result (topic ending in ``result_suffix``), None if the run ended without one."""
    stops, recorded = [], None
    for topic, _, msg in decode_bag(bag):
        if topic.endswith(stop_suffix):
            stops.append(convert(msg))
        elif topic.endswith(result_suffix) and msg.success:
            recorded = json.loads(msg.report_json)
    if not stops:
        raise MachineAlignmentError(f'{bag} holds no {what}')
    return stops, recorded


def print_pose_summary(label: str, summary: dict) -> None:
    print(f'  {label:<28} max {summary["max_displacement_m"] * 1e6:8.2f} um '
          f'{summary["max_angle_rad"] * 1e6:8.1f} urad   RMS '
          f'{summary["rms_displacement_m"] * 1e6:8.2f} um {summary["rms_angle_rad"] * 1e6:8.1f} urad')
