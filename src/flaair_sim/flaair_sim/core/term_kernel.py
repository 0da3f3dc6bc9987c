"""The RK4 kernel's constants tuple and the discovered dynamics terms (`flaair_model.terms`).

`mechanical_constants` is the nominal tuple `c` (coefficients over inertia), its order and
length derived from `plant_params.KERNEL_LAYOUT` (`C_*`, `N_CONSTANTS`); a model with
discovered dynamics terms gets `constants_with_terms`, the same tuple followed by one array of
the terms' slots (`N_CONSTANTS_WITH_TERMS` elements in all, the array at `C_TERMS`), so only
kernels compiled for that longer tuple evaluate terms. The slots are an array, not more tuple
elements, because a term's factors are read at indexes known only at run time: into an array
that is a load, into a tuple a switch over all its elements, which the RK4 stages would inline
dozens of times per kernel.

A dynamics term is a torque, coefficient x monomial of the mechanical state; `plant_params`
writes each into a slot of the kernel's parameter vector (equation, coefficient over the
equation's inertia, exponents over `flaair_model.terms.PRIMITIVES`), and the slots' array
carries each term as [equation, coefficient, its factors (primitive, power), at most
`MAX_FACTORS`, -1 after the last, its low-pass's corner in rad/s (0: none)].

A low-pass term (`lowpass(x)`) is a first-order low-pass of its monomial, z' = w (x - z), its
state integrated by the RK4 step with the mechanics (`lowpass_rates`), and acts by z; the states
travel with the actuator's (`plant_params.HELD_LOWPASS`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import overload
from numba.np.unsafe.ndarray import to_fixed_tuple

from flaair_model.terms import MAX_DYNAMICS_TERMS
from flaair_sim.core import plant_params as pp
from flaair_sim.core.plant_params import (
    C_TERMS,
    MAX_FACTORS,
    N_CONSTANTS,
)

__all__ = [
    "constants_with_terms",
    "dynamics_terms",
    "lowpass_rates",
    "mechanical_constants",
    "primitive",
]

_FMA = {"contract"}
# The kernels carry the low-pass terms' states as a pair (z0, z1): one per slot.
assert MAX_DYNAMICS_TERMS == 2, "the RK4 step carries two low-pass states"
_SOURCE = pp.CONSTANT_SOURCE
_DIVISOR = pp.CONSTANT_DIVISOR


def _slots_of(c):
    """The term slots' array of the constants tuple `c`; empty for a nominal tuple."""
    return c[C_TERMS] if len(c) > N_CONSTANTS else np.empty(0)


@overload(_slots_of, inline="always")
def _slots_of_typed(c):
    """`_slots_of` compiled: chosen by the tuple's type, since numba types the term code of a
    nominal kernel too (that code never runs: a compile-time branch) and a nominal tuple has no
    element at `C_TERMS`.
    """
    if isinstance(c, types.UniTuple):
        return lambda c: np.empty(0)
    return lambda c: c[C_TERMS]


@njit(cache=True, fastmath=_FMA)
def primitive(j, phi, dphi, psi, dpsi, v, t, dv):
    """Factor j of a term's monomial (flaair_model.terms.PRIMITIVES): the states, sign() and
    abs() of the rates, then sign() and abs() of the angles, then the drive the actuator sees
    (`v`), its sign() and abs(), then the time from the run's start (`t`), then the commanded
    drive's rate (`dv`), its sign() and abs().
    """
    if j < 4:
        return phi if j == 0 else (dphi if j == 1 else (psi if j == 2 else dpsi))
    if j >= 12:
        if j == 15:
            return t
        x = v if j < 15 else dv
        k = j - 12 if j < 15 else j - 16
        if k == 0:
            return x
        if k == 1:
            return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)
        return abs(x)
    if j < 8:
        x = dphi if j % 2 == 0 else dpsi
        signed = j < 6
    else:
        x = phi if j % 2 == 0 else psi
        signed = j < 10
    if signed:
        return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)
    return abs(x)


# Not inlined: the RK4 stages call it at dozens of places per kernel; inlined, its copies were
# most of the kernel's compile time, for no measurable speed.
@njit(cache=True, fastmath=_FMA)
def _monomial(s, base, phi, dphi, psi, dpsi, v, t, dv):
    """The monomial of the term slot at `base` of the slots' array `s` (its factors, each to its
    power).
    """
    f = 1.0
    for q in range(MAX_FACTORS):
        j = int(s[base + 2 + 2 * q])
        if j < 0:
            break
        x = primitive(j, phi, dphi, psi, dpsi, v, t, dv)
        for _ in range(int(s[base + 3 + 2 * q])):
            f *= x
    return f


