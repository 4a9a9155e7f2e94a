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


CONFIG = ROOT / 'config'


def _values(module: str, computed: list | None = None) -> dict:
    """Each declared parameter's default value, evaluated in the node module's namespace
    (its constants), in declaration order; the path parameters and the calibrators' status
    parameter as :func:`_parameters` lists them. An empty list has no type a parameter
    file can state, and a default the node computes as it starts (a time stamp) none to
    write: both are left out, the latter named in ``computed``."""
    import importlib
    namespace = vars(importlib.import_module(module))
    path = ROOT / (module.replace('.', '/') + '.py')
    values = {}
    calls = sorted((c for c in ast.walk(ast.parse(path.read_text())) if isinstance(c, ast.Call)),
                   key=lambda c: (c.lineno, c.col_offset))
    for call in calls:
        if getattr(call.func, 'attr', '') == 'declare_parameter' and len(call.args) > 1:
            try:
                value = eval(compile(ast.Expression(call.args[1]), str(path), 'eval'),
                             {**namespace, 'np': np})
            except NameError:       # a local of the node's __init__
                (computed if computed is not None else []).append(
                    ast.literal_eval(call.args[0]))
                continue
            value = value.tolist() if isinstance(value, np.ndarray) else value
            value = list(value) if isinstance(value, tuple) else value
            if value != []:
                values[ast.literal_eval(call.args[0])] = value
        elif getattr(call.func, 'id', '') == 'declare_paths':
            values.update({folder: PATH_DEFAULTS[folder]
                           for folder in map(ast.literal_eval, call.args[1:])})
        elif getattr(call.func, 'id', '') == 'CalibratorStatus':
            values['max_calibration_age_days'] = DEFAULT_MAX_AGE_DAYS
    return values


def parameter_file(name: str, module: str) -> str:
    """config/<name>.yaml: the node's parameters with their defaults, in the format
    ``--ros-args --params-file`` and launch files read."""
    import yaml
    computed = []
    values = _values(module, computed)
    header = (f'# {name} ({module}): every parameter with its default, as the code declares '
              'it.\n# Edit a copy and pass it: ros2 run machine_alignment '
              f'{name} --ros-args --params-file {name}.yaml\n# (written by '
              'test/test_node_parameters.py; docs/nodes.md says what each one means)\n')
    if computed:
        header += f'# Left out, computed as the node starts: {", ".join(computed)}\n'
    return header + yaml.safe_dump({name: {'ros__parameters': values}}, sort_keys=False,
                                   default_flow_style=False)


def test_every_node_has_a_parameter_file_with_the_code_defaults():
    import yaml
    for name, module in sorted(_nodes().items()):
        path = CONFIG / f'{name}.yaml'
        text = parameter_file(name, module)
        if os.environ.get('MACHINE_ALIGN_WRITE_DOCS'):
            CONFIG.mkdir(exist_ok=True)
            path.write_text(text)
        assert path.exists() and path.read_text() == text, \
            f'{path} differs from the code: run MACHINE_ALIGN_WRITE_DOCS=1 pytest {__file__}'
        # Read back (YAML, as rcl's parser types it), each value as the code declares it.
        loaded = yaml.safe_load(path.read_text())[name]['ros__parameters']
        declared = _values(module)
        assert loaded == declared, name
        for key, value in loaded.items():
            first = value[0] if isinstance(value, list) else value
            expected = declared[key][0] if isinstance(declared[key], list) else declared[key]
            assert type(first) is type(expected), (name, key)
