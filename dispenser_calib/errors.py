"""Errors of the dispenser; all derive from calib_core's MachineAlignmentError so nodes and
the CLI report them and keep running."""
from calib_core.errors import OutOfTravelError


class StrokeError(OutOfTravelError):
    """A commanded pose outside an axis's stroke; nothing moves."""
