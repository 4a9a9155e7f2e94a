"""The README's table of measured results cannot drift from the results files: every number
in a row's before, after and paper columns is claimed below with where it comes from (a
table cell found by its row and column, or a line of a log), and must equal that value to
the digits the README prints. A number no claim covers, a claim whose text is not in its
row and column, or a value that moved, fails; so does swapping a row's before and after."""
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NUMBER = re.compile(r'(?<![\w.])-?\d+(?:\.\d+)?(?:e-?\d+)?')
COLUMNS = ('before', 'after', 'paper')


def _tables(path: str) -> list[list[dict]]:
    """Every markdown table of a results file, as rows keyed by the header's cells."""
    tables, block = [], []
    for line in (REPO / path).read_text().splitlines() + ['']:
        if line.startswith('|'):
            block.append([c.strip() for c in line.strip().strip('|').split('|')])
            continue
        if len(block) > 2:
            tables.append([dict(zip(block[0], row)) for row in block[2:]])
        block = []
    return tables


def cell(path: str, column: str, **where) -> list[str]:
    """The numbers of the cell in ``column`` of the one row whose cells equal ``where``
    (keys are column names with spaces as underscores)."""
    where = {k.replace('_', ' '): v for k, v in where.items()}
    found = [row[column] for table in _tables(path) for row in table
             if column in row and all(row.get(k) == v for k, v in where.items())]
    assert len(found) == 1, f'{path}: {len(found)} rows with {where} and a {column} column'
    return NUMBER.findall(found[0])


def column(path: str, name: str) -> list[str]:
    """The numbers of every row's cell in column ``name`` (the first table that has it)."""
    table = next(t for t in _tables(path) if name in t[0])
    return [n for row in table for n in NUMBER.findall(row[name])]


def firsts(path: str, name: str) -> list[float]:
    """The first number of every row's cell in column ``name`` (the first table that has
    it): a median before its range, a count before its total."""
    table = next(t for t in _tables(path) if name in t[0])
    return [float(NUMBER.findall(row[name])[0]) for row in table]


def line(path: str, regex: str) -> list[str]:
    """The groups of the first match of ``regex`` in the file."""
    match = re.search(regex, (REPO / path).read_text())
    assert match, f'{path}: no {regex!r}'
    return list(match.groups())


STAGE, HEXAPOD, DEMO = 'bench_results/stage.md', 'bench_results/hexapod.md', \
    'bench_results/demo_run.log'
LOOP, AXIS, CHANNELS = 'bench_results/closed_loop.md', 'bench_results/closed_loop_axis.md', \
    'bench_results/closed_loop_channels.md'
GRID_ROW = {'runs': '200', 'sigma': '20 nm', 'plate_error_(RMS)': '1 um'}
PLAN = 'bench_results/plan_platform.md'
PLAN_FIVE_AXIS = 'bench_results/plan_five_axis.md'
PLAN_STAGE = 'bench_results/plan_stage.md'
TODAY = "today's 27 stops (12 linear, A alone at 4 tilts, C alone at 11 angles)"
PLANNED = 'planned 27 stops, I (15 linear, 3 a, 2 c, 7 both)'
ROTARY = 'bench_results/closed_loop_rotary.md'
CAMERAS = 'bench_results/camera_real.md'
DOTS, MAKO = ('640 x 480, 10 x 10 dot grid, 14 views',
              'AVT Mako 1600 x 1200, ChArUco corners, 15 views')
SCREW = 'periodic on chain 2 only (1.5 um, 2 mm lead)'
DRIFTING_TRACKER = 'drift_time: the tracker drifting 15 um over the run'
DRIFTING_ISO_RUN = ('drift_sequence: -15.8 um over a sparse ISO 230-2 run (5 targets), '
                    'backlash 5 um')
REAL_RUN = 'mcu1025_run_a (stepper axis, laser triangulation sensor, 5 targets x 5 cycles)'

