"""Shared fixtures: a seeded random generator and the real photos in ../shared."""
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO.parent / 'shared' / 'data' / 'real'


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


@pytest.fixture
def real_data():
    if not REAL_DATA.exists():
        pytest.skip(f'real photos not found at {REAL_DATA}')
    return REAL_DATA
