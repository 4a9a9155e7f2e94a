"""Fuzz the readers of user files (CSV datasets, YAML geometry, machine and marker descriptions,
intrinsics): random bytes, truncations, random column subsets and shuffled or damaged
cells of valid files. Every outcome is either a dataset or a MachineAlignmentError with a
message free of numpy reprs; nothing else may escape (bounded: 120 variants per reader,
seeded)."""
import re
import zlib
from pathlib import Path

import numpy as np
import pytest

from calib_core.axis import AxisData
from calib_core.errors import MachineAlignmentError
from calib_core.sim.axis import AxisTruth, simulate_axis_test
from dispenser_calib.core.data import read_observations, write_observations
from dispenser_calib.core.description import read_description as read_five_axis_description
from dispenser_calib.core.model import nominal_model
from dispenser_calib.core.procedure import plan_stops
from dispenser_calib.core.target_poses import read_target_poses
from dispenser_calib.sim.machine import observe, true_model
from grid_calib.core.data import Region, read_marks, write_marks
from grid_calib.core.description import read_description as read_grid_description
from grid_calib.core.model import Grid
from grid_calib.core.travel import calibrate_travel
from grid_calib.sim.plate import default_travel, measure_travel
from hexapod_calib.core.calibration import PoseData
from hexapod_calib.core.description import read_description as read_hexapod_description
from hexapod_calib.core.geometry import nominal_geometry, read_geometry, write_geometry
from platform_calib.core.description import read_description as read_platform_description
from platform_calib.core.geometry import nominal_geometry as platform_nominal
from platform_calib.core.identification import PoseData as PlatformPoses
from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry
from printer_alignment.core.camera_calibration import read_boofcv_intrinsics, read_correspondences
from printer_alignment.core.dot_markers import load_uchiya_markers
from printer_alignment.core.stage_calibration import StageData
from printer_alignment.core.stage_description import read_description as read_stage_description
from printer_alignment.sim.stage import simulate_calibration_run

REAL = Path(__file__).resolve().parent / 'data' / 'real'
ROOT = Path(__file__).resolve().parents[1]
# The machine descriptions' readers (issue 50), each on its user's example.
DESCRIPTIONS = {
    'hexapod description': ('hexapod_calib/descriptions/hexapod_0.8m_motion_capture.yaml',
                            read_hexapod_description),
    'platform description': ('platform_calib/descriptions/platform_0.6m_tracker.yaml',
                             read_platform_description),
    'five-axis description': ('dispenser_calib/descriptions/five_axis_5mp_mm_deg.yaml',
                              read_five_axis_description),
    'stage description': ('printer_alignment/descriptions/stage_0.5m_rev.yaml',
                          read_stage_description),
    'grid description': ('grid_calib/descriptions/grid_15x15_mm.yaml',
                         read_grid_description),
}
MEASURED = Path(__file__).resolve().parent / 'data' / 'measured'
VARIANTS = 120
# A message shows values as the user wrote them, not numpy's reprs.
NUMPY_REPR = re.compile(r'np\.\w+\(|array\(')