# (README row: its machine cell starts with this, column, text in that cell, its numbers)
CLAIMS = [
    ('Mark detection', 'after', '0.97-1.10x', lambda: [
        f'{min(firsts("bench_results/results.md", "ours/CRB (95 % interval)")):.2f}',
        f'{max(firsts("bench_results/results.md", "ours/CRB (95 % interval)")):.2f}']),
    ('printer vision', 'before', 'max 72.2 um, RMS 41.1 um',
     lambda: line(DEMO, r'before: max ([\d.]+) um, RMS ([\d.]+) um')),
    ('printer vision', 'after', 'max 8.08 um, RMS 4.68 um',
     lambda: line(DEMO, r'after: +max ([\d.]+) um, RMS ([\d.]+) um')),
    ('printer vision', 'after', 'held-out RMS 0.38 um',
     lambda: line(DEMO, r'closed loop added .*?held-out RMS [\d.]+ -> ([\d.]+) um')),
    ('XY-Theta stage', 'before', 'max 140.9 um, 16.85"', lambda: (
        cell(STAGE, 'position max', poses='200 poses x 5', model='before (nominal)')
        + cell(STAGE, 'orientation max', poses='200 poses x 5', model='before (nominal)'))),
    ('XY-Theta stage', 'after', 'max 6.37 um (1.81x its repeatability RP_l), 4.70" (1.77x RP_a)',
     lambda: [cell(STAGE, name, poses='200 poses x 5', model='parametric')[0] for name in
              ('position max', 'position max / RP_l', 'orientation max',
               'orientation max / RP_a')]),
    ('XY-Theta stage', 'paper', 'max 12.3 um, 0.720"',
     lambda: line(STAGE, r"paper's maxima after calibration: ([\d.]+) um and ([\d.]+)\"")),
    ('hexapod', 'before', '377 um / 3115 urad', lambda: cell(HEXAPOD, 'before max (median)',
                                                           poses='13')),
    ('hexapod', 'after', '10.3 um / 72 urad (median)', lambda: cell(
        HEXAPOD, 'after max (median)', poses='13')),
    ('hexapod', 'after', '15.0 um / 94 urad (worst)', lambda: cell(
        HEXAPOD, 'after max (worst)', poses='13')),
    ('hexapod', 'paper', '12.1 um / 1100 urad', lambda: cell(
        HEXAPOD, 'after max (median)', poses='paper (13)')),
    ('grid self-calibration', 'after', 'RMS(G - true) 0.948 sigma', lambda: cell(
        'bench_results/grid.md', 'RMS(G - true) / sigma, global: mean (p95)',
        **GRID_ROW)[:1]),
    ('grid self-calibration', 'after', 'by 0, 1 or 3 um RMS', lambda: sorted(
        cell('bench_results/grid.md', 'plate error (RMS)', runs='200', sigma='20 nm',
             **{'plate_error_(RMS)': plate})[0] for plate in ('0 um', '1 um', '3 um'))),
    ('grid self-calibration', 'after', 'propagation ratio 0.953', lambda: cell(
        'bench_results/grid.md', 'propagation ratio u(G) / sigma',
        **GRID_ROW)),
    ('printer gantry', 'before', 'max 12.51 um, RMS 7.15 um', lambda: [
        cell('bench_results/grid_gantry.md', name, gantry='with periodic error',
             approach='unidirectional', calibration='vision calibration')[0]
        for name in ('max', 'RMS')]),
    ('printer gantry', 'after', 'max 1.64 um, RMS 0.85 um', lambda: [
        cell('bench_results/grid_gantry.md', name, gantry='with periodic error',
             approach='unidirectional', calibration='vision + grid self-calibration')[0]
        for name in ('max', 'RMS')]),
    ('printer gantry', 'after', '0.12 um without', lambda: cell(
        'bench_results/grid_gantry.md', 'RMS', gantry='without periodic error',
        approach='unidirectional', calibration='vision + grid self-calibration')[:1]),
    ('screen-registration platform', 'before', 'median 0.378 mm, worst 1.987 mm', lambda: [
        cell('bench_results/platform.md', name, method='before')[0]
        for name in ('median', 'worst')]),
    ('screen-registration platform', 'after', 'median 0.0098 mm, worst 0.058 mm', lambda: [
        cell('bench_results/platform.md', name, method='exact')[0]
        for name in ('median', 'worst')]),
    ('screen-registration platform', 'after', "PSO settings: 2.40 mm", lambda: cell(
        'bench_results/platform.md', 'median',
        method='pso, source settings (4 iterations, +-6 mm)')),
    ('screen-registration platform', 'paper', '0.21-1.96 mm -> about 0.10 mm', lambda: line(
        'bench_results/platform.md', r'Source: ([\d.]+)-([\d.]+) mm before, about ([\d.]+) mm')),
    ('platform measurement plan', 'before', '24 random poses: RMS 9.65 um', lambda: [
        '24', *cell(PLAN, 'realised RMS (range)', design='random, 24 poses')[:1]]),
    ('platform measurement plan', 'after', '12 planned poses: RMS 8.88 um', lambda: [
        '12', *cell(PLAN, 'realised RMS (range)', design='I-optimal, 12 poses')[:1]]),
    ('platform measurement plan', 'after', 'predicted 8.38 um', lambda: cell(
        PLAN, 'predicted RMS', design='I-optimal, 12 poses')),
    ('stage measurement plan', 'before', 'today\'s 130 stops: RMS 0.300 um', lambda: [
        *cell(PLAN_STAGE, 'stops', plan='today (130 stops)'),
        *cell(PLAN_STAGE, 'realised RMS over the stages (um)', plan='today (130 stops)')]),
    ('stage measurement plan', 'after', '59 stops (short sweeps, 40 planned): RMS 0.454 um, '
     'predicted 0.470 um before anything moved; as good as 59 random ones (0.470 um)', lambda: [
         *cell(PLAN_STAGE, 'stops', plan='planned 40'), '40',
         *cell(PLAN_STAGE, 'realised RMS over the stages (um)', plan='planned 40'),
         *cell(PLAN_STAGE, 'predicted RMS (um)', plan='planned 40'),
         *cell(PLAN_STAGE, 'stops', plan='random 40 (for 40)'),
         *cell(PLAN_STAGE, 'realised RMS over the stages (um)', plan='random 40 (for 40)')]),
    ('dispenser measurement plan', 'before', 'E_B0A 0.370 mrad, part placement 3.12 um RMS',
     lambda: [*cell(PLAN_FIVE_AXIS, 'E_B0A realised', plan=TODAY),
              *cell(PLAN_FIVE_AXIS, 'placement realised', plan=TODAY)]),
    ('dispenser measurement plan', 'after', '27 planned stops: E_B0A 0.168 mrad, part '
     'placement 1.35 um, predicted 0.131 mrad and 1.17 um', lambda: [
         '27', *cell(PLAN_FIVE_AXIS, 'E_B0A realised', plan=PLANNED),
         *cell(PLAN_FIVE_AXIS, 'placement realised', plan=PLANNED),
         *cell(PLAN_FIVE_AXIS, 'E_B0A predicted', plan=PLANNED),
         *cell(PLAN_FIVE_AXIS, 'placement predicted', plan=PLANNED)]),
    ('five-axis', 'before', '38.2 px', lambda: line(
        'bench_results/five_axis.md', r'median of 10\): ([\d.]+) ->')),
    ('five-axis', 'after', '0.124 px after 3 iterations (floor 0.125 px)', lambda: [
        *_settled(line('bench_results/five_axis.md', r'median of 10\): ([\d. >-]+) px')[0]),
        *line('bench_results/five_axis.md', r'noise floor is ([\d.]+) px')]),
    ('five-axis', 'after', 'located to 1.52 um', lambda: line(
        'bench_results/five_axis.md', r'pairwise distance error mean ([\d.]+) um')),
    ('five-axis', 'after', 'within 4.28 um mean (1482 um', lambda: line(
        'bench_results/five_axis.md', r'mean ([\d.]+) um, max [\d.]+ um calibrated; mean ([\d.]+) um')),
    ('five-axis', 'after', 'within 3 sigma', lambda: ['3']),
    ('five-axis', 'paper', '0.17 px; 7.5 um', lambda: line(
        'bench_results/five_axis.md', r'in 2 iterations, ([\d.]+) px\)')
        + line('bench_results/five_axis.md', r'source: ([\d.]+) um mean')),
    ('closed loop (18 simulated', 'after', 'found exactly the undeclared effects in 356 of '
     '360 runs, 0 wrong claims', lambda: [
         f'{sum(firsts(LOOP, "found exactly it")):g}',
         str(sum(int(n) for n in column(LOOP, 'found exactly it')[1::2])),
         f'{sum(firsts(LOOP, "wrong claims")):g}']),
    ('closed loop (18 simulated', 'after', '1 of 20 of the drifting tracker', lambda: [
        str(20 - int(cell(LOOP, 'found exactly it', undeclared_effect=DRIFTING_TRACKER)[0])),
        cell(LOOP, 'found exactly it', undeclared_effect=DRIFTING_TRACKER)[1]]),
    ('closed loop (18 simulated', 'after', 'is found in 20 of 20 by preferring', lambda: [
        cell(LOOP, 'found exactly it', undeclared_effect=DRIFTING_ISO_RUN)[0],
        cell(LOOP, 'found exactly it', undeclared_effect=DRIFTING_ISO_RUN)[1]]),
    ('closed loop (18 simulated', 'after', 'missed: 3 of 20 runs of a 1.5 um screw error',
     lambda: [str(20 - int(cell(LOOP, 'found exactly it', undeclared_effect=SCREW)[0])),
              cell(LOOP, 'found exactly it', undeclared_effect=SCREW)[1],
              NUMBER.findall(SCREW)[1]]),
    ('closed loop (18 simulated', 'after', 'held-out RMS median 1.00-1.13x', lambda: [
        f'{min(firsts(LOOP, "after / floor")):.2f}',
        f'{max(firsts(LOOP, "after / floor")):.2f}']),
    ('closed loop, clean data', 'after', '3 runs with a finding', lambda: [
        str(sum(map(int, column(LOOP, 'runs with a finding'))))]),
    ('closed loop, real ISO', 'before', 'held-out RMS 27.9 um, max 105 um', lambda: [
        cell(AXIS, name, real_run=REAL_RUN)[0]
        for name in ('held-out RMS before -> after', 'held-out max before -> after')]),
    ('closed loop per channel', 'after', 'in 20 of 20, 0 wrong claims, 0 on 20 clean runs',
     lambda: cell(CHANNELS, 'found on exactly the true feeds', case='feed 2 only')
     + cell(CHANNELS, 'wrong claims', case='feed 2 only')
     + cell(CHANNELS, 'wrong claims', case='clean')
     + line(CHANNELS, r'(\d+) seeds per case')),
    ('closed loop per channel', 'after', 'held-out RMS 1.004x', lambda: cell(
        CHANNELS, 'held-out RMS after / clean floor (median)', case='feed 2 only')),
    ('closed loop, rotary table', 'after', '8 um twice-per-turn radial error motion of C named '
     'as error motion in 20 of 20, a 150 urad angle error of the same order as an angle error '
     'in 20 of 20, a 50 urad tilt error motion as tilt in 20 of 20; 0 wrong claims, 0 on 20 '
     'clean runs', lambda: [
         line(ROTARY, r'radial error motion (\d+) um')[0]]
     + cell(ROTARY, 'found with exactly its orders', case='C radial error motion')
     + line(ROTARY, r'angle error (\d+) urad') + cell(ROTARY, 'found with exactly its orders', case='C angle error')
     + line(ROTARY, r'tilt error motion (\d+) urad')
     + cell(ROTARY, 'found with exactly its orders', case='C tilt error motion')
     + [str(sum(int(cell(ROTARY, 'wrong claims', case=c)[0])
                for c in ('C radial error motion', 'C angle error', 'C tilt error motion')))]
     + cell(ROTARY, 'wrong claims', case='clean') + line(ROTARY, r'(\d+) seeds per case')),
    ('closed loop, two real cameras', 'before',
     'held-out RMS 0.317 px, max 3.80 px (dots); 0.940 px, max 3.10 px (Mako)', lambda: [
         n for camera in (DOTS, MAKO) for n in (_camera(camera, 'held-out RMS')[0],
                                                _camera(camera, 'held-out max')[0])]),
    ('closed loop, two real cameras', 'after',
     'k1, k2, k3, p1, p2 added, 0.198 px, max 1.40 px, a 0.026 px trend', lambda: [
         _camera(DOTS, 'held-out RMS')[1], _camera(DOTS, 'held-out max')[1],
         _camera(DOTS, 'left unexplained')[0]]),
    ('closed loop, two real cameras', 'after',
     'k1, k2 only, 0.664 px, max 2.65 px; every coefficient within 0.7 sigma', lambda: [
         _camera(MAKO, 'held-out RMS')[1], _camera(MAKO, 'held-out max')[1],
         str(max(float(_camera(c, 'largest difference')[0]) for c in (DOTS, MAKO)))]),
    ('closed loop, real tilt', 'before', 'held-out RMS 418 um, max 921 um', lambda: line(
        'bench_results/rotary_positioner.log',
        r'held out, pooled [^:]*: RMS (\d+) -> \d+ um, max (\d+) ->')),
    ('closed loop, real tilt', 'after', 'RMS 310 um, max 647 um', lambda: line(
        'bench_results/rotary_positioner.log',
        r'held out, pooled [^:]*: RMS \d+ -> (\d+) um, max \d+ -> (\d+)')),
]


