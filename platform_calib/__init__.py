"""3-DOF screen-registration platform (3-PRR): kinematics, 18-parameter identification, feed compensation (issue 22)."""
