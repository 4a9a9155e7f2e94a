"""Stage calibration data (the Marks measured at each input vector, CSV in and out),
the plan of inputs a run visits, and the rigid motions between Mark pairs."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.checks import MAX_POSITION_M, plan_rows, whole_number
from calib_core.datasets import directions_from_order, read_columns, write_columns
from calib_core.errors import InvalidInputError
from calib_core.schema import Column, Schema
from printer_alignment.core.alignment import rigid_fit
from printer_alignment.core.stage import STROKE, check_stroke


INPUT_COLUMNS = ('q1', 'q2', 'q3')      # the chains' inputs: the stage's actuators
STAGE_COLUMNS = INPUT_COLUMNS + ('mark1_x', 'mark1_y', 'mark2_x', 'mark2_y')


def stage_schema(stroke: float = STROKE) -> Schema:
    """The stage CSV, declared: chain inputs within 10x the ``stroke`` (m; a slip of a
    unit goes 1000x beyond it), Marks anywhere on a machine."""
    return Schema((
        *(Column(f'q{i}', 'm', -10 * stroke, 10 * stroke, f'chain {i} input')
          for i in (1, 2, 3)),
        *(Column(n, 'm', -MAX_POSITION_M, MAX_POSITION_M, f'Mark {n[4]} {n[-1]}')
          for n in STAGE_COLUMNS[3:])))
STAGE_DIRECTIONS = ('direction1', 'direction2', 'direction3')


@dataclass(frozen=True)
class StageData:
    """Calibration Marks measured at commanded stage inputs.

    Attributes
    ----------
    q : ndarray (n, 3)
        Commanded chain inputs, m.
    directions : ndarray (n, 3)
        Direction of each chain's last motion (+1 / -1).
    marks : ndarray (n, 2, 2)
        The two calibration Marks measured in the plate frame, m.
    covariates : dict of str to ndarray (n,)
    """

    q: np.ndarray
    directions: np.ndarray
    marks: np.ndarray
    covariates: dict = field(default_factory=dict)

    def __post_init__(self):
        q = np.atleast_2d(np.asarray(self.q, dtype=float))
        directions = np.atleast_2d(np.asarray(self.directions, dtype=float))
        marks = np.asarray(self.marks, dtype=float).reshape(-1, 2, 2)
        if q.shape[1:] != (3,) or directions.shape != q.shape or len(marks) != len(q):
            raise InvalidInputError(f'q {q.shape}, directions {directions.shape} and marks '
                                    f'{marks.shape} must be (n, 3), (n, 3), (n, 2, 2)')
        for name, value in (('q', q), ('marks', marks)):
            if not np.all(np.isfinite(value)):
                raise InvalidInputError(f'{name} contains NaN or infinite values')
        if not np.all(np.isin(directions, (-1.0, 1.0))):
            raise InvalidInputError('directions must be +1 or -1')
        object.__setattr__(self, 'q', q)
        object.__setattr__(self, 'directions', directions)
        object.__setattr__(self, 'marks', marks)

    def __len__(self) -> int:
        return len(self.q)

    def select(self, rows) -> 'StageData':
        return StageData(self.q[rows], self.directions[rows], self.marks[rows],
                         {k: v[rows] for k, v in self.covariates.items()})

    @classmethod
    def from_csv(cls, path, dropped: dict | None = None, m_per_unit: float = 1.0,
                 stroke: float = STROKE) -> 'StageData':
        """Columns q1..q3 (m; with ``m_per_unit``, a machine description's, in its
        actuators' unit), mark1_x, mark1_y, mark2_x, mark2_y (m, plate frame); optional
        direction1..3 (+1 / -1; without them, from the order of the rows) and covariates
        such as time (s) or temperature (K). Inputs beyond 10x the ``stroke`` (m) are
        refused."""
        columns = read_columns(path, list(STAGE_COLUMNS), dropped)
        for c in INPUT_COLUMNS:
            columns[c] = columns[c] * m_per_unit
        q = np.column_stack([columns[c] for c in INPUT_COLUMNS])
        present = [c for c in STAGE_DIRECTIONS if c in columns]
        if present and len(present) != 3:
            raise InvalidInputError(f'{path} has {", ".join(present)} but not all three '
                                    'direction columns')
        directions = (np.column_stack([columns[c] for c in STAGE_DIRECTIONS]) if present
                      else directions_from_order(np.vstack([np.zeros(3), q]))[1:])
        marks = np.column_stack([columns[c] for c in STAGE_COLUMNS[3:]]).reshape(-1, 2, 2)
        stage_schema(stroke).check(columns, path)
        used = set(STAGE_COLUMNS) | set(STAGE_DIRECTIONS)
        return cls(q, directions, marks, {k: v for k, v in columns.items() if k not in used})

    def to_csv(self, path, m_per_unit: float = 1.0) -> None:
        """The CSV :meth:`from_csv` reads, q1..q3 divided by ``m_per_unit`` (the actuators'
        unit of a machine description; default m)."""
        names = list(STAGE_COLUMNS[:3]) + list(STAGE_DIRECTIONS) + list(STAGE_COLUMNS[3:]) \
            + list(self.covariates)
        write_columns(path, names, [self.q / m_per_unit, self.directions,
                                    self.marks.reshape(-1, 4)]
                      + [self.covariates[k] for k in self.covariates])


@dataclass(frozen=True)
class StagePlan:
    """Which inputs the calibration visits (m). ``span`` is the fraction of the stroke
    used; sweeps have ``sweep_points`` each way, the workspace grid ``grid`` points per
    input (q1, (q2 + q3) / 2, q3 - q2). ``stops`` (n, 3) m, when given, are the whole run
    in visiting order instead (a planned one, :mod:`printer_alignment.core.stage_planning`):
    it starts at home, and the stepwise start needs its sweeps among them. ``stroke`` (m)
    is each input's limit either way (a machine description's)."""

    sweep_points: int = 9
    grid: tuple = (5, 5, 3)
    span: float = 0.95
    stops: np.ndarray | None = None
    stroke: float = STROKE

    def __post_init__(self):
        if self.stops is not None:
            stops = plan_rows(self.stops, 'q1, q2, q3 (m)', 'stops')
            if np.any(stops[0] != 0):
                raise InvalidInputError('a planned run starts at home (0, 0, 0): the Marks '
                                        'measured there are the reference of every other stop')
            object.__setattr__(self, 'stops', check_stroke(stops, self.stroke))
        object.__setattr__(self, 'sweep_points', whole_number(self.sweep_points, 'sweep_points', 3))
        if len(self.grid) != 3:
            raise InvalidInputError(f'grid must be three counts, not {self.grid!r}')
        object.__setattr__(self, 'grid', tuple(whole_number(n, 'grid', 2) for n in self.grid))
        if not isinstance(self.span, (int, float)) or isinstance(self.span, bool):
            raise InvalidInputError(f'span must be a number in (0, 1], not {self.span!r}')
        if not 0 < self.span <= 1:
            raise InvalidInputError('span must be in (0, 1]')

    def sweeps(self) -> np.ndarray:
        """Home, then each sweep up and back (the stepwise start's stops), m, (n, 3)."""
        reach = self.span * self.stroke
        ramp = np.linspace(-reach, reach, self.sweep_points)
        both_ways = np.concatenate([ramp, ramp[::-1]])
        zero = np.zeros_like(both_ways)
        x_sweep = np.column_stack([both_ways, zero, zero])
        y_sweep = np.column_stack([zero, both_ways, both_ways])
        attitude = np.column_stack([zero, -both_ways, both_ways])
        return check_stroke(np.vstack([np.zeros((1, 3)), x_sweep, y_sweep, attitude]),
                            self.stroke)

    def targets(self) -> np.ndarray:
        """Inputs in visiting order, m, (n, 3). Starts at home; sweeps go up and back;
        then the planned stops or the workspace grid."""
        if self.stops is not None:
            return self.stops.copy()
        reach = self.span * self.stroke
        n1, nm, nw = self.grid
        rows = []
        # Mean of q2, q3 and their difference share the stroke: |qm| + |w| / 2 <= reach.
        for k, w in enumerate(np.linspace(-reach, reach, nw)):
            qm_reach = reach - abs(w) / 2
            for j, qm in enumerate(np.linspace(-qm_reach, qm_reach, nm)):
                q1s = np.linspace(-reach, reach, n1)
                for q1 in (q1s if (j + k) % 2 == 0 else q1s[::-1]):
                    rows.append([q1, qm - w / 2, qm + w / 2])
        return np.vstack([self.sweeps(), check_stroke(np.array(rows), self.stroke)])


PLAN_COLUMNS = ('q1', 'q2', 'q3')


def plan_schema(stroke: float = STROKE) -> Schema:
    """A plan's inputs: each within ``stroke`` (m) either way."""
    return Schema(tuple(Column(n, 'm', -stroke, stroke, f'chain {n[1]} input')
                        for n in PLAN_COLUMNS))


def write_stage_plan(path, targets: np.ndarray) -> None:
    """A planned run as CSV: q1, q2, q3 (m), one stop per row in visiting order."""
    write_columns(path, list(PLAN_COLUMNS), [np.asarray(targets, dtype=float)])


def read_stage_plan(path, stroke: float = STROKE) -> StagePlan:
    """The run of a plan CSV (:func:`write_stage_plan`), checked as a plan of a stage whose
    inputs reach ``stroke`` (m) either way.

    Raises
    ------
    InvalidInputError
        Missing columns, values outside the stroke (mm given for m?), not home first."""
    columns = read_columns(path, list(PLAN_COLUMNS))
    plan_schema(stroke).check(columns, path)
    return StagePlan(stops=np.column_stack([columns[n] for n in PLAN_COLUMNS]), stroke=stroke)


def relative_motions(marks: np.ndarray, home: np.ndarray):
    """Rigid plate-frame motions (angle rad (n,), translation m (n, 2)) that carry the two
    ``home`` Marks ((2, 2)) to each measured pair ((n, 2, 2)): ``M = R(angle) M0 + C``."""
    out = [rigid_fit(home, pair) for pair in marks]
    return np.array([a for a, _ in out]), np.array([c for _, c in out])
