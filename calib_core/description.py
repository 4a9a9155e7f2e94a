"""What a user says about their own machine, once per machine (issue 50): its actuators'
units, the instrument that measures it and how well, its repeatability. Every machine
kind's description file has these sections beside its geometry; the gates size
themselves from them instead of from the simulated machines' constants.

```yaml
instrument:            # what measured the machine
  name: motion capture
  position_sigma_m: 0.4e-3      # 1 sigma per axis
  angle_sigma_rad: 2.0e-3       # 1 sigma per axis (pose sensors)
actuators:             # how the actuators are read
  unit: rev                     # m, mm, um, inch, rev (with m_per_unit), count (with m_per_unit)
  m_per_unit: 5.0e-3            # the nominal lead, m per revolution
  sigma_m: 5.0e-6               # positioning noise, 1 sigma
repeatability_m: 20.0e-6        # the machine's own, 1 sigma
```

Every number is SI; a missing section takes the defaults of the simulated machine the
suite ships (said in the report). Unknown keys, wrong types, NaN and negative noise are
refused with the key named.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import InvalidInputError
from calib_core.files import read_yaml

# The unit an actuator reading is in -> m per unit; rev and count need m_per_unit.
LENGTH_UNITS = {'m': 1.0, 'mm': 1e-3, 'um': 1e-6, 'inch': 0.0254}
# The unit a rotary axis's reading is in -> rad per unit (controllers read degrees).
ANGLE_UNITS = {'rad': 1.0, 'deg': float(np.pi / 180)}
SCALED_UNITS = ('rev', 'count')

RESIDUAL_GATE_FACTOR = 5.0
"""A fit's residual RMS may be this many times what the declared instrument, actuators and
repeatability give before the result is refused: a sound fit of a model that describes
the machine sits near 1 (effects the model lacks, such as a lead error, add a little); a
fit of data in another unit or of another machine sits far above."""


def described_number(section: dict, key: str, where: str, default=None,
                     positive: bool = False) -> float:
    """``section[key]`` as a finite number >= 0 (> 0 if ``positive``); ``default`` where
    the key is absent (None: it is required). Every error names ``where`` and the key."""
    if key not in section:
        if default is None:
            raise InvalidInputError(f'{where}: {key} is missing')
        return default
    value = section[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InvalidInputError(f'{where}: {key} must be a finite number, not {value!r}')
    if value < 0 or (positive and value == 0):
        raise InvalidInputError(f'{where}: {key} must be {"positive" if positive else ">= 0"}, '
                                f'not {value!r}')
    return float(value)


def check_keys(mapping, allowed: tuple, where: str) -> dict:
    """``mapping`` if it is a mapping of only ``allowed`` keys, else a clear error naming
    the unknown ones (a misspelt key would otherwise leave a figure at its default)."""
    if not isinstance(mapping, dict):
        raise InvalidInputError(f'{where} must be a mapping')
    unknown = sorted(map(str, set(mapping) - set(allowed)))
    if unknown:
        raise InvalidInputError(f'{where}: unknown key(s) {", ".join(unknown)} '
                                f'(known: {", ".join(allowed)})')
    return mapping


SECTIONS = ('kind', 'geometry', 'instrument', 'actuators', 'repeatability_m', 'workspace')


def read_description_file(path, kind: str) -> dict:
    """The mapping of a ``kind`` machine description YAML: only the known sections, the
    kind the one asked for and a geometry present (each error names the file and key)."""
    content = read_yaml(path, f'a {kind} description YAML')
    check_keys(content, SECTIONS, str(path))
    if content.get('kind') != kind:
        raise InvalidInputError(f'{path}: kind must be {kind}, not {content.get("kind")!r}')
    if 'geometry' not in content:
        raise InvalidInputError(f'{path}: geometry is missing')
    return content


def _section(content: dict, key: str, where: str, allowed: tuple) -> dict:
    return check_keys(content.get(key, {}), allowed, f'{where}: {key}')


@dataclass(frozen=True)
class Instrument:
    """What measured the machine: 1-sigma noise per axis (m, rad)."""

    name: str
    position_sigma_m: float
    angle_sigma_rad: float = 0.0


@dataclass(frozen=True)
class Actuators:
    """How the actuators are read: ``unit`` and ``m_per_unit`` (m per reading unit; for
    rev the nominal lead), and their positioning noise ``sigma_m`` (1 sigma)."""

    unit: str
    m_per_unit: float
    sigma_m: float

    def to_metres(self, readings: np.ndarray) -> np.ndarray:
        return np.asarray(readings, dtype=float) * self.m_per_unit


@dataclass(frozen=True)
class Measurement:
    """The instrument, actuators and repeatability of a description, and whether each
    was declared (else the shipped simulated machine's value stands, and the report says
    so)."""

    instrument: Instrument
    actuators: Actuators
    repeatability_m: float
    declared: tuple

    def sources(self) -> str:
        """Which figures came from the description, for the report."""
        left = [k for k in ('instrument', 'actuators', 'repeatability_m') if k not in self.declared]
        return ('declared in the description' if not left else
                f'{", ".join(left)}: the shipped simulated machine\'s (not declared)')


def read_measurement(content: dict, where: str, default_instrument: Instrument,
                     default_actuator_sigma_m: float) -> Measurement:
    """The instrument, actuators and repeatability sections of a description mapping."""
    instrument = _section(content, 'instrument', where,
                          ('name', 'position_sigma_m', 'angle_sigma_rad'))
    actuators = _section(content, 'actuators', where, ('unit', 'm_per_unit', 'sigma_m'))
    declared = tuple(k for k in ('instrument', 'actuators', 'repeatability_m') if k in content)
    name = instrument.get('name', default_instrument.name if not instrument else 'instrument')
    if not isinstance(name, str):
        raise InvalidInputError(f'{where}: instrument name must be text')
    measured_by = Instrument(
        name,
        described_number(instrument, 'position_sigma_m', f'{where}: instrument',
                default_instrument.position_sigma_m if not instrument else None, positive=True),
        described_number(instrument, 'angle_sigma_rad', f'{where}: instrument',
                default_instrument.angle_sigma_rad))
    unit = actuators.get('unit', 'm')
    if unit in LENGTH_UNITS:
        if 'm_per_unit' in actuators:
            raise InvalidInputError(f'{where}: actuators in {unit} take no m_per_unit')
        per_unit = LENGTH_UNITS[unit]
    elif unit in SCALED_UNITS:
        per_unit = described_number(actuators, 'm_per_unit', f'{where}: actuators in {unit}',
                           positive=True)
    else:
        raise InvalidInputError(f'{where}: actuator unit {unit!r} is not one of '
                                f'{", ".join(list(LENGTH_UNITS) + list(SCALED_UNITS))}')
    read_by = Actuators(unit, per_unit,
                        described_number(actuators, 'sigma_m', f'{where}: actuators',
                                         default_actuator_sigma_m))
    repeatability = described_number(content, 'repeatability_m', where, 0.0)
    return Measurement(measured_by, read_by, repeatability, declared)


def si_per_unit(unit, units: dict, where: str) -> float:
    """SI per ``unit`` from ``units`` (name -> SI per unit: LENGTH_UNITS, ANGLE_UNITS), or
    a clear error naming ``where`` the unit was given and listing the known ones."""
    if not isinstance(unit, str) or unit not in units:
        raise InvalidInputError(f'{where} {unit!r} is not one of {", ".join(units)}')
    return units[unit]


def unit_factor(section: dict, key: str, units: dict, where: str, default: str) -> tuple:
    """The unit ``section[key]`` names (``default`` if absent) and its factor to SI from
    ``units``, or a clear error listing the known ones."""
    unit = section.get(key, default)
    return unit, si_per_unit(unit, units, f'{where}: {key}')


def workspace_section(content: dict, where: str, keys: tuple) -> dict | None:
    """A description's ``workspace`` mapping with exactly ``keys``, or None without one."""
    section = content.get('workspace')
    if section is None:
        return None
    check_keys(section, keys, f'{where}: workspace')
    missing = [k for k in keys if k not in section]
    if missing:
        raise InvalidInputError(f'{where}: workspace lacks {", ".join(missing)}')
    return section


