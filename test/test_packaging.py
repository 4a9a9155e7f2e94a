"""The ROS package's entry points: every node in setup.py has a main(), and the launch
files in launch/ describe the same graphs as machine_alignment.launcher, naming only
installed executables. ``launch`` and ``launch_ros`` are not in the venv: stand-ins record
what the launch files build."""
import ast
import importlib
import importlib.util
import sys
import types
from dataclasses import dataclass
from pathlib import Path

import pytest

from machine_alignment.launcher import (
    five_axis_graph, grid_graph, hexapod_graph, platform_graph, printer_graph, stage_graph)

ROOT = Path(__file__).resolve().parents[1]
GRAPHS = {'printer_sim': printer_graph, 'stage_sim': stage_graph, 'hexapod_sim': hexapod_graph,
          'grid_sim': grid_graph, 'platform_sim': platform_graph, 'five_axis_sim': five_axis_graph}


def _nodes() -> dict:
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for statement in tree.body:
        if isinstance(statement, ast.Assign) and statement.targets[0].id == 'NODES':
            return ast.literal_eval(statement.value)
    raise AssertionError('setup.py defines no NODES')


def test_every_node_entry_point_has_a_main():
    nodes = _nodes()
    assert {'stage_sim', 'stage_calibrator', 'aligner', 'vision_calibrator'} <= set(nodes)
    for name, module in nodes.items():
        assert callable(getattr(importlib.import_module(module), 'main', None)), name


@dataclass(frozen=True)
class Configuration:
    """Stand-in for launch.substitutions.LaunchConfiguration."""
    name: str


@pytest.fixture
def launch_stand_ins(monkeypatch):
    launch = types.ModuleType('launch')
    launch.LaunchDescription = lambda actions: list(actions)
    launch_actions = types.ModuleType('launch.actions')
    launch_actions.DeclareLaunchArgument = lambda name, **kwargs: {'argument': name, **kwargs}
    substitutions = types.ModuleType('launch.substitutions')
    substitutions.LaunchConfiguration = Configuration
    actions = types.ModuleType('launch_ros.actions')
    actions.Node = lambda **kwargs: kwargs
    monkeypatch.setitem(sys.modules, 'launch', launch)
    monkeypatch.setitem(sys.modules, 'launch.actions', launch_actions)
    monkeypatch.setitem(sys.modules, 'launch.substitutions', substitutions)
    monkeypatch.setitem(sys.modules, 'launch_ros', types.ModuleType('launch_ros'))
    monkeypatch.setitem(sys.modules, 'launch_ros.actions', actions)


def _described(name: str) -> list[dict]:
    spec = importlib.util.spec_from_file_location(name, ROOT / 'launch' / f'{name}.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def test_every_graph_has_a_launch_file_and_no_launch_file_is_extra():
    assert sorted(p.name.removesuffix('.launch.py') for p in (ROOT / 'launch').glob('*.launch.py')) \
        == sorted(GRAPHS)


@pytest.mark.parametrize('name', sorted(GRAPHS))
def test_launch_file_matches_the_launcher_graph(name, launch_stand_ins):
    described, scripts = _described(name), _nodes()
    arguments = [a for a in described if 'argument' in a]
    nodes = [n for n in described if 'argument' not in n]
    # The folders are launch arguments with the launcher's defaults.
    assert {a['argument']: a['default_value'] for a in arguments} == \
        {'output_dir': 'calibration', 'record_dir': 'runs'}
    folders = {name: Configuration(name) for name in ('output_dir', 'record_dir')}
    graph = GRAPHS[name](**folders)
    assert [scripts[n['executable']] for n in nodes] == [spec.module for spec in graph]
    # Each node's parameter file (every default) first, then the graph's own values.
    assert [Path(n['parameters'][0]).name for n in nodes] == [
        f'{n["executable"]}.yaml' for n in nodes]
    assert all(Path(n['parameters'][0]).is_file() for n in nodes)
    assert [(n['parameters'][1:] or [{}])[0] for n in nodes] == [spec.parameters
                                                                  for spec in graph]
    assert any(Configuration('output_dir') in (n['parameters'][1:] or [{}])[0].values()
               for n in nodes)
    assert all(n['package'] == 'machine_alignment' for n in nodes)
