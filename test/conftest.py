"""Shared fixtures: a seeded random generator, the real photos in test/data/real
(BoofCV-Data, CC-BY-4.0; see its SOURCES.md) and the real measurements in
test/data/measured (each folder's SOURCES.md and licence)."""
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO / 'test' / 'data' / 'real'
MEASURED_DATA = REPO / 'test' / 'data' / 'measured'


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


@pytest.fixture
def real_data():
    return REAL_DATA


@pytest.fixture
def measured_data():
    return MEASURED_DATA


def pytest_collection_modifyitems(items):
    """The modules that start a node graph over DDS (they set their ``DOMAIN``) first: they
    are the longest and hold few tests, so scheduled last (pytest-xdist's default puts the
    modules with most tests first) they left one worker running them alone at the end.
    ``make test`` keeps this order (``--no-loadscope-reorder``)."""
    items.sort(key=lambda item: not hasattr(item.module, 'DOMAIN'))
