"""What the machine-description tests share (issue 50): a description file changed in one
section, and a command that must refuse with a given reason."""
import re
from pathlib import Path

import yaml

from machine_alignment.cli import main as cli_main


def changed(source: Path, tmp_path: Path, name: str = 'changed', merge: str = '',
            **sections) -> Path:
    """A copy of the description ``source`` with its top-level ``sections`` replaced (or,
    for the section named by ``merge``, updated key by key), written into ``tmp_path``."""
    content = yaml.safe_load(source.read_text())
    for key, value in sections.items():
        if key == merge:
            content[key].update(value)
        else:
            content[key] = value
    path = tmp_path / f'{name}.yaml'
    path.write_text(yaml.safe_dump(content))
    return path


def refused(capsys, argv: list, pattern: str, out: Path | None = None) -> None:
    """``machine-align argv`` exits with an error that matches ``pattern`` (a regex) and,
    given ``out`` (passed as --out), writes nothing there."""
    assert cli_main([*argv, *(['--out', str(out)] if out else [])]) != 0
    assert out is None or not out.exists()
    error = capsys.readouterr().err
    assert re.search(pattern, error), error
