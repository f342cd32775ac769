"""servogym.sim."""
