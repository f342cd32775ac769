"""servogym: tune real motion-controller chips in simulation.

Exact (bit-exact to a written spec) emulations of servo-chip filters run around MuJoCo
plants; RL agents, autotuners and benchmarks choose the chip's parameters within its legal
ranges, and the result exports in the form the hardware takes.

Importing the package registers every Gymnasium env id (``servogym/Tune-PMD-Rotary-v1``,
...; see docs/envs.md) without loading the simulator, so ``gym.register_envs(servogym)``
and ``rl_zoo3 --gym-packages servogym`` work as with any env package.
"""

import logging as _logging

from servogym._registration import register_builtin as _register_builtin

__version__ = "0.1.0"

_logging.getLogger(__name__).addHandler(_logging.NullHandler())
_register_builtin()
