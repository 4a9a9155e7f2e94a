"""What every subcommand shares: progress on a terminal, JSON output, the image-size
option and reading a calibrator's recorded run from its bag."""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from contextlib import contextmanager
from pathlib import Path

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


def write_report(path, content: dict, plot=None, text: str = '') -> None:
    """The report as JSON at ``path``, ``plot(png_path)``'s figure beside it (same name,
    .png) and the page to hand on (.html: the figure embedded, ``text`` the report as
    printed); nothing without a path."""
    if not path:
        return
    from calib_core.html_report import write_html      # only when a report is written
    write_json(path, content)
    figures = []
    if plot is not None:
        figures.append(Path(path).with_suffix('.png'))
        plot(figures[0])
        print(f'wrote {figures[0]}')
    title = f'{content.get("machine") or content.get("kind") or Path(path).stem} report'
    print(f'wrote {write_html(Path(path).with_suffix(".html"), content, title, figures, text)}')


def parse_size(text: str) -> tuple[int, int]:
    """``WxH`` in px, both positive."""
    try:
        w, h = (int(x) for x in text.lower().split('x'))
    except ValueError:
        raise MachineAlignmentError(f'--image-size must look like 640x480, not {text!r}') from None
    if w <= 0 or h <= 0:
        raise MachineAlignmentError(f'--image-size must be positive, not {text!r}')
    return w, h


def check_writable(path, option: str) -> None:
    """Fail before any work when ``path`` cannot be written: its folder cannot be created
    or written to, or it is a folder where a file is expected."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise MachineAlignmentError(f'{option} {path}: cannot create its folder '
                                    f'({exc.strerror or exc})') from None
    if not os.access(path.parent, os.W_OK):
        raise MachineAlignmentError(f'{option} {path}: its folder {path.parent} is not writable')
    if option == '--json' and path.is_dir():
        raise MachineAlignmentError(f'--json {path} is a folder; give a file name')


def read_run(bag, stop_topic: str, stop_type: str, convert, what: str,
             result_topic: str) -> tuple[list, dict | None]:
    """The stops of a calibrator's recorded run (``stop_type`` messages on ``stop_topic``,
    each passed through ``convert``) and the report of its successful result (on
    ``result_topic``), None if the run ended without one.

    Raises
    ------
    MachineAlignmentError
        The bag holds no such stops (a run of another kind, or a foreign bag), or cannot be
        read."""
    # Imported here, as in bag_temperature_log: rosbags costs the commands that read no
    # bag (every `analyze`) a tenth of a second.
    from calib_core.bags import bag_topics, cut_run_count, decode_bag
    recovered = cut_run_count(bag, stop_topic)      # None for a complete bag
    if recovered == 0:
        raise MachineAlignmentError(f'{bag} is a run cut before its first stop: nothing to '
                                    'replay')
    topics = bag_topics(bag)
    if topics.get(stop_topic) != stop_type:
        held = ', '.join(f'{t} ({m})' for t, m in sorted(topics.items())) or 'no topics'
        raise MachineAlignmentError(f'{bag} holds no {what} ({stop_type} on {stop_topic}); it '
                                    f'holds {held}: a run of another kind?')
    stops, recorded = [], None
    for topic, _, msg in decode_bag(bag, [stop_topic, result_topic]):
        if topic == stop_topic:
            stops.append(convert(msg))
        elif msg.success:
            recorded = json.loads(msg.report_json)
    if not stops:
        raise MachineAlignmentError(f'{bag} holds no {what}: the run stopped before its '
                                    'first stop')
    if recovered is not None:
        print(f'{bag} is a cut run (its writer was stopped before the bag was complete): '
              f'{len(stops)} stops recovered from its journal')
    return stops, recorded


@contextmanager
def unit_hint(args):
    """A dataset read as SI and refused for its values' unit (a UnitMistake) names the
    option of the command (``args``: --length-unit, --angle-unit) that reads it in that
    unit, where the command has it."""
    from calib_core.errors import InvalidInputError, UnitMistake
    try:
        yield
    except UnitMistake as exc:
        option = {'length': ('--length-unit', 'length_unit', 'm'),
                  'angle': ('--angle-unit', 'angle_unit', 'rad')}.get(exc.quantity)
        if option and getattr(args, option[1], None) == option[2]:
            raise InvalidInputError(f'{exc}; or read them as they are with {option[0]} '
                                    f'{exc.likely_unit}') from None
        raise


def read_in_si(read, *args, actuators: tuple, **kwargs):
    """``read(*args, **kwargs)`` of a file the suite reads in SI units; where the lengths
    or angles of one of its ``actuators`` columns look like mm or degrees, the refusal also
    says that a machine description can declare the unit the actuators are read in (not
    for the instrument's columns, nor a temperature: no description changes those).

    Raises
    ------
    InvalidInputError
        As ``read`` does."""
    from calib_core.errors import InvalidInputError, UnitMistake
    try:
        return read(*args, **kwargs)
    except UnitMistake as exc:
        if exc.quantity in ('length', 'angle') and exc.column in actuators:
            raise InvalidInputError(f'{exc}; if the actuators are read in another unit, say '
                                    'so in a machine description and give it with '
                                    '--description (docs/machine_description.md)') from None
        raise


def print_pose_summary(label: str, summary: dict) -> None:
    print(f'  {label:<28} max {summary["max_displacement_m"] * 1e6:8.2f} um '
          f'{summary["max_angle_rad"] * 1e6:8.1f} urad   RMS '
          f'{summary["rms_displacement_m"] * 1e6:8.2f} um {summary["rms_angle_rad"] * 1e6:8.1f} urad')


def quantity(value: float, sigma: float, unit: str) -> str:
    """``value +- sigma unit`` for a report line: no unit for dimensionless ("1") values,
    and a large angle also in degrees."""
    text = f'{value: .9g} +- {sigma:.2g}'
    if unit != '1':
        text += f' {unit}'
    if unit == 'rad' and abs(value) > 0.1:
        text += f' ({value * 180 / 3.141592653589793:.4f} deg)'
    return text


def ranged(kind, low: float | None = None, high: float | None = None, unit: str = '',
           why: str = ''):
    """An argparse ``type`` that parses ``kind`` (int or float) and refuses values outside
    [low, high] (or not finite) at parse time, naming the range, its unit and ``why``."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f'{text!r} is not {"a whole number" if kind is int else "a number"}') from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f'{text!r} is not a finite number')
        if (low is not None and value < low) or (high is not None and value > high):
            span = (f'at least {low:g}' if high is None else f'at most {high:g}' if low is None
                    else f'in {low:g}..{high:g}')
            raise argparse.ArgumentTypeError(
                f'{value:g} must be {span}{" " + unit if unit else ""}{": " + why if why else ""}')
        return value
    parse.__name__ = kind.__name__    # argparse names the type in its own messages
    return parse


def bag_temperature_log(bag):
    """The machine's temperature log a calibrator recorded in its run's bag
    (calib_core.temperature.temperature_log), or None where the run recorded none."""
    from calib_core.bags import bag_topics, decode_bag
    from calib_core.temperature import TEMPERATURE_TOPIC, TEMPERATURE_TYPE, temperature_log
    if bag_topics(bag).get(TEMPERATURE_TOPIC) != TEMPERATURE_TYPE:
        return None
    return temperature_log([msg for _, _, msg in decode_bag(bag, [TEMPERATURE_TOPIC])])
