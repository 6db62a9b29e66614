"""Motion primitives, primitive sequences and the executor that runs them on the robot."""
