"""Reading a user's text files (CSV, YAML) with one clear error for every way it can fail:
missing, a directory, unreadable, binary or not UTF-8, not YAML. The message names the
file and says what it is for."""
from __future__ import annotations

import csv
import io
import os
import re

import yaml

from calib_core.errors import InvalidInputError


def read_text(path: str | os.PathLike, what: str) -> str:
    """The text of ``path`` (UTF-8; a leading byte-order mark, which spreadsheets write
    and no one sees, is dropped).

    Raises
    ------
    InvalidInputError
        Missing, a directory, unreadable, or not UTF-8 text (e.g. a binary file)."""
    try:
        with open(path, encoding='utf-8-sig', newline='') as stream:
            text = stream.read()
    except FileNotFoundError:
        raise InvalidInputError(f'no such file: {path} (expected {what})') from None
    except IsADirectoryError:
        raise InvalidInputError(f'{path} is a directory, not {what}') from None
    except UnicodeDecodeError as exc:
        raise InvalidInputError(f'{path} is not UTF-8 text (byte {exc.start}): a binary file? '
                                f'expected {what}') from None
    except OSError as exc:
        raise InvalidInputError(f'cannot read {path}: {exc.strerror} (expected {what})') from None
    if '\x00' in text:
        raise InvalidInputError(f'{path} holds NUL bytes: a binary file, not {what}')
    return text


DELIMITERS = (',', ';', '\t')
"""Field separators a CSV may use: a comma, or a semicolon (a spreadsheet where the comma
is the decimal separator) or a tab (an instrument's export)."""


def csv_table(text: str) -> tuple[list, str]:
    """The rows (lists of fields) of CSV ``text`` and its separator: the one of DELIMITERS
    its header line holds most of (a comma where it holds none). Blank lines and lines
    starting with ``#`` (an instrument's notes above or between its rows) are left out,
    but for a note right above rows that are all numbers: their header, as numpy.savetxt
    writes it.

    Raises
    ------
    csv.Error
        Text the csv module cannot read."""
    every = [line for line in text.splitlines(keepends=True) if line.strip()]
    lines = [line for line in every if not line.lstrip().startswith('#')]
    header = lines[0] if lines else ''
    # numpy.savetxt writes its header as a note ('# x,y'): a note right above rows that
    # are all numbers is their header.
    first = every.index(header) if header else 0
    if first and _all_numbers(header) and not _all_numbers(every[first - 1].lstrip()[1:]):
        header = every[first - 1].lstrip()[1:]
        lines.insert(0, header)
    delimiter = max(DELIMITERS, key=header.count) if any(d in header for d in DELIMITERS) \
        else ','
    return list(csv.reader(io.StringIO(''.join(lines)), delimiter=delimiter)), delimiter


def _all_numbers(line: str) -> bool:
    """Whether every field of ``line`` (split at any of DELIMITERS) is a number."""
    try:
        for field in re.split('[,;\t]', line.strip()):
            float(field.replace(',', '.'))
    except ValueError:
        return False
    return True


def read_csv_rows(path: str | os.PathLike, what: str, columns, error=InvalidInputError) -> list:
    """The rows of a CSV file as dicts (see :func:`csv_table`), refused (``error``, an
    InvalidInputError) when it is not CSV, empty, or lacks one of ``columns``."""
    try:
        table, _ = csv_table(read_text(path, what))
    except csv.Error as exc:
        raise error(f'{path} is not a CSV file: {exc}') from None
    header = [name.strip() for name in table[0]] if table else []
    # A short row's missing fields are None, as csv.DictReader gives them.
    rows = [dict(zip(header, row + [None] * (len(header) - len(row)))) for row in table[1:]
            if any(cell.strip() for cell in row)]
    if not rows or any(c not in rows[0] for c in columns):
        raise error(f'{path} needs the columns {", ".join(columns)}')
    return rows


class _NumbersAsTyped(getattr(yaml, 'CSafeLoader', yaml.SafeLoader)):
    """PyYAML's safe loader (on libyaml's parser where PyYAML has it: a 180 kB marker
    description reads several times faster) that also reads ``10e-6`` and ``1e3`` as
    numbers, as YAML 1.2 and people do (YAML 1.1 needs a dot, ``1.0e-5``, and leaves
    ``10e-6`` a string)."""


_NumbersAsTyped.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$'),
    list('-+0123456789'))


def load_yaml(text: str):
    """YAML ``text`` read safely, exponents without a dot as numbers (yaml.YAMLError for
    text that is not YAML)."""
    return yaml.load(text, Loader=_NumbersAsTyped)


MAX_REQUEST_BYTES = 16 * 1024
"""The largest plan or options text a service takes: a plan is a few keys, and a request
of megabytes is refused before it is parsed."""


class _PlanLoader(_NumbersAsTyped):
    """The safe loader, refusing a mapping that gives one key twice (``nx: 3`` then
    ``nx: 4`` would silently take the second)."""

    def construct_mapping(self, node, deep=False):
        keys = [self.construct_object(key, deep=True) for key, _ in node.value]
        repeated = sorted({str(k) for k in keys if keys.count(k) > 1})
        if repeated:
            raise InvalidInputError(f'the key(s) {", ".join(repeated)} given twice')
        return super().construct_mapping(node, deep)


def load_request_yaml(text: str):
    """A service request's YAML (a plan, loop options), read safely and refused before
    any expansion when it is longer than :data:`MAX_REQUEST_BYTES`, uses aliases (a few
    hundred bytes of nested aliases expand to gigabytes) or repeats a key.

    Raises
    ------
    InvalidInputError, yaml.YAMLError"""
    size = len(text.encode('utf-8', 'replace'))
    if size > MAX_REQUEST_BYTES:
        raise InvalidInputError(f'the request is {size} bytes, more than the '
                                f'{MAX_REQUEST_BYTES} a plan takes')
    if any(isinstance(event, yaml.AliasEvent) for event in yaml.parse(text, Loader=_PlanLoader)):
        raise InvalidInputError('YAML aliases (*name) are not taken in a request: write the '
                                'values out')
    return yaml.load(text, Loader=_PlanLoader)


def read_yaml(path: str | os.PathLike, what: str):
    """The YAML content of ``path``; errors as :func:`read_text`, and for text that is not
    YAML."""
    try:
        return load_yaml(read_text(path, what))
    except yaml.YAMLError as exc:
        raise InvalidInputError(f'{path} is not valid YAML ({what}): {exc}') from None
