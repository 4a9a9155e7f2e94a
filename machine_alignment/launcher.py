"""The simulated machine graphs, defined once: started here as separate processes from the
venv (no ros2 launch needed), and turned into launch descriptions by the files in
``launch/`` for ROS installs (:func:`launch_arguments`), so the two cannot drift.

Each node runs as ``python -m <module>`` with ``--ros-args`` parameters; Ctrl-C or
:meth:`Graph.stop` ends them all.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from hexapod_calib.sim.hexapod import HexapodTruth
from printer_alignment.sim.gantry import GantryErrors


# Fast DDS: services wait up to 5 s for a new client to match before sending a response.
SERVICE_PROFILE = os.path.join(os.path.dirname(os.path.abspath(__file__)),
                               'fastdds_services.xml')


@dataclass(frozen=True)
class NodeSpec:
    module: str
    parameters: dict = field(default_factory=dict)


def printer_graph(scene: str = 'dot_plate', output_dir: str = 'calibration',
                  record_dir: str = 'runs', camera_rate_hz: float = 4.0,
                  description: str = '') -> list[NodeSpec]:
    """The printer's vision chain: gantry, camera, detector, vision calibrator.
    ``description``: a camera-gantry description YAML the vision calibrator takes (its lens,
    screws, camera, dot plate and travel)."""
    described = {'description': description} if description else {}
    return [
        NodeSpec('printer_alignment.nodes.gantry_sim'),
        NodeSpec('printer_alignment.nodes.camera_sim', {'scene': scene, 'rate_hz': camera_rate_hz}),
        NodeSpec('printer_alignment.nodes.mark_detector', {'continuous': False}),
        NodeSpec('printer_alignment.nodes.vision_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir, **described}),
    ]


def stage_graph(output_dir: str = 'calibration', record_dir: str = 'runs',
                camera_rate_hz: float = 10.0, substrate_shift=(0.0, 0.0, 0.0),
                description: str = '') -> list[NodeSpec]:
    """The printer with its XY-Theta stage (the dot plate removed): gantry, two-way camera
    over the stage, detector, vision calibrator (publishing the calibration in force),
    stage, stage calibrator and aligner. ``description``: a stage description YAML that
    the stage, the camera, the stage calibrator and the aligner take (the simulated stage
    is then the described one under the shipped gantry, and the Marks are taught where
    the simulation mounts them: :func:`printer_alignment.sim.stage.described_home_marks`)."""
    described, taught = {}, {}
    if description:
        from printer_alignment.core.stage_description import read_description
        from printer_alignment.sim.stage import described_home_marks
        described = {'description': description}
        taught = {'calibration_marks': [float(v) for v in np.ravel(
            described_home_marks(read_description(description)))]}
    return [
        NodeSpec('printer_alignment.nodes.gantry_sim'),
        NodeSpec('printer_alignment.nodes.camera_sim',
                 {'scene': 'stage', 'rate_hz': camera_rate_hz,
                  'substrate_shift': [float(v) for v in substrate_shift],
                  **({'stage_description': description} if description else {})}),
        NodeSpec('printer_alignment.nodes.mark_detector', {'continuous': False}),
        NodeSpec('printer_alignment.nodes.vision_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir}),
        NodeSpec('printer_alignment.nodes.stage_sim', dict(described)),
        NodeSpec('printer_alignment.nodes.stage_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir, **described, **taught}),
        NodeSpec('printer_alignment.nodes.aligner', {'record_dir': record_dir, **described}),
    ]


def hexapod_graph(output_dir: str = 'calibration', record_dir: str = 'runs',
                  description: str = '') -> list[NodeSpec]:
    """The hexapod cell: simulated hexapod, pose sensor (CMM / laser tracker), calibrator.
    ``description``: a machine description YAML that all three take (the simulated
    hexapod and sensor are then the described ones, the calibrator plans in its workspace
    and gates by its instrument)."""
    described = {'description': description} if description else {}
    return [
        NodeSpec('hexapod_calib.nodes.hexapod_sim', dict(described)),
        NodeSpec('hexapod_calib.nodes.pose_sensor_sim', dict(described)),
        # The engineer knows the payload the simulated hexapod carries.
        NodeSpec('hexapod_calib.nodes.hexapod_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir,
                  'payload_mass': HexapodTruth.payload_mass,
                  'payload_centre': list(HexapodTruth.payload_centre), **described}),
    ]


def grid_graph(output_dir: str = 'calibration', record_dir: str = 'runs',
               camera_rate_hz: float = 10.0, half: int = 4, pitch: float = 7.5e-3,
               columns: int = 3, rows: int = 2, gantry: dict | None = None,
               description: str = '') -> list[NodeSpec]:
    """The printer's camera gantry over a grid plate: gantry (its temperature published;
    ``gantry``: more of its parameters, such as its warm-up and its screws' expansion),
    camera (the simulated operator places the plate as asked), detector, vision calibrator
    (publishing the calibration in force: the camera's pixel size) and the grid
    calibrator. ``description``: a grid-plate description YAML, whose plate the camera sees
    and whose plate, regions and declared noise the grid calibrator takes (``half``,
    ``pitch``, ``columns`` and ``rows`` then come from it)."""
    plan = {'half': half, 'pitch': pitch, 'columns': columns, 'rows': rows}
    if description:
        from grid_calib.core.description import read_description
        described = read_description(description)
        half, pitch = described.grid.half, described.grid.pitch
        plan = {'description': description}
    return [
        NodeSpec('printer_alignment.nodes.gantry_sim', dict(gantry or {})),
        # The operator squares the plate to the simulated gantry's X axis.
        NodeSpec('printer_alignment.nodes.camera_sim',
                 {'scene': 'grid_plate', 'rate_hz': camera_rate_hz, 'grid_half': half,
                  'grid_pitch': pitch,
                  'plate_square_to': float(GantryErrors().model.axis_angle)}),
        NodeSpec('printer_alignment.nodes.mark_detector', {'continuous': False}),
        NodeSpec('printer_alignment.nodes.vision_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir}),
        NodeSpec('grid_calib.nodes.grid_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir, **plan}),
    ]


def platform_graph(output_dir: str = 'calibration', record_dir: str = 'runs',
                   screw: float = 0.0, backlash: float = 0.0,
                   description: str = '') -> list[NodeSpec]:
    """The screen-registration platform: the platform with its mark cameras, the laser
    tracker and the calibrator (identification and registration). ``description``: a
    machine description YAML that all three take (the simulated platform and tracker are
    then the described ones, the calibrator plans in its box and gates by its noise)."""
    described = {'description': description} if description else {}
    return [
        NodeSpec('platform_calib.nodes.platform_sim',
                 {'screw': screw, 'backlash': backlash, **described}),
        NodeSpec('platform_calib.nodes.laser_tracker_sim', dict(described)),
        NodeSpec('platform_calib.nodes.platform_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir, **described}),
    ]


def five_axis_graph(output_dir: str = 'calibration', record_dir: str = 'runs',
                    bad_fraction: float = 0.05, description: str = '') -> list[NodeSpec]:
    """The five-axis dispenser: the machine with its camera over the dot board, and the
    calibrator. ``description``: a machine description YAML that both take (the simulated
    dispenser is then the described one, the calibrator plans in its strokes and gates by
    its dot noise)."""
    described = {'description': description} if description else {}
    return [
        NodeSpec('dispenser_calib.nodes.five_axis_sim',
                 {'bad_fraction': bad_fraction, **described}),
        NodeSpec('dispenser_calib.nodes.five_axis_calibrator',
                 {'output_dir': output_dir, 'record_dir': record_dir, **described}),
    ]


def launch_arguments(nodes: list[NodeSpec], package: str = 'machine_alignment',
                     config_dir: Path | None = None) -> list[dict]:
    """Keyword arguments of one ``launch_ros.actions.Node`` per node of a graph: the
    executable is the module's console script (named after the module, see setup.py); its
    parameters the node's file in ``config_dir`` (``<node>.yaml``, every default) where
    given, then the graph's own values."""
    out = []
    for spec in nodes:
        name = node_name(spec)
        parameters = ([str(config_dir / f'{name}.yaml')] if config_dir else []) + (
            [dict(spec.parameters)] if spec.parameters else [])
        out.append({'package': package, 'executable': name, 'name': name,
                    **({'parameters': parameters} if parameters else {})})
    return out


def config_dir(package: str = 'machine_alignment') -> Path:
    """The nodes' parameter files: ``share/<package>/config`` of the install (a ROS
    install), else the source tree's ``config/``."""
    try:
        from ament_index_python.packages import (
            PackageNotFoundError, get_package_share_directory)
        return Path(get_package_share_directory(package)) / 'config'
    except (ImportError, OSError, PackageNotFoundError):     # OSError: no ament index set
        return Path(__file__).resolve().parents[1] / 'config'


# The folders a graph writes to, as launch arguments of every launch file.
FOLDER_ARGUMENTS = {'output_dir': ('calibration', 'where the calibrators write calibration files'),
                    'record_dir': ('runs', 'where runs are recorded (MCAP bags)')}


def launch_description(graph: Callable[..., list[NodeSpec]]):
    """The ``ros2 launch`` description of ``graph`` (one of this module's graph functions):
    its nodes, with ``output_dir`` and ``record_dir`` declared as launch arguments
    (``ros2 launch machine_alignment platform_sim.launch.py output_dir:=/data/cal``)."""
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node
    declared = [DeclareLaunchArgument(name, default_value=default, description=meaning)
                for name, (default, meaning) in FOLDER_ARGUMENTS.items()]
    nodes = graph(**{name: LaunchConfiguration(name) for name in FOLDER_ARGUMENTS})
    return LaunchDescription(declared + [Node(**arguments) for arguments
                                         in launch_arguments(nodes, config_dir=config_dir())])


def _format(value) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(_format(v) for v in value) + ']'
    return str(value)


def stop_on_sigterm() -> None:
    """Turn SIGTERM into KeyboardInterrupt in this (main) thread, so a launcher or demo
    stopped by ``kill`` or a service manager unwinds like Ctrl-C: every :class:`Graph`
    it holds stops its nodes instead of leaving them running as orphans. Ctrl-C itself
    raises KeyboardInterrupt even where the process was started with SIGINT ignored (a
    job sent to the background by a non-interactive shell, nohup): a launcher deaf to
    Ctrl-C would leave its whole graph running."""
    def interrupt(signum, frame):
        raise KeyboardInterrupt(f'signal {signum}')
    signal.signal(signal.SIGTERM, interrupt)
    signal.signal(signal.SIGINT, signal.default_int_handler)


def node_name(spec: NodeSpec) -> str:
    """The node's name in the graph: its module's last part (as in the launch files)."""
    return spec.module.rsplit('.', 1)[-1]


def describe_exit(code: int) -> str:
    """A process's return code in words: ``exit code 1`` or ``killed by SIGKILL``."""
    if code < 0:
        try:
            return f'killed by {signal.Signals(-code).name}'
        except ValueError:
            return f'killed by signal {-code}'
    return f'exit code {code}'


class Graph:
    """Running node processes; a context manager that stops them on exit, also when the
    block is left by an exception: SIGINT to every node, SIGTERM to those still running
    after ``sigint_grace``, SIGKILL after ``sigterm_grace`` more (as ``ros2 launch``
    escalates)."""

    def __init__(self, nodes: list[NodeSpec], env: dict | None = None, log_dir: str | None = None,
                 prefix: Callable[[NodeSpec], list[str]] | None = None):
        """``prefix(spec)`` is put before a node's command, e.g. ``ip netns exec <name>`` to
        run each node in the network namespace of the computer it stands for."""
        self.names = [node_name(spec) for spec in nodes]
        self.processes = []
        self.escalations: list[str] = []
        self._logs = []
        environment = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', **(env or {})}
        if not ({'FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE'}
                & environment.keys()):       # the user's own profile wins
            environment['FASTRTPS_DEFAULT_PROFILES_FILE'] = SERVICE_PROFILE
        for spec in nodes:
            args = (prefix(spec) if prefix else []) + [sys.executable, '-m', spec.module]
            if spec.parameters:
                args += ['--ros-args'] + [a for k, v in spec.parameters.items()
                                          for a in ('-p', f'{k}:={_format(v)}')]
            out = None
            if log_dir:
                os.makedirs(log_dir, exist_ok=True)
                out = open(os.path.join(log_dir, node_name(spec) + '.log'), 'w')
                self._logs.append(out)
            self.processes.append(subprocess.Popen(args, env=environment, stdout=out,
                                                   stderr=subprocess.STDOUT if out else None))

    def __enter__(self) -> 'Graph':
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def alive(self) -> list[bool]:
        return [p.poll() is None for p in self.processes]

    def exited(self) -> list[tuple[str, int]]:
        """The nodes that have ended: (name, return code) each, in the graph's order."""
        return [(name, p.returncode) for name, p in zip(self.names, self.processes)
                if p.poll() is not None]

    def stop(self, sigint_grace: float = 5.0, sigterm_grace: float = 5.0) -> None:
        """Stop every node still running, escalating SIGINT -> SIGTERM -> SIGKILL; each
        escalation is noted in :attr:`escalations` (name and signal) for the caller to
        report."""
        for sig, grace in ((signal.SIGINT, sigint_grace), (signal.SIGTERM, sigterm_grace),
                           (signal.SIGKILL, None)):
            running = [(name, p) for name, p in zip(self.names, self.processes)
                       if p.poll() is None]
            if not running:
                break
            for name, p in running:
                if sig != signal.SIGINT:
                    self.escalations.append(f'{name} still running: sent {sig.name}')
                p.send_signal(sig)
            deadline = time.monotonic() + (grace if grace is not None else 5.0)
            for _, p in running:
                try:
                    p.wait(max(deadline - time.monotonic(), 0.05))
                except subprocess.TimeoutExpired:
                    pass
        for log in self._logs:                   # the nodes have ended: nothing more to write
            log.close()
