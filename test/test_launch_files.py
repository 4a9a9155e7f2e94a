"""The launch files in launch/ describe the same graphs as machine_alignment.launcher, and
every executable they name is a console script of setup.py that runs the launcher's
module. ``launch`` and ``launch_ros`` are not in the venv: stand-ins record what the
launch files build."""
import ast
import importlib.util
import sys
import types
from pathlib import Path

import pytest

from machine_alignment.launcher import hexapod_graph, printer_graph, stage_graph

REPO = Path(__file__).resolve().parents[1]
GRAPHS = {'printer_sim': printer_graph, 'stage_sim': stage_graph, 'hexapod_sim': hexapod_graph}


def _console_scripts() -> dict:
    """setup.py's NODES: console script name -> module."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    nodes = next(n.value for n in tree.body if isinstance(n, ast.Assign)
                 and any(getattr(t, 'id', '') == 'NODES' for t in n.targets))
    return ast.literal_eval(nodes)


@pytest.fixture
def launch_stand_ins(monkeypatch):
    launch = types.ModuleType('launch')
    launch.LaunchDescription = lambda actions: list(actions)
    actions = types.ModuleType('launch_ros.actions')
    actions.Node = lambda **kwargs: kwargs
    monkeypatch.setitem(sys.modules, 'launch', launch)
    monkeypatch.setitem(sys.modules, 'launch_ros', types.ModuleType('launch_ros'))
    monkeypatch.setitem(sys.modules, 'launch_ros.actions', actions)


def _described(name: str) -> list[dict]:
    spec = importlib.util.spec_from_file_location(name, REPO / 'launch' / f'{name}.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def test_every_graph_has_a_launch_file_and_no_launch_file_is_extra():
    assert sorted(p.name.removesuffix('.launch.py') for p in (REPO / 'launch').glob('*.launch.py')) \
        == sorted(GRAPHS)


@pytest.mark.parametrize('name', sorted(GRAPHS))
def test_launch_file_matches_the_launcher_graph(name, launch_stand_ins):
    nodes, scripts = _described(name), _console_scripts()
    graph = GRAPHS[name]()
    assert [scripts[n['executable']] for n in nodes] == [spec.module for spec in graph]
    assert [n.get('parameters', [{}])[0] for n in nodes] == [spec.parameters for spec in graph]
    assert all(n['package'] == 'machine_alignment' for n in nodes)
