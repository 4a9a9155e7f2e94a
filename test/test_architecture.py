"""The layers of the source tree, checked on every import (top-level or inside a function).

    machine_alignment            the app: CLI, demo, launcher, benchmarks
         |
    <machine>/nodes              thin ROS nodes (rclpy, messages)
    <machine>/sim                simulated hardware
    <machine>/core               models, identification, procedures (numpy/scipy/OpenCV;
                                 numba for the Mark detector's fit in calib_core/marks)
         |
    calib_core                   shared bottom layer; calib_core/nodes: shared node helpers,
                                 calib_core/sim: shared simulated hardware (the axis)

A layer imports only downwards. Sim nodes (``*_sim.py`` in ``nodes/``) are the only nodes
that may use ``sim/``; machine packages do not import each other."""
import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MACHINES = ('printer_alignment', 'hexapod_calib', 'grid_calib', 'platform_calib',
            'dispenser_calib')
APP = 'machine_alignment'
ROS = ('rclpy', 'alignment_msgs', 'sensor_msgs', 'std_msgs', 'std_srvs', 'builtin_interfaces',
       'geometry_msgs', 'launch', 'launch_ros')


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            # Relative imports would hide the layer they reach; the code base has none.
            assert not node.level, f'{path}:{node.lineno}: use an absolute import'
            found += [(node.lineno, node.module)]
            found += [(node.lineno, f'{node.module}.{alias.name}') for alias in node.names]
    return found


def _forbidden(module: str) -> list[str]:
    """Prefixes ``module`` (dotted, relative to the repository) must not import."""
    parts = module.split('.')
    top = parts[0]
    if top == APP:
        return []
    room = parts[1] if len(parts) > 1 else ''
    if top == 'calib_core':
        below_app = [APP, *MACHINES]
        if room == 'nodes':
            return [*below_app, 'calib_core.sim']
        return [*below_app, *ROS, 'calib_core.nodes', *([] if room == 'sim' else ['calib_core.sim'])]
    if top in MACHINES:
        others = [APP, *(m for m in MACHINES if m != top)]
        sims = [f'{top}.sim', 'calib_core.sim']
        if room in ('core', 'sim'):
            return [*others, *ROS, f'{top}.nodes', 'calib_core.nodes',
                    *(sims if room == 'core' else [])]
        if room == 'nodes':
            return [*others, *([] if parts[-1].endswith('_sim') else sims)]
        return [*others, *ROS]
    return []


def layer_violations(root: Path) -> list[str]:
    """Every import under ``root`` that goes up a layer, as 'path:line: a imports b'."""
    violations = []
    for path in sorted(root.rglob('*.py')):
        relative = path.relative_to(root)
        if relative.parts[0] not in ('calib_core', APP, *MACHINES):
            continue
        module = '.'.join(relative.with_suffix('').parts)
        forbidden = _forbidden(module)
        reported = set()
        for line, imported in _imports(path):
            upward = any(imported == f or imported.startswith(f + '.') for f in forbidden)
            if upward and line not in reported:  # one line per import statement
                reported.add(line)
                violations.append(f'{relative}:{line}: {module} imports {imported}')
    return violations


def test_no_layer_imports_upwards():
    assert layer_violations(REPO) == []


def _tree(tmp_path: Path, files: dict) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


def test_the_check_catches_each_kind_of_upward_import(tmp_path):
    root = _tree(tmp_path, {
        'calib_core/fit.py': 'def f():\n    from printer_alignment.core import stage\n',
        'calib_core/plot.py': 'import rclpy\n',
        'calib_core/axis.py': 'from calib_core.sim.axis import AxisTruth\n',
        'calib_core/sim/axis.py': 'from calib_core.axis import AxisData\n',
        'calib_core/nodes/helper.py': 'import rclpy\nfrom calib_core.fit import f\n',
        'printer_alignment/core/model.py': 'from printer_alignment.sim.stage import TRUE\n',
        'printer_alignment/sim/stage.py': 'from alignment_msgs.msg import Pose\n',
        'printer_alignment/nodes/calibrator.py': 'from printer_alignment.sim import stage\n',
        'printer_alignment/nodes/stage_sim.py': 'from printer_alignment.sim import stage\n',
        'hexapod_calib/core/geometry.py': 'from machine_alignment.cli import main\n',
        'hexapod_calib/sim/hexapod.py': 'from printer_alignment.core.model import x\n',
        'machine_alignment/cli.py': 'import rclpy\nfrom printer_alignment.sim import stage\n',
    })
    found = [v.split(':')[0] for v in layer_violations(root)]
    # The app may import anything, calib_core/nodes may use rclpy and calib_core, a sim may
    # use its core and a sim node may use sim/: those files are not reported.
    assert found == ['calib_core/axis.py', 'calib_core/fit.py', 'calib_core/plot.py', 'hexapod_calib/core/geometry.py',
                     'hexapod_calib/sim/hexapod.py', 'printer_alignment/core/model.py',
                     'printer_alignment/nodes/calibrator.py', 'printer_alignment/sim/stage.py']
