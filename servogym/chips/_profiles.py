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


class TickArrays:
    """What every family's profile derives from its arrays (a base of the frozen profile
    dataclasses, whose ``__post_init__`` runs :func:`check_arrays`)."""

    position: np.ndarray

    @property
    def n_ticks(self) -> int:
        """Number of entries: servo ticks (PMD cycles, PMAC updates, 6000-series samples)."""
        return int(self.position.shape[0])

    @property
    def final_position(self) -> int:
        """The commanded position of the last entry, in whole counts."""
        return int(self.position[-1])


def check_arrays(profile: Any) -> int:
    """Make a frozen profile's arrays 1-D C-contiguous int64 of one length; return it.

    Raises:
        ValueError: naming the profile class and the array, for an array that is not 1-D,
            holds anything but integers (a float array holding only whole numbers is taken;
            a fraction, NaN or infinity is refused rather than truncated), or lengths that
            differ.
    """
    kind = type(profile).__name__
    sizes = {}
    for name in PROFILE_ARRAYS:
        arr = _int64_array(f"{kind}.{name}", getattr(profile, name))
        if arr.ndim != 1:
            raise ValueError(f"{kind}.{name} must be 1-D; got shape {arr.shape}.")
        object.__setattr__(profile, name, arr)
        sizes[name] = arr.shape[0]
    if len(set(sizes.values())) != 1:
        raise ValueError(f"{kind} arrays must have the same length; got {sizes}.")
    return sizes["position"]


_INT64 = np.iinfo(np.int64)


def _int64_array(label: str, value: Any) -> np.ndarray:
    """``value`` as a C-contiguous int64 array, refusing what a cast would change."""
    arr = np.asarray(value)
    kind = arr.dtype.kind
    if kind == "f" and arr.size:
        bad = ~np.isfinite(arr) | (arr != np.round(arr))
        bad |= (arr < _INT64.min) | (arr >= 2.0**63)
        if bad.any():
            i = int(np.flatnonzero(bad.ravel())[0])
            raise ValueError(
                f"{label} must hold integers (a whole number of counts or 16.16 units per "
                f"entry, within int64); got {arr.dtype} with entry {i} = "
                f"{float(arr.ravel()[i])!r}, which a cast to int64 would change."
            )
    elif kind == "u" and arr.size and int(arr.max()) > _INT64.max:
        raise ValueError(
            f"{label} must fit int64 (<= {_INT64.max}); got {int(arr.max())} ({arr.dtype})."
        )
    elif kind not in "iuf":
        raise ValueError(
            f"{label} must be an integer array; got dtype {arr.dtype} (kind {kind!r})."
        )
    return np.ascontiguousarray(arr, dtype=np.int64)