@njit(cache=True, fastmath=_FMA, inline="always")
def dynamics_terms(c, equation, phi, dphi, psi, dpsi, v, t, dv, z0, z1):
    """Sum of the discovered terms acting on `equation` (1 stroke, 2 pitch), over inertia, at
    the drive `v` the actuator sees, the time `t` from the run's start and the drive's rate
    `dv`; a low-pass term acts by its filter's state (`z0`, `z1`: slot 0's and slot 1's).
    """
    s = _slots_of(c)
    total = 0.0
    for slot in range(MAX_DYNAMICS_TERMS):
        base = slot * pp.TERM_SLOT
        if s[base] == equation:
            if s[base + pp.TERM_LOWPASS] != 0.0:
                total += s[base + 1] * (z0 if slot == 0 else z1)
            else:
                total += s[base + 1] * _monomial(s, base, phi, dphi, psi, dpsi, v, t, dv)
    return total


@njit(cache=True, fastmath=_FMA, inline="always")
def _lowpass_rate(s, base, phi, dphi, psi, dpsi, v, t, dv, z):
    """The rate w (monomial - z) of the slot at `base` of the slots' array `s` with a low-pass
    of corner w; else 0.
    """
    w = s[base + pp.TERM_LOWPASS]
    if s[base] == 0.0 or w == 0.0:
        return 0.0
    return w * (_monomial(s, base, phi, dphi, psi, dpsi, v, t, dv) - z)


@njit(cache=True, fastmath=_FMA, inline="always")
def lowpass_rates(c, phi, dphi, psi, dpsi, v, t, dv, z0, z1):
    """The low-pass terms' filter states' rates, w (monomial - z) (0 for a slot without one):
    a first-order low-pass integrated with the mechanics, its input the monomial at each stage.
    The two slots written out (no list: a list is a heap allocation per stage).
    """
    s = _slots_of(c)
    return (
        _lowpass_rate(s, 0, phi, dphi, psi, dpsi, v, t, dv, z0),
        _lowpass_rate(s, pp.TERM_SLOT, phi, dphi, psi, dpsi, v, t, dv, z1),
    )


@njit(cache=True, fastmath=_FMA)
def _constants(p):
    """The constants (coefficients pre-divided by the inertia of their equation: shortens the
    dependency chain) as an array.
    """
    over = (1.0, 1.0 / p[pp.P_I], 1.0 / p[pp.P_IP])
    c = np.empty(N_CONSTANTS)
    for j in range(N_CONSTANTS):
        c[j] = p[_SOURCE[j]] * over[_DIVISOR[j]]
    return c


@njit(cache=True, fastmath=_FMA)
def _term_slots(p):
    """The discovered terms' slots, each written compactly: [equation, coefficient over
    inertia, (primitive, power) per factor of its monomial in primitive order, -1 after the
    last, the low-pass's corner]. The kernel's loop then visits only the factors a monomial
    has, not every primitive.
    """
    s = np.empty(MAX_DYNAMICS_TERMS * pp.TERM_SLOT)
    for slot in range(MAX_DYNAMICS_TERMS):
        src = pp.P_TERMS + slot * pp.TERM_SLOT
        dst = slot * pp.TERM_SLOT
        s[dst], s[dst + 1] = p[src], p[src + 1]
        for k in range(2, pp.TERM_LOWPASS):
            s[dst + k] = -1.0
        s[dst + pp.TERM_LOWPASS] = p[src + pp.TERM_LOWPASS]
        q = 0
        for j in range(pp.TERM_LOWPASS - 2):
            if p[src + 2 + j] != 0.0 and q < MAX_FACTORS:  # plant_params refuses more
                s[dst + 2 + 2 * q], s[dst + 3 + 2 * q] = j, p[src + 2 + j]
                q += 1
    return s


@njit(cache=True, fastmath=_FMA)
def mechanical_constants(p):
    """The nominal constants tuple `c` of parameter vector `p` (order: `plant_params.C_*`)."""
    # an intrinsic: numba passes its typing context, so mypy sees one argument short
    return to_fixed_tuple(_constants(p), N_CONSTANTS)  # type: ignore[call-arg]


@njit(cache=True, fastmath=_FMA)
def constants_with_terms(p):
    """`mechanical_constants` followed by the discovered terms' slots' array (`_term_slots`): a
    longer tuple, so the kernels compiled for it are the only ones that evaluate terms.
    """
    return mechanical_constants(p) + (_term_slots(p),)  # noqa: RUF005  (numba: + not *c)
