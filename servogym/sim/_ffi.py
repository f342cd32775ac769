"""``mj_step`` callable from numba: the libmujoco the Python bindings load, bound once.

``llvmlite.binding.load_library_permanently`` puts the library's symbols in LLVM's table, so
compiled (and cached) code can call ``mj_step(model_address, data_address)`` directly, with no
Python in between. ``MjModel._address`` / ``MjData._address`` are the C pointers.
"""

from __future__ import annotations

import glob
import os

import mujoco
from llvmlite import binding as llvm
from numba import types


def libmujoco_path() -> str:
    """Path of the libmujoco shared library shipped inside the installed ``mujoco`` package."""
    here = os.path.dirname(mujoco.__file__)
    found = sorted(glob.glob(os.path.join(here, "libmujoco.so*")))
    found += sorted(glob.glob(os.path.join(here, "libmujoco*.dylib")))
    if not found:
        raise ImportError(
            f"servogym needs the libmujoco library of the mujoco package; none in {here}. "
            "Reinstall mujoco (pip install --force-reinstall mujoco)."
        )
    return found[0]


llvm.load_library_permanently(libmujoco_path())

# void mj_step(const mjModel* m, mjData* d); pointers passed as machine-word integers.
mj_step = types.ExternalFunction("mj_step", types.void(types.intp, types.intp))

# void mj_forward(const mjModel* m, mjData* d): the accelerations of the current state.
mj_forward = types.ExternalFunction("mj_forward", types.void(types.intp, types.intp))

# void mj_forwardSkip(const mjModel* m, mjData* d, int skipstage, int skipsensor): the same,
# reusing the stages before ``skipstage`` (mjSTAGE_POS = 1: keep the position-dependent
# quantities of the last full mj_forward).
mj_forwardSkip = types.ExternalFunction(
    "mj_forwardSkip", types.void(types.intp, types.intp, types.intc, types.intc)
)
