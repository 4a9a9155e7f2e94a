"""Errors of the platform; all derive from calib_core's MachineAlignmentError so nodes and
the CLI report them and keep running."""
from calib_core.errors import OutOfTravelError


class WorkspaceError(OutOfTravelError):
    """A pose the platform cannot reach: a feed outside its stroke, a chain that cannot
    close (the link is too short for the pose), or a pose reached only on another branch
    of the inverse kinematics (another assembly mode). Nothing moves."""
