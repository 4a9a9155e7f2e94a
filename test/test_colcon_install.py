"""The ROS install route: colcon builds this package as an ament_python package (against
the venv's ROS and interface packages, which ``make setup`` built with colcon as well), and
a node starts the way ``ros2 run machine_alignment <node>`` starts it: the package's prefix
found in the ament index, ``lib/machine_alignment/<node>`` run, the node seen on the graph.
The launch files and their parameter files are installed under share/machine_alignment."""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

DOMAIN = str(120 + os.getpid() % 5)   # each DDS test module has its own band
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

import rclpy  # noqa: E402
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# What setup.py packages (the source tree's bags, tests and data stay out of the copy).
SOURCES = ('setup.py', 'setup.cfg', 'package.xml', 'resource', 'launch', 'config', 'calib_core',
           'printer_alignment', 'hexapod_calib', 'grid_calib', 'platform_calib',
           'dispenser_calib', 'machine_alignment')


def _node_names() -> set:
    import ast
    tree = ast.parse((ROOT / 'setup.py').read_text())
    table = next(n.value for n in tree.body if isinstance(n, ast.Assign)
                 and getattr(n.targets[0], 'id', '') == 'NODES')
    return set(ast.literal_eval(table))


def _colcon_build(workspace: Path) -> subprocess.CompletedProcess:
    source = workspace / 'src' / 'machine_alignment'
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, source / name,
                            ignore=shutil.ignore_patterns('__pycache__', '*.nbi', '*.nbc'))
        elif path.exists():
            source.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, source / name)
    env = {**os.environ, 'AMENT_PREFIX_PATH': sys.prefix,
           'PATH': f'{Path(sys.executable).parent}{os.pathsep}{os.environ["PATH"]}'}
    return subprocess.run(
        [str(Path(sys.executable).parent / 'colcon'), '--log-base', str(workspace / 'log'),
         'build', '--base-paths', str(workspace / 'src'), '--build-base',
         str(workspace / 'build'), '--install-base', str(workspace / 'install'),
         '--merge-install'], cwd=workspace, env=env, capture_output=True, text=True,
        timeout=300)


def test_colcon_builds_the_package_and_a_node_starts_from_its_install(tmp_path):
    built = _colcon_build(tmp_path)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-2000:]
    assert 'Finished <<< machine_alignment' in built.stdout
    install = tmp_path / 'install'
    # What `source install/setup.bash` puts in the environment, then `ros2 run`'s lookup.
    site = install / 'lib' / f'python{sys.version_info[0]}.{sys.version_info[1]}' / \
        'site-packages'
    env = {**os.environ, 'AMENT_PREFIX_PATH': f'{install}{os.pathsep}{sys.prefix}',
           'PYTHONPATH': f'{site}{os.pathsep}{os.environ.get("PYTHONPATH", "")}',
           'ROS_DOMAIN_ID': DOMAIN}
    lookup = subprocess.run(
        [sys.executable, '-c', 'from ament_index_python.packages import get_package_prefix;'
         'print(get_package_prefix("machine_alignment"))'], env=env, capture_output=True,
        text=True, timeout=60)
    assert lookup.returncode == 0, lookup.stderr
    prefix = Path(lookup.stdout.strip())
    assert prefix == install
    share = prefix / 'share' / 'machine_alignment'
    assert {p.name for p in (share / 'launch').glob('*.launch.py')} >= {
        'hexapod_sim.launch.py', 'printer_sim.launch.py'}
    assert {p.name for p in (share / 'config').glob('*.yaml')} == {
        f'{name}.yaml' for name in _node_names()}
    executable = prefix / 'lib' / 'machine_alignment' / 'hexapod_sim'
    assert os.access(executable, os.X_OK)
    # Configured the ROS way: an edited copy of the installed parameter file.
    params = tmp_path / 'hexapod_sim.yaml'
    params.write_text((share / 'config' / 'hexapod_sim.yaml').read_text().replace(
        'rate_hz: 10.0', 'rate_hz: 7.5'))
    node_process = subprocess.Popen(
        [str(executable), '--ros-args', '--params-file', str(params)], env=env, cwd=tmp_path,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    rclpy.init(domain_id=int(DOMAIN))
    watcher = rclpy.create_node('colcon_install_watcher')
    try:
        deadline, names = time.time() + 30, []
        while 'hexapod_sim' not in names and time.time() < deadline:
            rclpy.spin_once(watcher, timeout_sec=0.5)
            names = watcher.get_node_names()
            assert node_process.poll() is None, node_process.stdout.read()
        assert 'hexapod_sim' in names
        client = AsyncParameterClient(watcher, 'hexapod_sim')
        assert client.wait_for_services(timeout_sec=10)
        future = client.get_parameters(['rate_hz'])
        rclpy.spin_until_future_complete(watcher, future, timeout_sec=10)
        assert future.result().values[0].double_value == 7.5
        # It runs the installed copy, not the source tree's.
        where = subprocess.run([sys.executable, '-c', 'import hexapod_calib; '
                                'print(hexapod_calib.__file__)'], env=env,
                               cwd=tmp_path, capture_output=True, text=True, timeout=60)
        assert where.stdout.startswith(str(site)), where.stdout
    finally:
        watcher.destroy_node()
        rclpy.try_shutdown()
        node_process.terminate()
        node_process.wait(timeout=30)
