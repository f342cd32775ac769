"""Fixed-point primitives the compiled chip kernels (and the runner) share.

Each is inlined into its caller. Widths are explicit: every chip kernel works on int64 and
applies its registers' widths with these.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, inline="always")
def clamp(x, lo, hi):
    """Saturate ``x`` to ``lo..hi``."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@njit(cache=True, nogil=True, inline="always")
def shr(x, n, trunc):
    """Divide by ``2**n``: an arithmetic shift (floor), or toward zero when ``trunc != 0``."""
    if trunc != 0 and x < 0:
        return -((-x) >> n)
    return x >> n


@njit(cache=True, nogil=True, inline="always")
def wrap32(x):
    """Two's-complement wrap to signed 32 bits."""
    return ((x + 2**31) & 0xFFFFFFFF) - 2**31
