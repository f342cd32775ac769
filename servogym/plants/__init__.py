"""servogym.plants."""
