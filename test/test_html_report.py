"""The page a calibration or analysis hands on: one self-contained HTML file with the key
figures, the parameters with their sigmas, what the loop added and left unexplained, the
figure embedded and the whole report; written beside every calibration file and every
analysis report, and rendered in headless Chromium (Debian's ``chromium``, installed by
``make setup`` where the machine can) with every image loaded and no script error."""
import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from calib_core.axis import AxisModel
from calib_core.closed_loop import analyze
from calib_core.html_report import quantity, render_html, write_html
from calib_core.loop_plots import plot_loop
from calib_core.nodes.analysis import printed_report
from calib_core.sim.axis import AxisTruth, simulate_axis_test
from calib_core.storage import write_calibration
from machine_alignment.cli import main as cli_main

CHROMIUM = shutil.which('chromium') or shutil.which('chromium-browser')
# Only in the test's copy of a page: what the browser saw, written into the DOM it dumps.
CHECKER = """<script>
window.seenErrors = [];
window.addEventListener('error', e => window.seenErrors.push(String(e.message)));
window.addEventListener('load', () => {
  const images = [...document.images];
  document.body.setAttribute('data-check', JSON.stringify({
    images: images.length,
    broken: images.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt),
    errors: window.seenErrors}));
});
</script>"""


@pytest.fixture(scope='module')
def loop_page(tmp_path_factory):
    """A backlash of 4 um on a simulated ISO 230-2 axis through the loop: its report, the
    figure and the page."""
    folder = tmp_path_factory.mktemp('page')
    machine = AxisModel(simulate_axis_test(AxisTruth(backlash=4e-6), seed=11))
    result = analyze(machine)
    figure = folder / 'axis.png'
    plot_loop(figure, machine, result)
    page = write_html(folder / 'axis.html', result.report, 'axis closed-loop analysis',
                      [figure], printed_report(result.report))
    return result.report, page


def _text(page: Path) -> str:
    """The page's visible text, tags out and entities decoded."""
    return html.unescape(re.sub(r'<[^>]+>', ' ', page.read_text()))


def test_the_loop_page_holds_its_key_numbers_as_text(loop_page):
    report, page = loop_page
    text = _text(page)
    effect = report['effects_added'][0]
    assert effect['name'] == 'reversal'
    backlash = effect['parameters']['backlash_axis']
    sigma = effect['std_devs']['backlash_axis']
    for number in (quantity(report['rms_before'], 'm'), quantity(report['rms_after'], 'm'),
                   quantity(backlash, 'm', sigma), quantity(sigma, 'm')):
        assert number in text, number
    assert abs(backlash - 4e-6) < 3 * sigma + 0.1e-6         # the page shows a true value
    assert 'The report as printed' in text and 'rows:' in text
    # The whole report is on the page: nothing the JSON had is lost.
    whole = html.unescape(re.search(r'<details>.*?<pre>(.*)</pre>', page.read_text(),
                                    re.S).group(1))
    assert json.loads(whole) == json.loads(json.dumps(report, default=str))
    assert '<script' not in page.read_text() and 'http' not in page.read_text().split('<pre>')[0]


def test_a_calibration_file_gets_its_page_with_parameters_and_sigmas(tmp_path):
    content = {'kind': 'gantry', 'report': {'parameters': {'lead_x': 0.0159972,
                                                           'axis_angle': 5.67e-4},
                                            'std_devs': {'lead_x': 2.1e-8, 'axis_angle': 3e-6},
                                            'units': {'lead_x': 'm', 'axis_angle': 'rad'},
                                            'held_out': {'rms_m': 1.25e-6, 'max_m': 3.1e-6}}}
    path, version = write_calibration(tmp_path, 'vision', content)
    page = path.with_suffix('.html')
    text = _text(page)
    assert version == 1 and 'vision calibration, version 1' in text
    # Each value to its sigma's second digit: 15.9972 mm known to 21 nm is not 16 mm.
    for number in ('15.997200 mm', '21 nm', '567.0 urad', '3 urad', '1.25 um', '3.1 um'):
        assert number in text, number


@pytest.mark.parametrize('value, unit, shown', [
    (1.25e-6, 'm', '1.25 um'), (0.0123, 'm', '12.3 mm'), (4e-9, 'm', '4 nm'),
    (2.5e-5, 'rad', '25 urad'), (0.5, 'm', '0.5 m'), (0.17, 'px', '0.17 px'),
    (float('nan'), 'm', 'nan'), (3, '', '3')])
def test_quantities_read_in_the_units_people_use(value, unit, shown):
    assert quantity(value, unit) == shown


def test_a_value_shows_the_digits_its_sigma_resolves():
    assert quantity(0.0159972, 'm', 2.1e-8) == '15.997200 mm'
    assert quantity(4.0223e-6, 'm', 9.6e-8) == '4.022 um'
    assert quantity(1.5, 'px', 0.25) == '1.50 px'
    assert quantity(2.0, 'm', float('nan')) == '2 m'


def test_text_from_the_report_cannot_become_markup():
    page = render_html({'machine': '<img src=x onerror=alert(1)>', 'effects_added': [],
                        'unexplained': [{'kind': '<b>', 'component': 'x'}], 'rejected': {}},
                       '<script>t</script>')
    assert '<img src=x' not in page and '<script>' not in page and '&lt;b&gt;' in page


def test_analyze_writes_the_page_beside_its_json(tmp_path):
    """The command-line route: ``analyze axis --json`` leaves JSON, PNG and HTML."""
    csv = tmp_path / 'axis.csv'
    assert cli_main(['simulate', 'axis', '--out', str(csv), '--backlash', '4e-6']) == 0
    assert cli_main(['analyze', 'axis', '--data', str(csv), '--json',
                     str(tmp_path / 'a.json')]) == 0
    page = tmp_path / 'a.html'
    report = json.loads((tmp_path / 'a.json').read_text())
    assert quantity(report['rms_after'], 'm') in _text(page)
    assert 'data:image/png;base64,' in page.read_text()


@pytest.mark.skipif(CHROMIUM is None, reason='no chromium (make setup installs Debian\'s '
                                              'where it can: apt install chromium)')
def test_the_page_renders_in_headless_chromium(loop_page, tmp_path):
    report, page = loop_page
    checked = tmp_path / 'checked.html'
    checked.write_text(page.read_text().replace('<head>', '<head>' + CHECKER, 1))
    done = subprocess.run(
        [CHROMIUM, '--headless', '--no-sandbox', '--disable-gpu', '--no-first-run',
         '--disable-background-networking', '--disable-component-update', '--disable-sync',
         f'--user-data-dir={tmp_path / "profile"}', '--virtual-time-budget=5000',
         '--dump-dom', checked.as_uri()], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    seen = json.loads(html.unescape(re.search(r'data-check="([^"]*)"', done.stdout).group(1)))
    assert seen == {'images': 1, 'broken': [], 'errors': []}
    assert quantity(report['rms_after'], 'm') in html.unescape(done.stdout)
