"""Compensation in the formats controllers read.

LinuxCNC's axis compensation file (``[JOINT_n] COMP_FILE``, ``COMP_FILE_TYPE``; LinuxCNC
documentation, INI configuration; its reader ``usrmotLoadComp`` in
src/emc/motion/usrmotintf.cc): one triplet per line,
``nominal forward reverse`` separated by spaces, in machine units, at most 256 lines; the
reader stops at the first line that is not three numbers (so the file carries no header
or comment). With ``COMP_FILE_TYPE = 1`` the second and third values are the trims, the
corrections added to the command while travelling forward (positive direction) and in
reverse; with type 0 they are where the axis is, and the reader takes ``nominal - value``
as the trim. The controller interpolates linearly between the entries and holds the end
values beyond them. When a COMP_FILE is given, BACKLASH is ignored: the two directions'
trims carry it.

A path of poses as an RS274/NGC program (LinuxCNC's G-code; the G-code reference of its
documentation): G20/G21 for inch/mm, G90 absolute, G94 feed per minute, linear axes in
machine units and rotary axes (A, B, C) in degrees.
"""
from __future__ import annotations

import re

import numpy as np

from calib_core.errors import InvalidInputError
from calib_core.storage import write_atomic

LINUXCNC_MAX_ENTRIES = 256
MACHINE_UNITS = {'mm': 1e3, 'inch': 1 / 0.0254}    # per m


def write_linuxcnc_comp(path, table, units: str = 'mm') -> int:
    """Write ``table`` (rows of position, correction forward, correction reverse, m: the
    correction added to a command approached from below / above) as a LinuxCNC
    ``COMP_FILE_TYPE = 1`` file in ``units`` (the machine's). Returns the entry count.

    Raises
    ------
    InvalidInputError
        Unknown units, more than 256 entries, positions not distinct."""
    if units not in MACHINE_UNITS:
        raise InvalidInputError(f'machine units must be one of {", ".join(MACHINE_UNITS)}, '
                                f'not {units!r}')
    rows = np.asarray(table, dtype=float).reshape(-1, 3)
    rows = rows[np.argsort(rows[:, 0])]
    if len(rows) > LINUXCNC_MAX_ENTRIES:
        raise InvalidInputError(f'{len(rows)} entries: LinuxCNC takes at most '
                                f'{LINUXCNC_MAX_ENTRIES} per joint')
    if np.any(np.diff(rows[:, 0]) <= 0):
        raise InvalidInputError('the table\'s positions must be distinct')
    scaled = rows * MACHINE_UNITS[units]
    write_atomic(path, ''.join(f'{n:.6f} {f:.9f} {r:.9f}\n' for n, f, r in scaled))
    return len(rows)


def resampled_for_linuxcnc(table) -> tuple[np.ndarray, bool]:
    """``table`` (rows of position, forward, reverse) as LinuxCNC can take it: unchanged
    where it has at most :data:`LINUXCNC_MAX_ENTRIES` rows, else that many positions evenly
    over its span with the corrections interpolated linearly (as the controller itself
    interpolates between entries). Returns the table and whether it was resampled."""
    rows = np.asarray(table, dtype=float).reshape(-1, 3)
    rows = rows[np.argsort(rows[:, 0])]
    if len(rows) <= LINUXCNC_MAX_ENTRIES:
        return rows, False
    positions = np.linspace(rows[0, 0], rows[-1, 0], LINUXCNC_MAX_ENTRIES)
    return np.column_stack([positions, np.interp(positions, rows[:, 0], rows[:, 1]),
                            np.interp(positions, rows[:, 0], rows[:, 2])]), True


def read_linuxcnc_comp(path, comp_type: int = 1) -> np.ndarray:
    """The entries (k, 3) (nominal, forward trim, reverse trim, machine units) as
    LinuxCNC reads the file: triplets until the first line that is not one, type 0's
    positions turned into trims."""
    entries = []
    with open(path, encoding='utf-8') as stream:
        for line in stream:
            words = line.split()
            try:
                nominal, forward, reverse = (float(v) for v in words[:3])
            except ValueError:      # fewer than three, or not numbers: the reader stops
                break
            if comp_type == 0:
                forward, reverse = nominal - forward, nominal - reverse
            entries.append((nominal, forward, reverse))
    return np.array(entries).reshape(-1, 3)


