"""servogym.autotune."""
