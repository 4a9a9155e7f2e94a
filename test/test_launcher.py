"""The launcher watches its nodes (issue 31): a node that dies is named, the others are
stopped, and ``machine-align launch`` exits non-zero, in every graph; Ctrl-C stops a graph
with exit 0; a node deaf to SIGINT and SIGTERM is escalated to SIGKILL, and each
escalation is reported."""
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

from machine_alignment.launcher import (
    Graph, NodeSpec, five_axis_graph, grid_graph, hexapod_graph, platform_graph, printer_graph,
    node_name, stage_graph)
from machine_alignment.live import LiveClient

GRAPHS = {'printer': printer_graph, 'stage': stage_graph, 'hexapod': hexapod_graph,
          'grid': grid_graph, 'platform': platform_graph, 'five-axis': five_axis_graph}
DOMAINS = {name: str(60 + i) for i, name in enumerate(GRAPHS)}


def children(pid: int) -> list[int]:
    path = Path(f'/proc/{pid}/task/{pid}/children')
    return [int(c) for c in path.read_text().split()] if path.exists() else []


def command_line(pid: int) -> str:
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode()
    except OSError:
        return ''


def launch(graph: str, tmp_path: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, '-m', 'machine_alignment.cli', 'launch', graph,
         '--output-dir', str(tmp_path / graph / 'calibration'),
         '--record-dir', str(tmp_path / graph / 'runs')],
        env={**os.environ, 'ROS_DOMAIN_ID': DOMAINS[graph]}, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)


def wait_for_nodes(launcher: subprocess.Popen, graph: str, timeout: float = 90.0) -> list[int]:
    """The node processes of ``graph``, once each node is in the ROS graph (a node
    interrupted while it still imports dies with Python's KeyboardInterrupt trace)."""
    names = {node_name(spec) for spec in GRAPHS[graph]()}
    deadline = time.monotonic() + timeout
    with LiveClient('launcher_test_probe', int(DOMAINS[graph])) as probe:
        while not names <= set(probe.node.get_node_names()):
            assert time.monotonic() < deadline, f'{graph}: {names} did not all come up'
            probe.executor.spin_once(timeout_sec=0.2)
    return children(launcher.pid)


def test_a_killed_node_is_named_in_every_graph_and_the_rest_are_stopped(tmp_path):
    # All six graphs at once, each on its own domain: the last node of each is killed.
    launchers = {name: launch(name, tmp_path) for name in GRAPHS}
    try:
        victims = {}
        for name, launcher in launchers.items():
            nodes = wait_for_nodes(launcher, name)
            module = GRAPHS[name]()[-1].module
            victims[name] = next(pid for pid in nodes if module in command_line(pid))
        for name, pid in victims.items():
            os.kill(pid, signal.SIGKILL)
        for name, launcher in launchers.items():
            _, stderr = launcher.communicate(timeout=30)
            victim = GRAPHS[name]()[-1].module.rsplit('.', 1)[-1]
            assert launcher.returncode == 2, (name, stderr)
            assert f'{victim} ended (killed by SIGKILL)' in stderr, (name, stderr)
            assert 'the other nodes were stopped' in stderr, (name, stderr)
            assert 'Traceback' not in stderr, (name, stderr)
            assert children(launcher.pid) == []
    finally:
        for launcher in launchers.values():
            if launcher.poll() is None:
                launcher.kill()


def test_ctrl_c_stops_the_graph_cleanly(tmp_path):
    launcher = launch('platform', tmp_path)
    nodes = wait_for_nodes(launcher, 'platform')
    launcher.send_signal(signal.SIGINT)
    _, stderr = launcher.communicate(timeout=30)
    assert launcher.returncode == 0, stderr
    assert 'still running' not in stderr, stderr
    assert not any(Path(f'/proc/{pid}').exists() and command_line(pid) for pid in nodes)


@pytest.fixture
def deaf_module(tmp_path):
    (tmp_path / 'deaf_node.py').write_text(textwrap.dedent('''
        import signal, time
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        print('ignoring', flush=True)
        time.sleep(600)
    '''))
    return tmp_path


def test_a_node_deaf_to_sigint_and_sigterm_is_killed_and_reported(deaf_module):
    graph = Graph([NodeSpec('deaf_node')], env={'PYTHONPATH': str(deaf_module)},
                  log_dir=str(deaf_module / 'logs'))
    deadline = time.monotonic() + 10
    while 'ignoring' not in (deaf_module / 'logs' / 'deaf_node.log').read_text():
        assert time.monotonic() < deadline, 'the test node did not start'
        time.sleep(0.05)
    started = time.monotonic()
    graph.stop(sigint_grace=0.5, sigterm_grace=0.5)
    assert time.monotonic() - started < 5
    assert graph.exited() == [('deaf_node', -signal.SIGKILL)]
    assert graph.escalations == ['deaf_node still running: sent SIGTERM',
                                 'deaf_node still running: sent SIGKILL']