def linuxcnc_trim(entries: np.ndarray, position, forward: bool) -> np.ndarray:
    """The trim LinuxCNC adds to a command at ``position`` (machine units) moving forward
    or in reverse: linear between the entries, the end values beyond them."""
    return np.interp(position, entries[:, 0], entries[:, 1 if forward else 2])


# RS274/NGC as LinuxCNC reads it (LinuxCNC G-code reference: G20/G21 units, G90 absolute,
# G0 rapid, G1 with F in units per minute under G94; rotary axes A, B, C in degrees).
GCODE_UNITS = {'mm': ('G21', 1e3), 'inch': ('G20', 1 / 0.0254)}
LINEAR_AXES, ROTARY_AXES = ('X', 'Y', 'Z'), ('A', 'B', 'C')


def write_gcode_path(path, poses, axes: str = 'XYZAC', units: str = 'mm',
                     feed: float = 300.0, comment: str = '') -> int:
    """Write ``poses`` (k, len(axes)): linear axes in m, rotary axes in rad, as an
    RS274/NGC program: a rapid (G0) to the first pose, then G1 through the rest at
    ``feed`` (machine units per minute), absolute (G90), rotary axes in degrees. Returns
    the move count.

    Raises
    ------
    InvalidInputError
        Unknown units or axis letters, poses not finite or of the wrong width, a feed <= 0."""
    if units not in GCODE_UNITS:
        raise InvalidInputError(f'machine units must be one of {", ".join(GCODE_UNITS)}, '
                                f'not {units!r}')
    unknown = set(axes) - set(LINEAR_AXES + ROTARY_AXES)
    if unknown or len(set(axes)) != len(axes):
        raise InvalidInputError(f'axes {axes!r}: each of X, Y, Z, A, B, C at most once')
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    if poses.shape[1] != len(axes) or not np.all(np.isfinite(poses)) or not len(poses):
        raise InvalidInputError(f'poses must be finite rows of {len(axes)} values ({axes})')
    if not feed > 0:
        raise InvalidInputError(f'feed {feed} must be > 0 ({units}/min)')
    code, per_m = GCODE_UNITS[units]
    scale = np.array([per_m if a in LINEAR_AXES else 180.0 / np.pi for a in axes])
    lines = ['%', f'({comment})' if comment else '(path)', f'{code} G90 G94 G17']
    for k, pose in enumerate(poses * scale):
        words = ' '.join(f'{a}{v:.6f}' for a, v in zip(axes, pose))
        lines.append(f'G0 {words}' if k == 0 else f'G1 {words}' + (f' F{feed:g}' if k == 1 else ''))
    lines += ['M2', '%']
    write_atomic(path, '\n'.join(lines) + '\n')
    return len(poses)


def read_gcode_moves(path, axes: str = 'XYZAC') -> np.ndarray:
    """The positions (k, len(axes)) of the program's G0/G1 moves in m and rad, read as a
    controller reads them: the units word in force (G20/G21), modal motion and axis
    words (an axis not named keeps its value), comments in parentheses left out."""
    per_m, motion, position, moves = None, None, {a: 0.0 for a in axes}, []
    with open(path, encoding='utf-8') as stream:
        for line in stream:
            words = re.sub(r'\([^)]*\)|;.*', '', line).upper().split()
            named = False
            for word in words:
                letter, value = word[0], word[1:]
                if letter == 'G' and value in ('20', '21'):
                    per_m = GCODE_UNITS['inch' if value == '20' else 'mm'][1]
                elif letter == 'G' and value in ('0', '00', '1', '01'):
                    motion = int(value)
                elif letter in axes:
                    if per_m is None:
                        raise InvalidInputError(f'{path}: an axis word before G20/G21')
                    position[letter] = float(value) / (per_m if letter in LINEAR_AXES
                                                       else 180.0 / np.pi)
                    named = True
            if named and motion is not None:
                moves.append([position[a] for a in axes])
    return np.array(moves).reshape(-1, len(axes))
