"""The README's table of measured results cannot drift from the results files: every number
in a row's before, after and paper columns must be in the file its last column names (to
the digits README prints), and that file must exist."""
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NUMBER = re.compile(r'(?<![\w.])-?\d+(?:\.\d+)?(?:e-?\d+)?')


def _rows() -> list[list[str]]:
    text = (REPO / 'README.md').read_text()
    table = text.split('## Measured', 1)[1].split('\n## ', 1)[0]
    rows = [[c.strip() for c in line.strip('|').split('|')]
            for line in table.splitlines() if line.startswith('|')]
    return [r for r in rows[2:] if len(r) == 5]        # skip the header and the rule


def _matches(number: str, available: set[str]) -> bool:
    """``number`` as printed equals some number of the file rounded to the same digits."""
    digits = len(number.split('.')[1]) if '.' in number else 0
    value = float(number)
    return any(abs(round(float(a), digits) - value) < 10 ** -digits / 2 for a in available)


def test_readme_table_has_rows_and_sources():
    rows = _rows()
    assert len(rows) >= 6
    for row in rows:
        source = re.search(r'`([^`]+)`', row[4])
        assert source and (REPO / source.group(1)).is_file(), row[4]


def test_every_readme_number_is_in_its_results_file():
    missing = []
    for machine, before, after, paper, source in _rows():
        text = (REPO / re.search(r'`([^`]+)`', source).group(1)).read_text()
        available = set(NUMBER.findall(text))
        for number in NUMBER.findall(' '.join((before, after, paper))):
            if not _matches(number, available):
                missing.append(f'{machine}: {number} not in {source}')
    assert not missing, '\n'.join(missing)


def test_the_check_finds_a_number_that_drifted():
    assert _matches('140.9', {'140.90', '49.48'})
    assert not _matches('140.8', {'140.90', '49.48'})
    assert _matches('6.4', {'6.37'}) and not _matches('6.3', {'6.37'})
