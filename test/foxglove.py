"""The suite's MCAP bags as the Foxglove app decodes them: tools/foxglove/decode.mjs runs
@mcap/core, @foxglove/rosmsg and @foxglove/rosmsg2-serialization (installed by ``make
setup`` with npm) under Node.js, and what it read is checked against this suite's reader."""
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from calib_core.bags import decode_bag

ROOT = Path(__file__).resolve().parents[1]
DECODER = ROOT / 'tools' / 'foxglove' / 'decode.mjs'
MODULES = ROOT / 'tools' / 'foxglove' / 'node_modules'


def foxglove_decode(files: list[Path]) -> list[dict]:
    """Foxglove's decoding of each MCAP file: per file its channels (schema, messages,
    decoded, the last message as JSON) and errors. Skips the test where Node.js or the npm
    packages are missing (``apt install nodejs npm``, then ``make setup``)."""
    node = shutil.which('node')
    if node is None or not MODULES.is_dir():
        pytest.skip('Node.js and the Foxglove npm packages are not installed (apt install '
                    'nodejs npm; make setup)')
    done = subprocess.run([node, str(DECODER), *map(str, files)], capture_output=True,
                          text=True, timeout=120)
    assert done.stdout, done.stderr
    return json.loads(done.stdout)


def assert_foxglove_reads(bags: list[Path]) -> dict:
    """Every channel's schema of every bag in ``bags`` (rosbag2 directories) parses and every
    message decodes with Foxglove's libraries, as many per topic as this suite's reader
    finds, and the last message of each topic the same as it decodes it (every number and
    string compared). Returns {bag name: {topic: count}}."""
    files = [next(bag.glob('*.mcap')) for bag in bags]
    assert files, 'no bag to decode'
    seen = {}
    for bag, result in zip(bags, foxglove_decode(files)):
        assert not result['errors'], (bag.name, result['errors'])
        ours = {}
        for topic, _, message in decode_bag(bag):
            ours.setdefault(topic, []).append(message)
        counts = {t: c['decoded'] for t, c in result['channels'].items() if c['decoded']}
        assert counts == {t: len(m) for t, m in ours.items()}, bag.name
        for topic, channel in result['channels'].items():
            if channel['decoded']:
                _same(channel['last'], ours[topic][-1], f'{bag.name} {topic}')
        seen[bag.name] = counts
    return seen


def assert_runs_decode(runs: Path, kinds: set) -> None:
    """Every complete bag in the folder ``runs`` decodes in Foxglove as in this suite
    (:func:`assert_foxglove_reads`), and among them a run of each of ``kinds`` (the bag
    names' prefixes: ``hexapod``, ``hexapod_analysis``, ...)."""
    bags = sorted(b for b in runs.iterdir() if (b / 'metadata.yaml').exists())
    seen = {name.rsplit('_', 1)[0] for name in assert_foxglove_reads(bags)}
    assert seen >= kinds, seen


def _same(theirs, ours, where: str) -> None:
    """Foxglove's JSON of a message against rosbags' object: every field equal (floats to
    the last bit, long arrays on the first 16 values Foxglove kept)."""
    if isinstance(theirs, dict) and set(theirs) == {'first', 'length'}:
        assert len(ours) == theirs['length'], where
        _same(theirs['first'], list(ours[:16]), where)
    elif isinstance(theirs, dict):
        for key, value in theirs.items():
            _same(value, getattr(ours, key), f'{where}.{key}')
    elif isinstance(theirs, list):
        ours = list(ours)
        assert len(theirs) == len(ours), where
        for k, (a, b) in enumerate(zip(theirs, ours)):
            _same(a, b, f'{where}[{k}]')
    elif isinstance(theirs, str) and isinstance(ours, (float, np.floating)):
        assert np.array_equal(float(theirs), ours, equal_nan=True), where   # NaN, Infinity
    elif isinstance(theirs, str) and not isinstance(ours, str):
        assert int(theirs) == int(ours), where          # 64-bit integers come as text
    elif isinstance(theirs, float) or isinstance(ours, (float, np.floating)):
        assert float(theirs) == float(ours), where
    else:
        assert theirs == ours, where
