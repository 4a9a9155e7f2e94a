"""Errors of the grid self-calibration; all derive from calib_core's MachineAlignmentError
so nodes and the CLI report them and keep running."""
from calib_core.errors import InvalidInputError


class PlacementError(InvalidInputError):
    """The plate's placements are not the three the method needs (initial, turned 90
    degrees counter-clockwise about the plate centre, shifted one pitch along +x), or their
    marks do not cover the grid."""
