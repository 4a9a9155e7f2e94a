"""Checks shared by every machine: lengths that only a file in mm would have, and the
counts, sizes and rows of a plan, refused with the reason before anything moves."""
from __future__ import annotations

import numpy as np

from calib_core.errors import InvalidInputError, UnitMistake

# Plausible magnitudes of the lengths in a dataset (m). Beyond them the file is most likely
# in mm: a 200 mm travel written in mm reads as 200 m, a 30 um error as 30 mm.
MAX_POSITION_M = 10.0    # machine positions, joint coordinates, target points
MAX_ERROR_M = 0.01       # measured minus commanded position of a calibrated machine


def check_metres(values, what: str, source, limit_m: float) -> None:
    """Refuse lengths (m) beyond ``limit_m``: no machine this suite calibrates has them,
    and the likely cause is a file written in mm.

    Raises
    ------
    UnitMistake
        The largest magnitude in ``values`` exceeds ``limit_m``; the message names
        ``what`` in ``source`` and the likely cause (mm)."""
    values = np.asarray(values, dtype=float)
    largest = float(np.max(np.abs(values))) if values.size else 0.0
    if largest > limit_m:
        raise UnitMistake(f'{source}: {what} reaches {largest:.4g} m, beyond the '
                          f'{limit_m:g} m plausible here: the values look like mm; the format '
                          'is SI metres', 'length', 'mm')


MAX_COUNT = 10_000
"""The most measurements, poses, stops or sites any plan count may ask for: at a few
seconds a measurement that is hours of a machine's time, and every plan here needs tens to
hundreds. A plan may set a lower bound of its own."""

MAX_SEED = 2 ** 32 - 1
"""The largest random seed a plan takes (numpy's legacy seeds, and plenty)."""

BRIEF = 60
"""Characters of a refused value quoted in a message: a 10^7-element list or an expanded
YAML alias must not come back as a reply of megabytes."""


def brief(value) -> str:
    """``repr(value)`` cut to :data:`BRIEF` characters, for error messages."""
    text = repr(value)
    return text if len(text) <= BRIEF else f'{text[:BRIEF]}... ({len(text)} characters)'


def whole_number(value, name: str, minimum: int = 0, maximum: int = MAX_COUNT) -> int:
    """``value`` as an int, refused unless it is an integer in [``minimum``, ``maximum``]
    (``2.7`` and ``True`` are refused; ``3.0`` is 3).

    Raises
    ------
    InvalidInputError"""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value) or int(value) != value or not minimum <= value <= maximum:
        raise InvalidInputError(f'{name} must be an integer from {minimum} to {maximum}, not '
                                f'{brief(value)}')
    return int(value)


def positive_length(value, name: str, limit_m: float = MAX_POSITION_M) -> float:
    """``value`` (m) as a float, refused unless finite, positive and at most ``limit_m``
    (beyond it, likely mm).

    Raises
    ------
    InvalidInputError"""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f'{name} must be a length in m, not {brief(value)}') from None
    if not (np.isfinite(value) and value > 0):
        raise InvalidInputError(f'{name} must be a positive length (m), not {brief(value)}')
    check_metres(value, name, 'the plan', limit_m)
    return value


def plan_rows(values, columns: str, name: str) -> np.ndarray:
    """``values`` as a float array (n, k) of at least one row of the k ``columns`` (a
    sentence naming them with their units, e.g. ``'q1, q2, q3 (m)'``).

    Raises
    ------
    InvalidInputError
        Not a list of rows of k numbers, or none."""
    width = len(columns.split('(')[0].split(','))
    try:
        rows = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInputError(f'{name} must be a list of [{columns}] rows') from None
    if rows.ndim != 2 or rows.shape[1] != width or not len(rows):
        raise InvalidInputError(f'{name} must be a list of [{columns}] rows, got shape '
                                f'{rows.shape}')
    return rows
