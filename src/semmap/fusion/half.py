"""IEEE half-precision (float16) storage for numba kernels, which cannot type ``float16`` arrays.

Maps that keep their per-class state in float16 hold it as ``uint16`` bit patterns; kernels read a value with
:func:`half_to_float` (exact) and write one with :func:`float_to_half` (round to nearest, ties to even, as
``numpy.float16``).  Outside numba, ``bits.view(np.float16)`` gives the same numbers.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_EXP_MASK = np.uint32(0x7F800000)
_MANT_MASK = np.uint32(0x007FFFFF)
_HALF_INF = np.uint16(0x7C00)
_HALF_NAN = np.uint16(0x7E00)


@nb.njit(cache=True, inline="always")
def half_to_float(h: np.uint16) -> np.float32:
    """Value of the float16 bit pattern ``h`` (exact: every half is a float32)."""
    sign = -1.0 if (h >> 15) & 1 else 1.0
    e = (np.int64(h) >> 10) & 0x1F
    m = np.int64(h) & 0x3FF
    if e == 0:
        return np.float32(sign * m * 2.0**-24)
    if e == 31:
        return np.float32(sign * np.inf) if m == 0 else np.float32(np.nan)
    return np.float32(sign * (1024 + m) * 2.0 ** (e - 25))


@nb.njit(cache=True, inline="always")
def float_to_half(x: float) -> np.uint16:
    """float16 bit pattern nearest to ``x`` (ties to even; overflow gives ±inf, like ``np.float16``)."""
    if x != x:
        return _HALF_NAN
    sign = np.uint16(0x8000) if math.copysign(1.0, x) < 0.0 else np.uint16(0)
    a = abs(np.float64(np.float32(x)))  # round to float32 first, as numpy converts float32 arrays
    if a == 0.0:
        return sign
    if a >= 65520.0:  # rounds to inf (largest half is 65504, halfway to the next binade is 65520)
        return sign | _HALF_INF
    if a < 2.0**-14:  # subnormal: multiples of 2^-24
        q = a * 2.0**24
        r = np.floor(q)
        d = q - r
        if d > 0.5 or (d == 0.5 and np.int64(r) % 2 == 1):
            r += 1.0
        return sign | np.uint16(np.int64(r))
    m, e = math.frexp(a)  # a = m * 2^e, 0.5 <= m < 1
    q = (m * 2.0 - 1.0) * 1024.0
    r = np.floor(q)
    d = q - r
    if d > 0.5 or (d == 0.5 and np.int64(r) % 2 == 1):
        r += 1.0
    exp = np.int64(e) - 1 + 15
    mant = np.int64(r)
    if mant == 1024:
        mant = 0
        exp += 1
    if exp >= 31:
        return sign | _HALF_INF
    return sign | np.uint16((exp << 10) | mant)


def to_half_bits(values: np.ndarray) -> np.ndarray:
    """numpy float array -> its float16 bit patterns (uint16)."""
    return np.ascontiguousarray(np.asarray(values, np.float32).astype(np.float16)).view(np.uint16)


def from_half_bits(bits: np.ndarray) -> np.ndarray:
    """float16 bit patterns (uint16) -> float32 values."""
    return np.ascontiguousarray(bits, np.uint16).view(np.float16).astype(np.float32)
