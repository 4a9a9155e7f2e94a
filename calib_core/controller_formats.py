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
"""
from __future__ import annotations

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