def _valid_files(folder: Path) -> dict:
    axis = folder / 'axis.csv'
    simulate_axis_test(AxisTruth(backlash=3e-6), seed=1).to_csv(axis)
    stage = folder / 'stage.csv'
    simulate_calibration_run(seed=1).to_csv(stage)
    poses = folder / 'poses.csv'
    nominal = nominal_geometry()
    rng = np.random.default_rng(1)
    commanded = np.array([0, 0, 0.2, 0, 0, 0]) + rng.uniform(-0.01, 0.01, (10, 6))
    from hexapod_calib.core.kinematics import inverse_kinematics
    PoseData(commanded, commanded, inverse_kinematics(nominal, commanded)).to_csv(poses)
    camera = folder / 'camera.csv'
    camera.write_text('view,model_x,model_y,u,v\n' + ''.join(
        f'{k // 9},{0.03 * (k % 3)},{0.03 * (k // 3 % 3)},{100 + 40 * (k % 3)},'
        f'{90 + 40 * (k // 3 % 3)}\n' for k in range(27)))
    geometry = folder / 'geometry.yaml'
    write_geometry(geometry, nominal)
    marks, grid = folder / 'marks.csv', Grid(2, 0.01)
    truth = default_travel(grid, 2, 1, seed=1)
    write_marks(marks, grid, {r: Region(truth.origins[r], p)
                              for r, p in measure_travel(grid, truth, 20e-9, 1).items()})
    platform = folder / 'platform.csv'
    measure_poses(PlatformSim(true_geometry(1)), plan_poses(20, 1),
                  platform_nominal()).to_csv(platform)
    five_axis = folder / 'five_axis.csv'
    write_observations(five_axis, observe(true_model(1), plan_stops(nominal_model(), 0))[0])
    described_grid = read_grid_description(ROOT / DESCRIPTIONS['grid description'][0])
    described_marks = folder / 'described_marks.csv'
    truth = default_travel(described_grid.grid, 1, 1, seed=1)
    described_grid.write(described_marks, {
        r: Region(truth.origins[r], p)
        for r, p in measure_travel(described_grid.grid, truth, 50e-9, 1).items()})
    return {
        **{name: (ROOT / path, read) for name, (path, read) in DESCRIPTIONS.items()},
        'grid marks in a described unit': (described_marks, described_grid.read),
        'platform poses': (platform, lambda p: PlatformPoses.from_csv(p)),
        'five-axis observations': (five_axis, read_observations),
        'target poses': (MEASURED / 'ric_two_axis_positioner' / 'positioner_poses.csv',
                         lambda p: read_target_poses(p, 'j1', 'j2')),
        'axis': (axis, AxisData.from_csv),
        'grid marks': (marks, lambda p: calibrate_travel(*read_marks(p, grid.pitch))),
        'stage': (stage, StageData.from_csv),
        'poses': (poses, lambda p: PoseData.from_csv(p, nominal)),
        'camera': (camera, read_correspondences),
        'geometry': (geometry, read_geometry),
        'markers': (REAL / 'boofcv_fiducial_dots' / 'random_dots' / 'descriptions.yaml',
                    load_uchiya_markers),
        'intrinsics': (REAL / 'boofcv_mono' / 'Sony_DSC-HX5V_Chess' / 'intrinsic.yaml',
                       read_boofcv_intrinsics),
    }


def _variant(text: bytes, rng) -> bytes:
    """One damaged version of ``text``."""
    kind = rng.integers(6)
    if kind == 0:                                     # random bytes
        return rng.integers(0, 256, rng.integers(0, 400), dtype=np.uint8).tobytes()
    if kind == 1:                                     # truncated anywhere
        return text[:rng.integers(0, len(text) + 1)]
    lines = text.split(b'\n')
    if kind == 2:                                     # a random subset of the columns
        cells = [line.split(b',') for line in lines]
        width = max(len(c) for c in cells)
        keep = sorted(rng.choice(width, rng.integers(1, width + 1), replace=False))
        return b'\n'.join(b','.join(c[j] for j in keep if j < len(c)) for c in cells)
    if kind == 3:                                     # lines shuffled
        rng.shuffle(lines)
        return b'\n'.join(lines)
    data = bytearray(text)
    if kind == 4 and data:                            # bytes overwritten
        for at in rng.integers(0, len(data), rng.integers(1, 8)):
            data[at] = rng.integers(0, 256)
        return bytes(data)
    words = [b'nan', b'inf', b'-', b'', b'1e308', b'x', b'[', b'{a: 1}', b'\xff']
    cells = text.split(b',')                          # a cell replaced by a hard value
    if len(cells) > 1:
        cells[rng.integers(len(cells))] = words[rng.integers(len(words))]
    return b','.join(cells)


@pytest.fixture(scope='module')
def valid(tmp_path_factory):
    return _valid_files(tmp_path_factory.mktemp('fuzz'))


@pytest.mark.parametrize('reader', ['axis', 'stage', 'poses', 'camera', 'geometry', 'markers',
                                    'intrinsics', 'grid marks', 'platform poses',
                                    'five-axis observations', 'target poses',
                                    'grid marks in a described unit', *DESCRIPTIONS])
def test_damaged_files_give_a_dataset_or_a_clear_error(reader, valid, tmp_path):
    source, read = valid[reader]
    read(source)                                      # the undamaged file reads
    text = source.read_bytes()
    rng = np.random.default_rng(zlib.crc32(reader.encode()))
    outcomes = {'read': 0, 'refused': 0}
    for k in range(VARIANTS):
        damaged = tmp_path / f'{k}{source.suffix}'
        damaged.write_bytes(_variant(text, rng))
        try:
            read(damaged)
            outcomes['read'] += 1
        except MachineAlignmentError as exc:
            assert str(exc), 'an error without a message'
            assert not NUMPY_REPR.search(str(exc)), str(exc)
            outcomes['refused'] += 1
    assert outcomes['refused'] > VARIANTS // 4, outcomes
