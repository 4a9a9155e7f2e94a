"""Named parameter sets that map to and from an optimiser's flat vector."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.errors import InvalidInputError


@dataclass
class Parameter:
    """One model parameter: its value in SI units, its unit and whether it is estimated."""

    name: str
    value: float
    unit: str
    free: bool = True


@dataclass
class ParameterSet:
    """An ordered set of named parameters; only free ones enter the optimiser's vector."""

    parameters: list[Parameter] = field(default_factory=list)

    def __post_init__(self):
        names = [p.name for p in self.parameters]
        if len(set(names)) != len(names):
            raise InvalidInputError(f'duplicate parameter names in {names}')

    def __getitem__(self, name: str) -> float:
        return self._find(name).value

    def __contains__(self, name: str) -> bool:
        return any(p.name == name for p in self.parameters)

    def _find(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def free_names(self) -> list[str]:
        return [p.name for p in self.parameters if p.free]

    def set_free(self, name: str, free: bool) -> None:
        self._find(name).free = free

    def free_vector(self) -> np.ndarray:
        """Values of the free parameters, shape (n_free,)."""
        return np.array([p.value for p in self.parameters if p.free], dtype=float)

    def with_free_vector(self, vector: np.ndarray) -> 'ParameterSet':
        """A copy with the free parameters replaced by ``vector`` (shape (n_free,))."""
        vector = np.asarray(vector, dtype=float)
        free = [p for p in self.parameters if p.free]
        if vector.shape != (len(free),):
            raise InvalidInputError(f'expected {len(free)} values, got shape {vector.shape}')
        values = iter(vector.tolist())
        # Built without __post_init__: the names are this set's, already checked (a fit
        # makes thousands of these).
        copy = ParameterSet.__new__(ParameterSet)
        copy.parameters = [Parameter(p.name, next(values) if p.free else p.value, p.unit, p.free)
                           for p in self.parameters]
        return copy

    @classmethod
    def from_dict(cls, values: dict, units: dict) -> 'ParameterSet':
        """All free, in the order of ``values``; units from ``units`` (missing: '')."""
        return cls([Parameter(n, float(v), units.get(n, '')) for n, v in values.items()])

    def as_dict(self) -> dict[str, float]:
        return {p.name: p.value for p in self.parameters}

    def units(self) -> dict[str, str]:
        return {p.name: p.unit for p in self.parameters}
