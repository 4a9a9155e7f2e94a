"""The ROS package's entry points: every node in setup.py has a main(), and every
executable a launch file starts is one of them (launch_ros is not in the venv, so the
launch files are read, not run)."""
import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


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


@pytest.mark.parametrize('launch_file', sorted((ROOT / 'launch').glob('*.launch.py')),
                         ids=lambda p: p.name)
def test_launch_files_start_only_installed_nodes(launch_file):
    executables = [k.value.value for call in ast.walk(ast.parse(launch_file.read_text()))
                   if isinstance(call, ast.Call) for k in call.keywords
                   if k.arg == 'executable']
    assert executables and set(executables) <= set(_nodes()), launch_file.name
