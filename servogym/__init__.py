"""servogym: tune real motion-controller chips in simulation.

Exact (bit-exact to a written spec) emulations of servo-chip filters run around MuJoCo
plants; RL agents, autotuners and benchmarks choose the chip's parameters within its legal
ranges, and the result exports in the form the hardware takes.
"""

__version__ = "0.1.0"
