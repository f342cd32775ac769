"""servogym.agents."""
