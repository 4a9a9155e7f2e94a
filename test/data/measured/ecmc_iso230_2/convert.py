"""Convert ecmc's ISO 230-2 input files (``*.dat``) to this suite's axis CSV.

Each ``.dat`` lists the target positions TGT_DATA[i] and the reference system's reading
REF_DATA_FWD[i, j] / REF_DATA_BWD[i, j] at target i in cycle j, in mm. The CSV has
command and measured in m, direction (+1 forward, -1 backward), cycle (1..5) and sequence:
the approach's number in an ISO 230-2 standard test (each cycle runs forward through the
targets, then backward; 0 is the first approach). The files do not record the order of
approach, so sequence assumes that standard cycle.

Run: python convert.py  (writes one CSV beside each .dat)
"""
import csv
import re
from pathlib import Path

ENTRY = re.compile(r'^(TGT_DATA|REF_DATA_FWD|REF_DATA_BWD)\[(\d+)(?:,(\d+))?\]=(\S+)$')


def convert(path: Path) -> Path:
    targets, readings = {}, {}
    for line in path.read_text().splitlines():
        match = ENTRY.match(line.strip())
        if not match:
            continue
        kind, i, j, value = match.groups()
        if kind == 'TGT_DATA':
            targets[int(i)] = float(value)
        else:
            readings[(kind, int(i), int(j))] = float(value)
    positions = sorted(targets)
    cycles = sorted({j for _, _, j in readings})
    rows, sequence = [], 0
    for j in cycles:
        for kind, order, sign in (('REF_DATA_FWD', positions, 1), ('REF_DATA_BWD', positions[::-1], -1)):
            for i in order:
                rows.append((targets[i] * 1e-3, readings[(kind, i, j)] * 1e-3, sign, j, sequence))
                sequence += 1
    out = path.with_suffix('.csv')
    with open(out, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(['command', 'measured', 'direction', 'cycle', 'sequence'])
        for command, measured, sign, cycle, number in rows:
            writer.writerow([f'{command:.9g}', f'{measured:.12g}', sign, cycle, number])
    return out


if __name__ == '__main__':
    for dat in sorted(Path(__file__).parent.glob('*.dat')):
        print('wrote', convert(dat))
