"""Atomic, versioned calibration files.

A calibration is written as ``<directory>/<name>.v<N>.yaml`` (never overwritten) and the
current one is ``<directory>/<name>.yaml``, replaced atomically. A process killed midway
leaves either the old or the new current file, never a partial one.
"""
from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import yaml

FILE_MODE = 0o644    # owner writes, everyone reads


def write_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same directory and
    ``os.replace``, so readers see the old or the new content and nothing in between."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    try:
        with os.fdopen(fd, 'w') as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        # mkstemp makes the file 0600; calibrations are read by the machine's other users.
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def next_version(directory: str | os.PathLike, name: str) -> int:
    """Return one more than the highest version of ``name`` in ``directory`` (1 if none)."""
    pattern = re.compile(rf'^{re.escape(name)}\.v(\d+)\.yaml$')
    versions = [int(m.group(1)) for f in Path(directory).glob(f'{name}.v*.yaml')
                if (m := pattern.match(f.name))]
    return max(versions, default=0) + 1


def write_calibration(directory: str | os.PathLike, name: str, content: dict) -> tuple[Path, int]:
    """Write a new version of calibration ``name`` and make it current, with its page to
    hand on beside it (``<name>.v<version>.html``, :mod:`calib_core.html_report`).

    Returns
    -------
    path : Path
        The versioned file written.
    version : int
        Its version number (stored in the file as ``version``).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    version = next_version(directory, name)
    text = yaml.safe_dump({'version': version, **content}, sort_keys=False)
    path = write_atomic(directory / f'{name}.v{version}.yaml', text)
    # The page before the file in force: a page that cannot be written leaves the previous
    # calibration in force, not a new one whose run reported a failure. Imported here: the
    # page's module writes through this one.
    from calib_core.html_report import write_html
    write_html(path.with_suffix('.html'), {'version': version, **content},
               f'{name} calibration, version {version}')
    write_atomic(directory / f'{name}.yaml', text)
    return path, version


def read_calibration(directory: str | os.PathLike, name: str) -> dict | None:
    """Return the current calibration ``name`` in ``directory``, or None if there is none."""
    path = Path(directory) / f'{name}.yaml'
    if not path.exists():
        return None
    with open(path) as stream:
        return yaml.safe_load(stream)
