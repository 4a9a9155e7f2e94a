"""CSV datasets (header row, numeric columns) with clear errors for malformed files."""
from __future__ import annotations

import csv
import os

import numpy as np

from calib_core.errors import InvalidInputError
from calib_core.files import csv_table, read_text
from calib_core.storage import write_atomic


# The words an instrument's export may write for a direction of approach (a laser
# system's "+" / "-" or "forward" / "reverse"), read as +1 / -1 in a column whose name
# begins with "direction".
DIRECTION_WORDS = {**dict.fromkeys(('+', 'forward', 'fwd', 'positive', 'pos', 'up'), 1.0),
                   **dict.fromkeys(('-', 'reverse', 'rev', 'backward', 'back', 'bwd',
                                    'negative', 'neg', 'down'), -1.0)}


def _number(cell: str, column: str, decimal_comma: bool = False) -> float:
    """A cell as a float (with ``decimal_comma``, 0,5 as 0.5); in a direction column, also
    one of DIRECTION_WORDS."""
    try:
        return float(cell.replace(',', '.') if decimal_comma else cell)
    except ValueError:
        if column.startswith('direction') and cell.strip().lower() in DIRECTION_WORDS:
            return DIRECTION_WORDS[cell.strip().lower()]
        raise


def read_columns(path: str | os.PathLike, required: list[str],
                 dropped: dict | None = None, labels: tuple = ()) -> dict[str, np.ndarray]:
    """Read a CSV with a header row into float columns (a direction column may also say
    "+" / "-", "forward" / "reverse" and the like: DIRECTION_WORDS); the columns named in
    ``labels`` (names of views, images) as text, stripped. Fields are separated by commas,
    semicolons or tabs, ``#`` lines are notes (files.csv_table); where semicolons or tabs
    separate them, a decimal comma is read as a point (a spreadsheet's 0,5).

    Every column is returned (extra numeric columns are covariates for later analysis).
    Extra columns that are not numeric are left out. Given a ``dropped`` dict, extra
    columns with NaN or infinite values are left out too, with the reason stored in it
    under the column's name; otherwise they are an error.

    Raises
    ------
    InvalidInputError
        Missing file or columns, non-numeric, NaN or infinite values, ragged rows.
    """
    try:
        rows, delimiter = csv_table(read_text(path, 'a CSV dataset'))
    except csv.Error as exc:
        raise InvalidInputError(f'{path} is not a CSV file: {exc}') from None
    if not rows:
        raise InvalidInputError(f'{path} is empty')
    header = [h.strip() for h in rows[0]]
    missing = [c for c in required if c not in header]
    if missing:
        raise InvalidInputError(f'{path} lacks column(s) {", ".join(missing)}; it has '
                                f'{", ".join(header)}')
    body = [r for r in rows[1:] if any(cell.strip() for cell in r)]
    if not body:
        raise InvalidInputError(f'{path} has a header but no data rows')
    columns = {}
    for i, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise InvalidInputError(f'{path} line {i}: {len(row)} fields, header has '
                                    f'{len(header)}')
    for j, name in enumerate(header):
        if name in labels:
            columns[name] = np.array([row[j].strip() for row in body])
            continue
        values = []
        for i, row in enumerate(body, start=2):
            try:
                values.append(_number(row[j], name, delimiter != ','))
            except ValueError:
                if name in required:
                    words = (' nor a direction (+1 / -1, + / -, forward / reverse)'
                             if name.startswith('direction') else '')
                    raise InvalidInputError(f'{path} line {i}: {name}={row[j]!r} is not a '
                                            f'number{words}') from None
                break
        else:
            array = np.array(values)
            if not np.all(np.isfinite(array)):
                bad = int(np.argmax(~np.isfinite(array))) + 2
                if dropped is None or name in required:
                    raise InvalidInputError(f'{path} line {bad}: {name} is NaN or infinite')
                dropped[name] = f'NaN or infinite from line {bad}: column not used'
                continue
            columns[name] = array
    return columns


def directions_from_order(command: np.ndarray) -> np.ndarray:
    """Direction of approach (+1 / -1) of each row from the order the targets were
    visited, shape like ``command`` (n, C): the sign of the last move that changed each
    axis (+1 before the first move)."""
    command = np.asarray(command, dtype=float)
    out = np.ones_like(command)
    last = np.ones(command.shape[1])
    for i in range(1, len(command)):
        step = command[i] - command[i - 1]
        last = np.where(step != 0, np.sign(step), last)
        out[i] = last
    return out


def write_columns(path, names: list[str], columns: list[np.ndarray]) -> None:
    """Write a CSV with a header row (atomically); ``columns`` are (n,) or (n, k) arrays
    whose columns match ``names`` in order."""
    table = np.column_stack(columns)
    lines = [','.join(names)] + [','.join(f'{v:.12g}' for v in row) for row in table]
    write_atomic(path, '\n'.join(lines) + '\n')
