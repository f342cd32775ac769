"""servogym.envs."""
