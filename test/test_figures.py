"""Every figure a page embeds was drawn by today's code in a named run: its PNG carries the
run and a hash of the modules that drew it (calib_core.figures.save_figure), the hash must
match those modules in this tree, and the figures in docs/figures must come from the run
bench_results/demo_run.log names (one `make figures` run: text and figures agree). A stale
figure fails here until `make figures` (or `make bench` for bench_results/) draws it again."""
import re
from pathlib import Path

import matplotlib
import pytest

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from calib_core.figures import ROOT, RUN_VARIABLE, code_hash, read_stamp, save_figure  # noqa: E402

PAGES = sorted((ROOT / 'docs').glob('*.md')) + [ROOT / 'README.md']
IMAGE_LINK = re.compile(r'!\[[^\]]*\]\(([^)\s]+\.png)\)')


def _embedded() -> list[Path]:
    found = {(page.parent / link).resolve() for page in PAGES
             for link in IMAGE_LINK.findall(page.read_text())}
    return sorted(found)


def _demo_run() -> str:
    header = (ROOT / 'bench_results' / 'demo_run.log').read_text().splitlines()[0]
    match = re.search(r'run "([^"]+)"', header)
    assert match, f'demo_run.log names no run: {header!r}'
    return match.group(1)


def test_pages_embed_figures():
    assert len(_embedded()) >= 8


@pytest.mark.parametrize('figure', _embedded(), ids=lambda p: str(p.relative_to(ROOT)))
def test_each_embedded_figure_was_drawn_by_todays_code_in_a_named_run(figure):
    assert figure.is_file(), f'{figure} is embedded but missing'
    stamp = read_stamp(figure)
    assert stamp, f'{figure.name} carries no stamp: draw it again (make figures / make bench)'
    assert stamp['run'] and stamp['run'] != 'unnamed'
    missing = [m for m in stamp['modules'] if not (ROOT / m).is_file()]
    assert not missing, f'{figure.name} was drawn by modules no longer here: {missing}'
    assert code_hash(stamp['modules']) == stamp['code'], (
        f'{figure.name} was drawn by other code than {stamp["modules"]} in this tree: '
        'draw it again (make figures / make bench)')
    if figure.parent == ROOT / 'docs' / 'figures':
        assert stamp['run'] == _demo_run(), (
            f'{figure.name} is from run {stamp["run"]!r}, the text beside it from '
            f'{_demo_run()!r}: make figures')


def test_a_stamp_names_its_run_and_goes_stale_when_its_code_changes(tmp_path, monkeypatch):
    monkeypatch.setenv(RUN_VARIABLE, 'test run 7')
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    save_figure(fig, tmp_path / 'f.png', [__file__])
    plt.close(fig)
    stamp = read_stamp(tmp_path / 'f.png')
    assert stamp['run'] == 'test run 7'
    assert stamp['modules'] == sorted(['calib_core/figures.py', 'test/test_figures.py'])
    assert code_hash(stamp['modules']) == stamp['code']
    # The same names over other contents: another hash.
    other = tmp_path / 'tree'
    for module in stamp['modules']:
        (other / module).parent.mkdir(parents=True, exist_ok=True)
        (other / module).write_text((ROOT / module).read_text() + '\n# changed\n')
    assert code_hash(stamp['modules'], other) != stamp['code']
    fig, _ = plt.subplots()
    fig.savefig(tmp_path / 'plain.png')            # drawn without the stamp
    plt.close(fig)
    assert read_stamp(tmp_path / 'plain.png') == {}