def workspace_numbers(value, count: int, name: str, where: str, positive: bool) -> tuple:
    """``count`` finite numbers (all > 0 if ``positive``) of workspace entry ``name``."""
    try:
        values = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InvalidInputError(f'{where}: workspace {name} must be {count} numbers') from None
    if values.shape != (count,) or not np.all(np.isfinite(values)) or (
            positive and not np.all(values > 0)):
        raise InvalidInputError(f'{where}: workspace {name} must be {count} finite '
                                f'{"positive " if positive else ""}number(s), not {value!r}')
    return tuple(float(v) for v in values)


UNIT_SLIP = 1e3
"""Actuators whose readings travel about this many times (or this share of) what the
measured motion needs are read in another unit: mm as m, or m as mm."""
MAX_TRAVEL_RATIO = 10.0
"""Readings that travel more than this many times (or less than this share of) what the
measured motion needs are not in the declared unit: no fit or analysis of them means
anything. Within it, a lead or scale declared wrong is something the loop can name."""


def unit_slip(travel_ratio: float, slip: float = UNIT_SLIP, within: float = 3.0) -> float | None:
    """Which of ``slip`` and its inverse ``travel_ratio`` (readings' travel over the measured
    motion's) is, to a factor ``within`` either way; None for neither. A machine whose
    measured motion is known well (a camera seeing a board move) takes a narrow
    ``within``; ``slip`` is 1000 for a length unit (mm read as m), 57.3 for degrees read as
    radians."""
    return next((factor for factor in (slip, 1 / slip)
                 if 1 / within < travel_ratio / factor < within), None)


