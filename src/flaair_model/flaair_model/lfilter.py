"""scipy.signal.lfilter as numba kernels, for the per-block cores (front end, dSA controller).

A 10-sample block through ``scipy.signal.lfilter`` costs ~20 us of Python and argument checks
for ~0.1 us of arithmetic; the cores that run 2000 blocks a second compile their whole block
(filters, blends, clips) into one kernel built from these. The arithmetic is scipy's own
direct form II transposed, in scipy's order of operations (``_linear_filter``)::

    y     = z[0] + b[0] x
    z[k]  = z[k+1] + x b[k+1] - y a[k+1]      (k = 0 .. m-3)
    z[-1] = x b[-1] - y a[-1]

with (b, a) normalized by a[0] and the state ``z`` in scipy's ``zi`` convention, so a kernel
filter and ``lfilter(b, a, x, zi=z)`` give the same samples and the same final state (tests:
tests/test_lfilter_kernels.py).

Note: numba's on-disk cache of a kernel that calls ``lfilter_sample`` is keyed on the calling
module's source; change this file and touch (or re-warm) the callers.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "float_block",
    "lfilter",
    "lfilter_sample",
    "normalized_ba",
]


def normalized_ba(b: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) as float64 arrays of one length, divided by a[0] (what lfilter does first)."""
    b = np.atleast_1d(np.asarray(b, dtype=np.float64))
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    m = max(b.size, a.size)
    b = np.concatenate([b, np.zeros(m - b.size)]) / a[0]
    a = np.concatenate([a, np.zeros(m - a.size)]) / a[0]
    return b, a


@njit(cache=True)
def lfilter_sample(b: np.ndarray, a: np.ndarray, z: np.ndarray, x: float) -> float:
    """One sample through the filter; ``z`` (length len(b) - 1) is updated in place."""
    m = b.size
    if m == 1:
        only: float = x * b[0]
        return only
    y = z[0] + b[0] * x
    for k in range(m - 2):
        z[k] = z[k + 1] + x * b[k + 1] - y * a[k + 1]
    z[m - 2] = x * b[m - 1] - y * a[m - 1]
    out: float = y
    return out


@njit(cache=True)
def lfilter(
    b: np.ndarray, a: np.ndarray, x: np.ndarray, zi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.lfilter(b, a, x, zi=zi)`` for normalized (b, a) of one length: (y, zf)."""
    z = zi.copy()
    y = np.empty(x.size)
    for i in range(x.size):
        y[i] = lfilter_sample(b, a, z, x[i])
    return y, z


def float_block(x: np.ndarray) -> np.ndarray:
    """A block as the kernels take it: 1-D, float64, C-contiguous, aligned, writeable.

    Copies only when needed (a read-only CDR view, another dtype), so a kernel is compiled for
    one argument type, not one per memory layout it meets.
    """
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    flags = a.flags
    if not (flags.c_contiguous and flags.aligned and flags.writeable):
        a = a.copy()
    return a
