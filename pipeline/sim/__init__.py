"""The simulator: Model (what does not change), State (positions, velocities, forces),
Control (growth prescribed over time), integrators, and effects as small units."""
