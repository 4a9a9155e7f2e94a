"""The gate every calibration passes before it is written or put in force: residuals
against the measurement noise the method expects, parameters inside physical bounds,
every standard deviation finite. A result that fails is refused with every reason, so a
wrong calibration (data in the wrong unit, a plan that determines nothing) never goes
into force looking like a result."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.errors import CalibrationError


@dataclass
class SanityGate:
    """Collects the failures of one result; :meth:`enforce` refuses it if there are any.

    Parameters
    ----------
    what : str
        The result, for the message ("platform identification").
    """

    what: str
    failures: list = field(default_factory=list)

    def residual(self, rms: float, limit: float, unit: str, expected: str,
                 causes: str = 'data in another unit, or the machine is not the one '
                               'described') -> None:
        """The fit's residual RMS must stay under ``limit`` (in ``unit``); ``expected``
        says what the method's noise gives, ``causes`` the likely causes, most likely
        first."""
        if not (np.isfinite(rms) and rms <= limit):
            self.failures.append(f'residual RMS {rms:.4g} {unit}, above the {limit:.4g} {unit} '
                                 f'a sound fit gives ({expected}): {causes}')

    def within(self, name: str, value: float, low: float, high: float, unit: str,
               why: str) -> None:
        """A parameter must lie in [low, high]."""
        if not (np.isfinite(value) and low <= value <= high):
            unit = f' {unit}' if unit else ''
            self.failures.append(f'{name} = {value:.6g}{unit}, outside {low:.6g}..{high:.6g}'
                                 f'{unit} ({why})')

    def finite_std_devs(self, std_devs: dict) -> None:
        """Every parameter must have a finite standard deviation (the data determine it
        with some redundancy)."""
        lacking = [n for n, s in std_devs.items() if not np.isfinite(s)]
        if lacking:
            self.failures.append(f'no finite standard deviation for {", ".join(lacking[:6])}'
                                 f'{" and more" if len(lacking) > 6 else ""}: the data '
                                 'determine them exactly or not at all (add measurements)')

    def enforce(self) -> None:
        """Raise if anything failed.

        Raises
        ------
        CalibrationError
            Naming every failure; nothing is to be written or put in force."""
        if self.failures:
            raise CalibrationError(f'{self.what} failed its sanity checks, nothing written or '
                                   'put in force: ' + '; '.join(self.failures))
