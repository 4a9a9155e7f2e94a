"""The files of a workpiece's localisation, offline (``machine-align locate``) as on the
live graph (``five_axis_calibrator/locate``).

- Views CSV (read by ``locate --data``): ``feature, x, y, z, a, c, u, v``: a feature's name,
  the commanded pose it was imaged at (m, rad) and its centre in that image (px).
- Points CSV (a part's CAD features, ``--cad``, or its dispensing path, ``--path``):
  ``name, x_m, y_m, z_m`` in the part's frame; a CAD feature's name is the one the views
  give it.
- Path poses CSV (what ``locate --csv`` and ``call five_axis_calibrator/locate --csv``
  write, for a controller or CAM): ``point, x_m, y_m, z_m, a_rad, c_rad``, the commanded
  axes that put the needle tip on each path point, in the path's order. The same columns
  give the poses the needle's test dots were dispensed at (``needle --dispensed``).
- Plan CSV (what ``machine-align plan five-axis`` writes, read by ``simulate five-axis
  --plan``): ``stop, x_m, y_m, z_m, a_rad, c_rad``, the stops of a calibration in the
  order to measure them, each named by its kind (``linear``, ``a`` or ``c`` alone,
  ``both``) and number.
"""
from __future__ import annotations

import numpy as np

from calib_core.datasets import read_columns
from calib_core.errors import InvalidInputError
from calib_core.files import read_csv_rows
from calib_core.storage import write_atomic
from dispenser_calib.core.data import check_poses

VIEW_COLUMNS = ('feature', 'x', 'y', 'z', 'a', 'c', 'u', 'v')
POINT_COLUMNS = ('name', 'x_m', 'y_m', 'z_m')
PATH_POSE_COLUMNS = ('point', 'x_m', 'y_m', 'z_m', 'a_rad', 'c_rad')
PLAN_COLUMNS = ('stop', 'x_m', 'y_m', 'z_m', 'a_rad', 'c_rad')


def read_views(path) -> dict[str, np.ndarray]:
    """Per feature name, its views (n, 7): pose x, y, z (m), a, c (rad), pixel u, v (px).

    Raises
    ------
    InvalidInputError
        Missing columns, values that are not finite numbers, poses no dispenser commands
        (mm written as m, degrees as rad)."""
    views = {}
    for line, row in enumerate(read_csv_rows(path, 'a features CSV', VIEW_COLUMNS), start=2):
        try:
            values = [float(row[k]) for k in VIEW_COLUMNS[1:]]
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f'{path} line {line}: {exc}') from None
        if not np.all(np.isfinite(values)):
            raise InvalidInputError(f'{path} line {line}: NaN or infinite value')
        views.setdefault(row['feature'], []).append(values)
    views = {name: np.array(table) for name, table in views.items()}
    check_poses(np.vstack([table[:, :5] for table in views.values()]), str(path))
    return views


def write_views(path, names, poses: np.ndarray, pixels: np.ndarray) -> None:
    """One row per view: ``names`` (n,), ``poses`` (n, 5) m and rad, ``pixels`` (n, 2) px."""
    lines = [','.join(VIEW_COLUMNS)]
    lines += [f'{name},' + ','.join(f'{v:.12g}' for v in pose) + f',{u:.6f},{v:.6f}'
              for name, pose, (u, v) in zip(names, poses, pixels)]
    write_atomic(path, '\n'.join(lines) + '\n')


def read_points(path, what: str) -> tuple[list[str], np.ndarray]:
    """Names and points (k, 3) m of a points CSV (``name, x_m, y_m, z_m``).

    Raises
    ------
    InvalidInputError
        Missing columns, a name twice, values that are not finite numbers or beyond 2 m
        (mm written as m)."""
    names, points = _read_named(path, what, POINT_COLUMNS)
    if np.max(np.abs(points)) > 2.0:
        raise InvalidInputError(f'{path}: {what} reaches {np.max(np.abs(points)):.4g}: '
                                'points are in m (was it written in mm?)')
    return names, points


def write_points(path, names, points: np.ndarray) -> None:
    _write_named(path, POINT_COLUMNS, names, points)


def write_path_poses(path, names, poses: np.ndarray) -> None:
    """The path poses (k, 5) (x, y, z m, a, c rad) as a labelled CSV, one row per point."""
    _write_named(path, PATH_POSE_COLUMNS, names, poses)


def read_path_poses(path, what: str) -> tuple[list[str], np.ndarray]:
    """Names and poses (k, 5) (x, y, z m, a, c rad) of a path poses CSV.

    Raises
    ------
    InvalidInputError
        Missing columns, a name twice, values that are not finite numbers or beyond what
        a dispenser's axes read (mm written as m)."""
    names, poses = _read_named(path, what, PATH_POSE_COLUMNS)
    check_poses(poses, str(path))
    return names, poses


def write_plan(path, names, stops: np.ndarray) -> None:
    """A calibration's stops (n, 5) (x, y, z m, a, c rad), one row each."""
    _write_named(path, PLAN_COLUMNS, names, stops)


def read_plan(path) -> tuple[list[str], np.ndarray]:
    """Names and stops (n, 5) of a plan CSV, refused as :func:`read_path_poses` refuses."""
    names, stops = _read_named(path, 'a five-axis plan', PLAN_COLUMNS)
    check_poses(stops, str(path))
    return names, stops


def _read_named(path, what: str, columns: tuple) -> tuple[list[str], np.ndarray]:
    """A CSV of a name column then numbers: the names and the rows (k, len(columns) - 1),
    a name given twice refused."""
    names = [row[columns[0]] for row in read_csv_rows(path, what, columns)]
    if len(set(names)) != len(names):
        raise InvalidInputError(f'{path}: a {columns[0]} appears twice in {what}')
    table = read_columns(path, list(columns[1:]))
    return names, np.column_stack([table[k] for k in columns[1:]])


def _write_named(path, columns: tuple, names, rows: np.ndarray) -> None:
    lines = [','.join(columns)]
    lines += [f'{name},' + ','.join(f'{v:.12g}' for v in row)
              for name, row in zip(names, np.atleast_2d(rows))]
    write_atomic(path, '\n'.join(lines) + '\n')
