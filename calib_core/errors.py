"""Errors raised by machine_alignment's core code.

Every error a user can cause with bad input derives from :class:`MachineAlignmentError`, so
nodes and the CLI can catch it, log the message and keep running.
"""


class MachineAlignmentError(Exception):
    """Base class: a clear message about bad input or an impossible request."""


class InvalidInputError(MachineAlignmentError, ValueError):
    """Input data is malformed: missing columns, NaN or infinite values, wrong shapes."""


class UnitMistake(InvalidInputError):
    """Values that make sense only in another unit than the one they were read in (a file
    in mm read as metres): ``quantity`` ('length', 'angle' or 'temperature'),
    ``likely_unit`` ('mm', 'deg', 'degC' or 'K') and the ``column`` they are in (None
    where several are), for a caller that can offer the option reading them in that
    unit."""

    def __init__(self, message: str, quantity: str, likely_unit: str,
                 column: str | None = None):
        super().__init__(message)
        self.quantity = quantity
        self.likely_unit = likely_unit
        self.column = column


class DetectionError(MachineAlignmentError):
    """No usable Mark in an image: none found, clipped at the border, ambiguous, saturated."""


class OutOfTravelError(MachineAlignmentError):
    """A motion command outside the machine's travel; the machine was not moved."""


class CalibrationError(MachineAlignmentError):
    """The data cannot determine the requested parameters, or the fit failed."""


class BagError(MachineAlignmentError):
    """A bag is missing, truncated, or not in rosbag2 MCAP layout."""


class RunCancelled(MachineAlignmentError):
    """The operator cancelled the run: the machine stopped before its next move, what was
    measured is in the run's bag, the calibration in force is unchanged."""