def is_unit_slip(travel_ratio: float) -> bool:
    """Whether ``travel_ratio`` is about :data:`UNIT_SLIP` or its inverse (within 3x,
    :func:`unit_slip`)."""
    return unit_slip(travel_ratio) is not None


def refuse_unit_slip(travel_ratio: float, actuators: Actuators, moving: str,
                     where: str) -> None:
    """Refuse data whose ``moving`` actuators travel more than :data:`MAX_TRAVEL_RATIO`
    times (or less than its share of) what the measured motion needs, naming a unit slip
    where the ratio is about 1000x or 1/1000 (:func:`is_unit_slip`). ``where`` names the
    file and the description.

    Raises
    ------
    InvalidInputError"""
    if 1 / MAX_TRAVEL_RATIO <= travel_ratio <= MAX_TRAVEL_RATIO:
        return
    seen = (f'{where}: the {moving} travel {travel_ratio:.4g}x as far as the measured motion '
            'needs: ')
    if is_unit_slip(travel_ratio):
        raise InvalidInputError(
            seen + f'the readings are in a unit '
            f'{"1000x smaller" if travel_ratio > 1 else "1000x larger"} than the declared '
            f'{actuators.unit}')
    raise InvalidInputError(
        seen + f'the readings are not in the declared {actuators.unit}'
        + (f' of {actuators.m_per_unit:g} m' if actuators.unit in SCALED_UNITS else '')
        + ' (another unit, or another scale)')


def likely_causes(travel_ratio: float, actuators: Actuators, moving: str, model: str,
                  command: str) -> str:
    """The likely causes of a residual far above the declared noise, most likely first,
    from how far the actuators travelled against what the measured poses need
    (``travel_ratio``, median over the actuators): a unit slip where that is about 1000x
    or 1/1000 (:func:`is_unit_slip`, and only then), the declared lead off where it is more than 20 % from 1,
    then the instrument, the nominal geometry and effects ``model`` lacks (``command``
    names them). ``moving`` names the actuators (legs, feeds)."""
    causes = []
    if is_unit_slip(travel_ratio) and travel_ratio > 1:
        causes.append(f'the {moving} move 1000x as far as the measured poses need: the '
                      'readings are in a unit 1000x smaller than declared (mm read as m: '
                      'actuators: {unit: mm})')
    elif is_unit_slip(travel_ratio):
        causes.append(f'the {moving} move 1/1000 as far as the measured poses need: the '
                      'readings are in a unit 1000x larger than declared (m read as mm: '
                      'actuators: {unit: m})')
    elif abs(travel_ratio - 1) > 0.2:
        causes.append(f'the {moving} move {travel_ratio:.3g}x as far as the measured poses '
                      f"need: the actuators' m_per_unit ({actuators.m_per_unit:g} m per "
                      f'{actuators.unit}) is off')
    causes += ['the instrument is noisier than declared',
               "the nominal geometry is not this machine's",
               f'effects the {model} lacks ({command} names them)']
    return '; '.join(f'{k + 1}. {c}' for k, c in enumerate(causes))
