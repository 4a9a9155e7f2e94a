"""Conversions between ROS messages and core types, kept at the node boundary."""
from __future__ import annotations

import numpy as np
from alignment_msgs.msg import GantryState, Mark as MarkMsg, MarkArray

from calib_core.errors import InvalidInputError
from calib_core.marks import Mark


def marks_as_message(marks: list[Mark], header, status: str = 'ok') -> MarkArray:
    out = MarkArray()
    out.header = header
    out.status = status
    for mark in marks:
        out.marks.append(MarkMsg(shape=mark.shape, u=mark.u, v=mark.v,
                                 covariance=np.asarray(mark.covariance, float).ravel().tolist(),
                                 size=mark.size, contrast=mark.contrast, quality=mark.quality))
    return out


def marks_from_message(msg) -> list[Mark]:
    """Core Marks from an alignment_msgs/MarkArray (or a decoded bag message).

    Raises InvalidInputError if a centre or covariance is not finite."""
    marks = []
    for m in msg.marks:
        values = np.array([m.u, m.v, *m.covariance], dtype=float)
        if not np.all(np.isfinite(values)):
            raise InvalidInputError('a Mark in the message has a NaN or infinite centre or covariance')
        marks.append(Mark(m.shape, float(m.u), float(m.v), np.reshape(np.array(m.covariance,
                                                                               float), (2, 2)),
                          float(m.size), float(m.contrast), float(m.quality)))
    return marks


def gantry_state_as_message(axis_position, revs, header, moving: bool = False) -> GantryState:
    return GantryState(header=header, x=float(axis_position[0]), y=float(axis_position[1]),
                       x_rev=float(revs[0]), y_rev=float(revs[1]), moving=moving)
