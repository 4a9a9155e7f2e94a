"""Shared fixtures: a seeded random generator and the real photos in test/data/real
(BoofCV-Data, CC-BY-4.0; see its SOURCES.md)."""
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO / 'test' / 'data' / 'real'


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


@pytest.fixture
def real_data():
    return REAL_DATA
