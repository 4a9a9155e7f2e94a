"""Simulated XY camera gantry (servo motors and ball screws) with its true errors.

True camera position (plate frame, m)::

    M(a, t) [Rx theta_x + e_x(theta_x) - b_x / 2 * dir_x, Ry theta_y + ...] + [x0, y0]

with the paper's model (leads Rx, Ry, axis angle a, non-orthogonality t) plus two effects
the paper's model lacks: backlash b (lost motion: the carriage lags the motor by b/2 in the
direction of the last move) and lead-screw periodic error e(theta) = A sin(2 pi theta + phase)
(once per screw revolution). The encoders read the motor angle theta exactly; commands are
axis positions in m converted with the nominal leads, as a real drive does. Optionally the
screws expand as the machine warms, their leads R (1 + k dT), which the rotary encoders do
not see: the carriage runs ahead of the reading by k dT times its distance from the
screws' zero. A move lands within ``landing_sigma`` (m, 1 sigma per axis) of where the
model puts it: the machine's repeatability, which no calibration removes.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.errors import InvalidInputError, OutOfTravelError
from printer_alignment.core.geometry import NOMINAL_LEADS, GantryModel


@dataclass(frozen=True)
class GantryErrors:
    """The simulation's truth. Angles in rad, lengths in m, leads in m/rev."""

    model: GantryModel = field(default_factory=lambda: GantryModel(
        lead_x=0.0159972, lead_y=0.0399984, axis_angle=np.deg2rad(0.0325),
        non_orthogonality=np.deg2rad(-0.0060), offset_x=0.0012, offset_y=-0.0008))
    backlash_x: float = 4e-6
    backlash_y: float = 6e-6
    periodic_amplitude_x: float = 1.5e-6
    periodic_amplitude_y: float = 2.0e-6
    periodic_phase_x: float = 0.4
    periodic_phase_y: float = 2.1
    screw_expansion: float = 0.0        # 1/K, of both screws' leads (steel: about 11.5e-6)

    @classmethod
    def ideal(cls) -> 'GantryErrors':
        """A gantry exactly at its nominal geometry (for tests of clean data)."""
        return cls(model=GantryModel(), backlash_x=0.0, backlash_y=0.0,
                   periodic_amplitude_x=0.0, periodic_amplitude_y=0.0)


@dataclass(frozen=True)
class MachineTemperature:
    """The machine's temperature (K) ``seconds`` after start-up: a warm-up towards its
    running equilibrium, ``warm_up`` K above ``start`` with the time constant
    ``warm_up_time`` (s), and the shop's cycle (its air conditioning), ``cycle_amplitude``
    K over ``cycle_period`` s."""

    start: float = 293.15
    warm_up: float = 0.0
    warm_up_time: float = 3600.0
    cycle_amplitude: float = 0.0
    cycle_period: float = 1800.0

    def __post_init__(self):
        if not (200.0 <= self.start <= 400.0 and abs(self.warm_up) <= 50.0
                and 0 <= self.cycle_amplitude <= 20.0 and self.warm_up_time > 0
                and self.cycle_period > 0):
            raise InvalidInputError(
                f'need a start in 200..400 K, |warm_up| <= 50 K, a cycle_amplitude in 0..20 K '
                f'and positive times (s), not {self}')

    def at(self, seconds: float) -> float:
        return (self.start + self.warm_up * (1.0 - np.exp(-seconds / self.warm_up_time))
                + self.cycle_amplitude * np.sin(2 * np.pi * seconds / self.cycle_period))


@dataclass(frozen=True)
class Travel:
    """Axis travel limits, m (commanded axis positions)."""

    x_min: float = 0.0
    x_max: float = 0.200
    y_min: float = 0.0
    y_max: float = 0.150

    def contains(self, x: float, y: float) -> bool:
        return self.x_min <= x <= self.x_max and self.y_min <= y <= self.y_max


