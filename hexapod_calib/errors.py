"""Errors of the hexapod suite; all derive from calib_core's MachineAlignmentError so nodes
and the CLI report them and keep running."""
from calib_core.errors import MachineAlignmentError, OutOfTravelError


class KinematicsError(MachineAlignmentError):
    """A pose or a set of leg lengths the kinematics cannot handle."""


class SingularPoseError(KinematicsError, OutOfTravelError):
    """The pose is at or near a singularity: the legs no longer control every direction."""


class ConvergenceError(KinematicsError):
    """Forward kinematics did not converge (leg lengths no platform pose can realise)."""
