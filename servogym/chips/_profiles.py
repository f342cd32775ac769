"""Argument checks every family's profile generator shares.

The profiles themselves differ per family (PMD's 16.16 trajectory generator, PMAC's 1/32-count
segments, the 6000-series trajectory periods); the checks of their arguments and of the
profile arrays do not.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from servogym.chips._space import ParameterError, ParamSpec

PROFILE_ARRAYS = ("position", "velocity", "acceleration")
"""The arrays of every family's profile, one entry per servo cycle."""


def int_arg(name: str, value: Any, low: int, high: int, width: str) -> int:
    """``value`` as a Python int, or a ParameterError naming ``name``, the value and range."""
    return ParamSpec(name, low, high, low, width).validate(value)


def real_arg(name: str, value: Any, *, positive: bool = False) -> float:
    """``value`` as a finite float (int or float, not bool), optionally > 0."""
    rule = "a finite number > 0" if positive else "a finite number"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ParameterError(
            f"{name} must be {rule}; got {name}={value!r} of type {type(value).__name__}."
        )
    x = float(value)
    if not math.isfinite(x) or (positive and x <= 0.0):
        raise ParameterError(f"{name} must be {rule}; got {name}={value!r}.")
    return x


def check_arrays(profile: Any) -> int:
    """Make a frozen profile's arrays 1-D C-contiguous int64 of one length; return it.

    Raises:
        ValueError: naming the profile class, for an array that is not 1-D or lengths that
            differ.
    """
    kind = type(profile).__name__
    sizes = {}
    for name in PROFILE_ARRAYS:
        arr = np.ascontiguousarray(getattr(profile, name), dtype=np.int64)
        if arr.ndim != 1:
            raise ValueError(f"{kind}.{name} must be 1-D; got shape {arr.shape}.")
        object.__setattr__(profile, name, arr)
        sizes[name] = arr.shape[0]
    if len(set(sizes.values())) != 1:
        raise ValueError(f"{kind} arrays must have the same length; got {sizes}.")
    return sizes["position"]
