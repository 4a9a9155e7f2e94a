"""The work of the subcommands ``export.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

import dataclasses

import numpy as np

from calib_core.errors import MachineAlignmentError
from calib_core.temperature import run_covariates, stamp_seconds
from dispenser_calib.core.data import write_observations
from dispenser_calib.core.records import (
    OBSERVATIONS_TOPIC as FIVE_AXIS_TOPIC, RESULT_TOPIC as FIVE_AXIS_RESULT_TOPIC,
    image_from_message)
from grid_calib.core.data import write_marks
from hexapod_calib.core.calibration import PoseData as HexapodPoseData
from hexapod_calib.core.records import (
    HEXAPOD_RESULT_TOPIC, MEASUREMENTS_TOPIC as HEXAPOD_TOPIC, measurement_record)
from machine_alignment.cli.common import bag_temperature_log, read_run
from machine_alignment.cli.grid_run import grid_run
from platform_calib.core.procedure import data_of
from platform_calib.core.records import (
    MEASUREMENTS_TOPIC as PLATFORM_TOPIC, RESULT_TOPIC as PLATFORM_RESULT_TOPIC,
    stop_from_message)
from printer_alignment.core.records import (
    STAGE_OBSERVATIONS_TOPIC, STAGE_RESULT_TOPIC, stage_data_from_messages)


def _stamped(convert):
    """``convert`` of a stop message, with the stop's header stamp (s)."""
    return lambda msg: (convert(msg), stamp_seconds(msg))


def _covariates(bag, stamps) -> dict:
    """The run's covariates per stop (time, and temperature where the bag has it)."""
    covariates, why = run_covariates(stamps, bag_temperature_log(bag))
    if why:
        print(why)
    return covariates


def _stage(bag):
    messages, _ = read_run(bag, STAGE_OBSERVATIONS_TOPIC, 'alignment_msgs/msg/StageObservation',
                           lambda msg: msg, 'stage calibration observations', STAGE_RESULT_TOPIC)
    data, why = stage_data_from_messages(messages, bag_temperature_log(bag))
    if why:
        print(why)
    return data, 'every stop'


def _platform(bag):
    stamped, _ = read_run(bag, PLATFORM_TOPIC, 'alignment_msgs/msg/PlatformMeasurement',
                          _stamped(stop_from_message), 'platform measurements',
                          PLATFORM_RESULT_TOPIC)
    identified = [(s, t) for s, t in stamped if s.phase == 'identify']
    if not identified:
        raise MachineAlignmentError(f'{bag} holds no identification poses')
    stops, stamps = zip(*identified)
    data = data_of(list(stops))
    covariates = {**data.covariates, **_covariates(bag, stamps)}
    return dataclasses.replace(data, covariates=covariates), 'the identification poses'


def _hexapod(bag):
    stamped, _ = read_run(bag, HEXAPOD_TOPIC, 'alignment_msgs/msg/HexapodMeasurement',
                          _stamped(measurement_record), 'hexapod calibration measurements',
                          HEXAPOD_RESULT_TOPIC)
    records, stamps = zip(*stamped)
    # (phase, target, leg lengths, measured): every stop, as the calibrator's own analysis
    columns = [np.array([r[k] for r in records]) for k in (1, 3, 2)]
    return (HexapodPoseData(*columns, _covariates(bag, stamps)),
            'every stop (all rounds and the evaluation)')


@dataclasses.dataclass
class _Images:
    """A five-axis run's images, written as the observations CSV."""

    images: list

    def __len__(self):
        return len(self.images)

    def to_csv(self, path):
        write_observations(path, self.images)


def _five_axis(bag):
    recorded, _ = read_run(bag, FIVE_AXIS_TOPIC, 'alignment_msgs/msg/FiveAxisObservation',
                           image_from_message, 'five-axis observations', FIVE_AXIS_RESULT_TOPIC)
    phases = sorted({phase for _, phase in recorded})
    return _Images([image for image, _ in recorded]), f'the images ({", ".join(phases)})'


@dataclasses.dataclass
class _Marks:
    """A grid run's complete regions, written as the marks CSV."""

    grid: object
    regions: dict

    def __len__(self):
        return sum(len(p.marks) for region in self.regions.values()
                   for p in region.placements)

    def to_csv(self, path):
        write_marks(path, self.grid, self.regions)


def _grid(bag):
    grid, regions, _ = grid_run(bag)
    return _Marks(grid, regions), f'the readings of region(s) {", ".join(map(str, regions))}'


READERS = {'stage': _stage, 'platform': _platform, 'hexapod': _hexapod,
           'five-axis': _five_axis, 'grid': _grid}
NEXT = {'hexapod': 'analyze hexapod --data {out} --geometry NOMINAL.yaml',
        'five-axis': ('analyze rotary --data {out} --calibration five_axis.yaml (a sweep with '
                      'the linear axes held), or calibrate five-axis --data {out}'),
        'grid': 'analyze grid --data {out} --pitch PITCH (the plate\'s, m)'}


def cmd_export(args) -> int:
    data, which = READERS[args.machine](args.bag)
    data.to_csv(args.out)
    follow = NEXT.get(args.machine, f'analyze {args.machine} --data {{out}}').format(out=args.out)
    print(f'wrote {args.out}: {len(data)} rows, {which} of {args.bag}; run the closed loop '
          f'with: machine-align {follow}')
    return 0