def _camera(camera: str, column: str) -> list[str]:
    return cell(CAMERAS, column, camera=camera)


def _settled(sequence: str) -> list[str]:
    """'38.2 -> 0.74 -> 0.124 -> 0.124': the value it settles at and the iterations to it."""
    values = sequence.split(' -> ')
    return [values[-1], str(values.index(values[-1]))]


def _readme_rows(text: str) -> list[list[str]]:
    table = text.split('## Measured', 1)[1].split('\n## ', 1)[0]
    rows = [[c.strip() for c in line.strip('|').split('|')]
            for line in table.splitlines() if line.startswith('|')]
    return [r for r in rows[2:] if len(r) == 5]        # skip the header and the rule


def _equal(printed: str, value: str) -> bool:
    """``value`` rounded to the digits ``printed`` shows equals it."""
    digits = len(printed.split('.')[1]) if '.' in printed else 0
    return abs(round(float(value), digits) - float(printed)) < 10 ** -digits / 2


def problems(readme: str) -> list[str]:
    """What in ``readme``'s Measured table no claim traces to its results file."""
    out = []
    rows = _readme_rows(readme)
    covered = {}
    for prefix, name, text, source in CLAIMS:
        matching = [r for r in rows if r[0].startswith(prefix)]
        if len(matching) != 1:
            out.append(f'{len(matching)} README rows start with {prefix!r}')
            continue
        content = matching[0][1 + COLUMNS.index(name)]
        where = content.find(text)
        if where < 0:
            out.append(f'{prefix}, {name}: {text!r} is not in {content!r}')
            continue
        covered.setdefault((prefix, name), []).append((where, where + len(text)))
        printed, values = NUMBER.findall(text), source()
        if len(printed) != len(values) or not all(map(_equal, printed, values)):
            out.append(f'{prefix}, {name}: README {printed}, results file {values}')
    for row in rows:
        for k, name in enumerate(COLUMNS):
            spans = [s for (prefix, n), found in covered.items()
                     if row[0].startswith(prefix) and n == name for s in found]
            for match in NUMBER.finditer(row[1 + k]):
                if not any(a <= match.start() and match.end() <= b for a, b in spans):
                    out.append(f'{row[0]}, {name}: {match.group()} is claimed by nothing')
    return out


def test_every_readme_number_is_traced_to_its_row_and_column():
    readme = (REPO / 'README.md').read_text()
    assert len(_readme_rows(readme)) >= 12
    for row in _readme_rows(readme):
        source = re.search(r'`([^`]+)`', row[4])
        assert source and (REPO / source.group(1)).is_file(), row[4]
    assert problems(readme) == []


def test_a_swapped_or_changed_number_is_caught():
    readme = (REPO / 'README.md').read_text()
    swapped = readme.replace('max 140.9 um, 16.85"', 'max 6.37 um, 16.85"', 1).replace(
        'max 6.37 um (1.80x', 'max 140.9 um (1.80x', 1)
    assert swapped != readme and problems(swapped)
    assert problems(readme.replace('| 3 runs with a finding', '| 1 runs with a finding', 1))
    assert problems(readme.replace('0.948 sigma', '0.948 sigma over 300 runs', 1))
