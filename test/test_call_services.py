"""`machine-align call` offers exactly the operator services the nodes serve (issue 52): a
node that gains a calibrator's or the aligner's service fails here until the shared list
(calib_core/nodes/services.py) names it."""
import ast
from pathlib import Path

from calib_core.nodes.services import OPERATOR_SERVICES
from machine_alignment.cli.call import SERVICES

ROOT = Path(__file__).resolve().parents[1]
# Hardware simulators' services (moves, captures, measurements) are the machine's own, not
# an operator's: their names start with the simulated device.
OPERATOR_PREFIXES = ('vision_calibrator/', 'stage_calibrator/', 'hexapod_calibrator/',
                     'grid_calibrator/', 'platform_calibrator/', 'five_axis_calibrator/',
                     'aligner/')


def _served() -> dict:
    """service name -> (type name, node file) of every create_service call in a node, and
    the ``<node>/cancel`` (Trigger) that a node's CalibratorStatus serves."""
    served = {}
    for path in ROOT.glob('*/nodes/*.py'):
        name, status = None, False
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr == 'create_service' and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant)):
                served[node.args[1].value] = (ast.unparse(node.args[0]), path.name)
            elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                  and node.func.attr == '__init__' and node.args
                  and isinstance(node.args[0], ast.Constant)):
                name = node.args[0].value       # super().__init__('<node name>')
            elif isinstance(node, ast.Call) and getattr(node.func, 'id', '') == 'CalibratorStatus':
                status = True
        if status:
            served[f'{name}/cancel'] = ('Trigger', path.name)
    return served


def test_every_operator_service_a_node_serves_is_offered_by_call():
    served = {name: value for name, value in _served().items()
              if name.startswith(OPERATOR_PREFIXES)}
    assert len(served) >= 19
    assert set(served) == set(OPERATOR_SERVICES)
    for name, (kind, path) in served.items():
        assert OPERATOR_SERVICES[name][0] == kind, (name, path)
        assert SERVICES[name][0].__name__ == kind


def test_the_loop_on_every_machine_can_be_triggered():
    for machine in ('vision', 'stage', 'hexapod', 'platform', 'grid', 'five_axis'):
        assert f'{machine}_calibrator/analyze_residuals' in SERVICES


def test_printed_units_are_the_ones_named():
    """An alignment's leftover in the units its line names (1 arcsec = 4.848 urad), and a
    node's end in words (a clean exit is an exit code, not signal 0)."""
    from machine_alignment.cli.call import alignment_line
    from machine_alignment.launcher import describe_exit
    assert alignment_line(2.5e-6, 4.8481368e-6) == (
        'aligned: 2.50 um, 1.00 arcsec left (measured by the camera)')
    assert describe_exit(0) == 'exit code 0'
    assert describe_exit(1) == 'exit code 1'
    assert describe_exit(-9) == 'killed by SIGKILL'
    assert describe_exit(-15) == 'killed by SIGTERM'