class GantrySim:
    """State of the simulated gantry. Moves are instantaneous; use :meth:`move`."""

    def __init__(self, errors: GantryErrors = GantryErrors(), travel: Travel = Travel(),
                 landing_sigma: float = 0.0, seed: int | None = None):
        if not (np.isfinite(landing_sigma) and 0.0 <= landing_sigma < 1e-3):
            raise InvalidInputError(
                f'landing_sigma must be a length in m in [0, 1e-3), not {landing_sigma}')
        self.errors = errors
        self.travel = travel
        self.landing_sigma = float(landing_sigma)
        self._rng = np.random.default_rng(seed)
        self._landing = np.zeros(2)   # m: where this move's carriage came to rest, off the model
        self.revs = np.zeros(2)
        self._direction = np.ones(2)  # +1: last moved towards +, -1: towards -
        self.warming = 0.0            # K above the temperature of the leads in the model

    @property
    def axis_position(self) -> np.ndarray:
        """Encoder reading as axis position (m), shape (2,)."""
        return self.revs * NOMINAL_LEADS

    def move(self, x: float, y: float) -> np.ndarray:
        """Move to axis position (x, y) in m; returns the encoder position reached (m).

        Raises
        ------
        OutOfTravelError
            The target is outside the travel; the gantry does not move.
        """
        if not (np.isfinite(x) and np.isfinite(y)):
            raise InvalidInputError(f'gantry target ({x}, {y}) is not finite')
        if not self.travel.contains(x, y):
            t = self.travel
            raise OutOfTravelError(
                f'gantry target ({x * 1e3:.3f}, {y * 1e3:.3f}) mm is outside the travel '
                f'x [{t.x_min * 1e3:.1f}, {t.x_max * 1e3:.1f}] mm, '
                f'y [{t.y_min * 1e3:.1f}, {t.y_max * 1e3:.1f}] mm; not moved')
        target = np.array([x, y]) / NOMINAL_LEADS
        step = target - self.revs
        moved = step != 0
        self._direction[moved] = np.sign(step[moved])
        self.revs = target
        if moved.any() and self.landing_sigma > 0:
            self._landing = self._rng.normal(0.0, self.landing_sigma, 2)
        return self.axis_position

    def true_camera_position(self) -> np.ndarray:
        """Where the camera really is in the plate frame (m), shape (2,). Truth: sim only."""
        e = self.errors
        theta = self.revs
        grown = 1.0 + e.screw_expansion * self.warming
        screw = np.array([
            e.model.lead_x * grown * theta[0]
            + e.periodic_amplitude_x * np.sin(2 * np.pi * theta[0] + e.periodic_phase_x)
            - 0.5 * e.backlash_x * self._direction[0],
            e.model.lead_y * grown * theta[1]
            + e.periodic_amplitude_y * np.sin(2 * np.pi * theta[1] + e.periodic_phase_y)
            - 0.5 * e.backlash_y * self._direction[1]])
        return (e.model.matrix() @ screw + np.array([e.model.offset_x, e.model.offset_y])
                + self._landing)


def measure_positions(gantry: GantrySim, targets: np.ndarray, noise: float = 0.3e-6,
                      seed: int = 0, temperature: MachineTemperature | None = None,
                      seconds_each: float = 10.0):
    """Visit ``targets`` (commanded axis positions, m, (n, 2)) in order and measure the
    camera position through the camera and a dot plate, with ``noise`` m (1 sigma) per
    coordinate; the data for the closed loop (directions from the moves). With a
    ``temperature``, a position is measured every ``seconds_each`` s as the machine's
    temperature changes, each with its ``time`` (s) and ``temperature`` (K) logged."""
    from calib_core.datasets import directions_from_order
    from printer_alignment.core.loop_models import GantryData
    rng = np.random.default_rng(seed)
    targets = np.atleast_2d(np.asarray(targets, dtype=float))
    times = seconds_each * np.arange(len(targets))
    kelvin = np.array([temperature.at(t) for t in times]) if temperature else None
    measured = []
    for k, (x, y) in enumerate(targets):
        gantry.move(x, y)
        if temperature:
            gantry.warming = kelvin[k] - temperature.start
        measured.append(gantry.true_camera_position() + rng.normal(0, noise, 2))
    start = np.array([gantry.travel.x_min, gantry.travel.y_min])
    # The gantry's own state fixes the direction of the first target.
    with_start = np.vstack([start, targets])
    covariates = {'time': times, 'temperature': kelvin} if temperature else {}
    return GantryData(targets, np.array(measured), directions_from_order(with_start)[1:],
                      covariates)


def measure_random_positions(errors: GantryErrors, count: int = 200, noise: float = 0.3e-6,
                             seed: int = 0, temperature: MachineTemperature | None = None):
    """:func:`measure_positions` at ``count`` random targets over the whole travel, visited
    in random order, so both directions of approach occur on each axis."""
    travel = Travel()
    targets = np.random.default_rng(seed).uniform(
        [travel.x_min, travel.y_min], [travel.x_max, travel.y_max], (count, 2))
    return measure_positions(GantrySim(errors, travel), targets, noise, seed=seed + 1,
                             temperature=temperature)
