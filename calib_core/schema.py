"""Declared columns of the suite's data files: each column's unit and the range a real
machine can produce, so every reader (and every node's plan check) refuses the same value
with the same words, naming the column, the value, the unit expected and the likely
mistake (mm for m, degrees for rad)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import InvalidInputError, UnitMistake

DEGREES_PER_RAD = 180 / np.pi
MM_PER_M = 1000.0
CELSIUS_ZERO_K = 273.15


@dataclass(frozen=True)
class Column:
    """One numeric column.

    Attributes
    ----------
    name : str
    unit : str
        'm', 'rad', 'px', 's', 'K' or '1'.
    low, high : float
        The range a real machine produces, in ``unit`` (a stroke, a turn).
    meaning : str
        What the column is, for the message ("commanded X axis").
    """

    name: str
    unit: str
    low: float
    high: float
    meaning: str

    def mistaken_unit(self, value: float) -> tuple[str, str, str] | None:
        """The unit the column's largest value outside the range was most likely written
        in, as (quantity, unit, what to say): mm for m when it is many times the range or a
        metre and more, and would fit it in mm; degrees for rad when over twice the range
        and fitting it in degrees; degrees Celsius for kelvin (and the other way round)
        when the value so read fits; else None."""
        ratio = abs(value) / max(abs(self.low), abs(self.high))
        # A metre or more outside a machine's range, or many times the range: mm, when the
        # value read in mm fits.
        if self.unit == 'm' and (ratio >= 20 or abs(value) >= 1.0) \
                and self.low <= value / MM_PER_M <= self.high:
            return 'length', 'mm', 'the values look like mm; the format is SI metres'
        if self.unit == 'rad' and ratio >= 2 and \
                self.low <= value / DEGREES_PER_RAD <= self.high:
            return 'angle', 'deg', 'the values look like degrees; the format is radians'
        if self.unit == 'K' and self.low <= value + CELSIUS_ZERO_K <= self.high:
            return ('temperature', 'degC',
                    'the values look like degrees Celsius; the format is kelvin')
        if self.unit == 'K' and self.low <= value - CELSIUS_ZERO_K <= self.high:
            return ('temperature', 'K', 'the values look like kelvin where degrees Celsius '
                    'were due (as sensor_msgs/Temperature carries them)')
        return None

    def check(self, values, source: str) -> None:
        """Refuse the column if any value is NaN or outside [low, high], naming the one
        furthest out.

        Raises
        ------
        InvalidInputError
            A :class:`~calib_core.errors.UnitMistake` where the value fits the range in
            another unit."""
        values = np.asarray(values, dtype=float).ravel()
        if not np.all(np.isfinite(values)):
            raise InvalidInputError(f'{source}: column {self.name} ({self.meaning}) holds NaN '
                                    'or infinite values')
        outside = np.flatnonzero((values < self.low) | (values > self.high))
        if outside.size:
            worst = outside[np.argmax(np.abs(values[outside]))]
            value = float(values[worst])
            mistaken = self.mistaken_unit(value)
            message = (f'{source}: column {self.name} ({self.meaning}) is {value:.6g} '
                       f'{self.unit} in row {worst + 1}, outside {self.low:.6g}..'
                       f'{self.high:.6g} {self.unit}: ' + (
                           mistaken[2] if mistaken
                           else 'no such machine reads this (another zero, unit or column?)'))
            if mistaken:
                raise UnitMistake(message, *mistaken[:2], self.name)
            raise InvalidInputError(message)


@dataclass(frozen=True)
class Schema:
    """The numeric columns of one file kind."""

    columns: tuple

    def check(self, values: dict, source: str) -> None:
        """Check every declared column present in ``values`` (name -> array).

        Raises
        ------
        InvalidInputError"""
        for column in self.columns:
            if column.name in values:
                column.check(values[column.name], source)
