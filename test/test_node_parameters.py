"""docs/nodes.md's parameter tables are read from the nodes' code: every
``declare_parameter(name, default)`` of every node in setup.py, with its default and the
comment on its line. The test fails when the two differ (MACHINE_ALIGN_WRITE_DOCS=1
rewrites the tables)."""
import ast
import os
from pathlib import Path

import numpy as np

from calib_core.nodes.calibrator import PATH_DEFAULTS
from calib_core.nodes.status import DEFAULT_MAX_AGE_DAYS

ROOT = Path(__file__).resolve().parents[1]
NODES_DOC = ROOT / 'docs' / 'nodes.md'
START = '<!-- parameter tables: written by test/test_node_parameters.py -->'
END = '<!-- end of the parameter tables -->'


def _nodes() -> dict:
    tree = ast.parse((ROOT / 'setup.py').read_text())
    table = next(n.value for n in tree.body if isinstance(n, ast.Assign)
                 and getattr(n.targets[0], 'id', '') == 'NODES')
    return ast.literal_eval(table)


def _default(node: ast.expr) -> str:
    """The default as a reader wants it: evaluated when it is arithmetic on numbers (np
    allowed), else as written."""
    source = ast.unparse(node)
    try:
        value = eval(compile(ast.Expression(node), '<default>', 'eval'), {'np': np, 'float': float})
    except Exception:  # a name from the module (a constant): show it as written
        return f'`{source}`'
    if isinstance(value, float):
        return f'{value:.6g}'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(f'{v:.6g}' if isinstance(v, float) else repr(v)
                               for v in value) + ']'
    return repr(value) if isinstance(value, str) else str(value)


def _parameters(module: str) -> list[tuple[str, str, str]]:
    path = ROOT / (module.replace('.', '/') + '.py')
    lines = path.read_text().splitlines()
    rows = []
    calls = sorted((c for c in ast.walk(ast.parse(path.read_text())) if isinstance(c, ast.Call)),
                   key=lambda c: (c.lineno, c.col_offset))
    for call in calls:
        if isinstance(call, ast.Call) and getattr(call.func, 'attr', '') == 'declare_parameter':
            name = ast.literal_eval(call.args[0])
            line = lines[call.lineno - 1]
            comment = line.split('#', 1)[1].strip() if '#' in line else ''
            rows.append((name, _default(call.args[1]) if len(call.args) > 1 else '', comment))
        elif isinstance(call, ast.Call) and getattr(call.func, 'id', '') == 'declare_paths':
            rows += [(folder, repr(PATH_DEFAULTS[folder]), 'read-only: set at launch')
                     for folder in map(ast.literal_eval, call.args[1:])]
        elif isinstance(call, ast.Call) and getattr(call.func, 'id', '') == 'CalibratorStatus':
            rows.append(('max_calibration_age_days', f'{DEFAULT_MAX_AGE_DAYS:g}',
                         'days; older: WARN on /diagnostics (calib_core.nodes.status)'))
    return rows


def tables() -> str:
    out = [START, 'Read from each node\'s `declare_parameter` calls (default as in the code; '
                  'the note is the comment on that line). Units: SI unless the name says '
                  '(`_s`, `_hz`, `_px`).', '']
    for name, module in sorted(_nodes().items()):
        rows = _parameters(module)
        if not rows:
            continue
        out += [f'`{name}` (`{module}`)', '', '| parameter | default | note |', '|---|---|---|']
        out += [f'| `{p}` | {d} | {c.replace("|", "/")} |' for p, d, c in rows]
        out.append('')
    return '\n'.join(out + [END])


def test_the_parameter_tables_are_the_code():
    text = NODES_DOC.read_text()
    assert START in text and END in text
    before, rest = text.split(START, 1)
    written = before + tables() + rest.split(END, 1)[1]
    if os.environ.get('MACHINE_ALIGN_WRITE_DOCS'):
        NODES_DOC.write_text(written)
    assert written == text, 'docs/nodes.md differs from the nodes\' parameters: run ' \
        'MACHINE_ALIGN_WRITE_DOCS=1 pytest test/test_node_parameters.py'


def test_every_node_with_parameters_has_a_table():
    tables_text = tables()
    for name, module in _nodes().items():
        if _parameters(module):
            assert f'`{name}` (`{module}`)' in tables_text
    assert '| `output_dir` |' in tables_text and '| `design` | \'random\' |' in tables_text
