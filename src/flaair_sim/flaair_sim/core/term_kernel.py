"""The RK4 kernel's constants tuple and the discovered dynamics terms (`flaair_model.terms`).

`mechanical_constants` is the nominal tuple `c` (coefficients over inertia), its order and
length derived from `plant_params.KERNEL_LAYOUT` (`C_*`, `N_CONSTANTS`); a model with
discovered dynamics terms gets `constants_with_terms`, the same tuple followed by one small
tuple per term slot (`N_CONSTANTS_WITH_TERMS` elements in all, the slots at `C_TERM_SLOTS`), so
only kernels compiled for that longer tuple evaluate terms.

A dynamics term is a torque, coefficient x monomial of the mechanical state; `plant_params`
writes each into a slot of the kernel's parameter vector (equation, coefficient over the
equation's inertia, exponents over `flaair_model.terms.PRIMITIVES`), and each slot of the
constants tuple carries its term as `SLOT_FIELDS`: its equation, its coefficient, its monomial
packed into two codes (`_term_slots`), its low-pass's corner in rad/s (0: none).

Why packed: the monomial is evaluated by one non-inlined function (`_monomial`; its inlined
copies were most of the kernel's compile time), so what crosses that call must be a few
scalars. A tuple of the factors is copied at every call, and an array taken out of the
constants tuple is reference-counted at every RK4 stage; either makes the accelerations too
large for LLVM to inline, and each RK4 stage then copies the whole constants tuple into a call.

A low-pass term (`lowpass(x)`) is a first-order low-pass of its monomial, z' = w (x - z), its
state integrated by the RK4 step with the mechanics (`lowpass_rates`), and acts by z; the states
travel with the actuator's (`plant_params.HELD_LOWPASS`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import overload
from numba.np.unsafe.ndarray import to_fixed_tuple

from flaair_model.terms import MAX_DYNAMICS_TERMS, PRIMITIVES
from flaair_sim.core import plant_params as pp
from flaair_sim.core.plant_params import MAX_FACTORS, MAX_POWER, N_CONSTANTS

__all__ = [
    "FACTORS_PER_CODE",
    "FACTOR_BITS",
    "POWER_BITS",
    "SLOT_FIELDS",
    "constants_with_terms",
    "dynamics_terms",
    "lowpass_rates",
    "mechanical_constants",
    "primitive",
]

# A term slot of the constants tuple, field by field.
SLOT_FIELDS = ("equation", "coefficient", "factors_a", "factors_b", "corner_rad_s")
_EQUATION, _COEFFICIENT, _FACTORS_A, _FACTORS_B, _CORNER = range(len(SLOT_FIELDS))
_SLOT_LEN = len(SLOT_FIELDS)
# A factor packs as primitive x 2^POWER_BITS + power in FACTOR_BITS bits, the first factor
# lowest; a code holds FACTORS_PER_CODE factors (48 bits: exact in a float64), and two codes
# hold MAX_FACTORS.
FACTOR_BITS = 8
FACTORS_PER_CODE = 6
POWER_BITS = 3
assert MAX_POWER < 2**POWER_BITS, "a factor's power outgrows its packed bits"
assert len(PRIMITIVES) < 2 ** (FACTOR_BITS - POWER_BITS), "PRIMITIVES outgrow their packed bits"
assert MAX_FACTORS <= 2 * FACTORS_PER_CODE, "a monomial's factors outgrow its two packed codes"

_FMA = {"contract"}
# The kernels carry the low-pass terms' states as a pair (z0, z1): one per slot.
assert MAX_DYNAMICS_TERMS == 2, "the RK4 step carries two low-pass states"
_SOURCE = pp.CONSTANT_SOURCE
_DIVISOR = pp.CONSTANT_DIVISOR


# The slots' places in the longer tuple, as module constants: numba reads a global index as a
# literal, so each slot is one static element, not a switch over the tuple.
_SLOT_0, _SLOT_1 = pp.C_TERM_SLOTS
_EMPTY_SLOT = (0.0,) * _SLOT_LEN


def _slots_of(c):
    """The two term slots of the constants tuple `c`; empty slots for a nominal tuple."""
    return (c[_SLOT_0], c[_SLOT_1]) if len(c) > N_CONSTANTS else (_EMPTY_SLOT, _EMPTY_SLOT)


@overload(_slots_of, inline="always")
def _slots_of_typed(c):
    """`_slots_of` compiled: chosen by the tuple's type, since numba types the term code of a
    nominal kernel too (that code never runs: a compile-time branch) and a nominal tuple has no
    element at `C_TERM_SLOTS`.
    """
    if isinstance(c, types.UniTuple):
        return lambda c: (_EMPTY_SLOT, _EMPTY_SLOT)
    return lambda c: (c[_SLOT_0], c[_SLOT_1])


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
def _monomial(factors_a, factors_b, phi, dphi, psi, dpsi, v, t, dv):
    """The monomial packed in the codes `factors_a`, `factors_b` (its factors, each to its
    power).
    """
    f = 1.0
    for packed in (factors_a, factors_b):
        code = int(packed)
        while code:
            factor = code & (2**FACTOR_BITS - 1)
            x = primitive(factor >> POWER_BITS, phi, dphi, psi, dpsi, v, t, dv)
            for _ in range(factor & (2**POWER_BITS - 1)):
                f *= x
            code >>= FACTOR_BITS
    return f


@njit(cache=True, fastmath=_FMA, inline="always")
def _acting(slot, phi, dphi, psi, dpsi, v, t, dv, z):
    """What the term `slot` multiplies its coefficient by: its low-pass's state `z` if it has
    one, else its monomial.
    """
    if slot[_CORNER] != 0.0:
        return z
    return _monomial(slot[_FACTORS_A], slot[_FACTORS_B], phi, dphi, psi, dpsi, v, t, dv)


@njit(cache=True, fastmath=_FMA, inline="always")
def dynamics_terms(c, phi, dphi, psi, dpsi, v, t, dv, z0, z1):
    """Sums of the discovered terms acting on the stroke and on the pitch equation, over
    inertia, at the drive `v` the actuator sees, the time `t` from the run's start and the
    drive's rate `dv`; a low-pass term acts by its filter's state (`z0`, `z1`: slot 0's and
    slot 1's). Each term's monomial is evaluated once.
    """
    if len(c) == N_CONSTANTS:  # a compile-time constant: a nominal kernel carries no term code
        return 0.0, 0.0
    s0, s1 = _slots_of(c)
    return _slot_sums(s0, s1, phi, dphi, psi, dpsi, v, t, dv, z0, z1)


# Not inlined (numba IR): every RK4 stage of every kernel would carry a copy, and the kernels'
# cold compile grows with the copies; LLVM inlines it where that pays.
@njit(cache=True, fastmath=_FMA)
def _slot_sums(s0, s1, phi, dphi, psi, dpsi, v, t, dv, z0, z1):
    """`dynamics_terms` of the slots `s0`, `s1`."""
    stroke_0, pitch_0 = _slot_torques(s0, phi, dphi, psi, dpsi, v, t, dv, z0)
    stroke_1, pitch_1 = _slot_torques(s1, phi, dphi, psi, dpsi, v, t, dv, z1)
    return stroke_0 + stroke_1, pitch_0 + pitch_1


@njit(cache=True, fastmath=_FMA, inline="always")
def _slot_torques(slot, phi, dphi, psi, dpsi, v, t, dv, z):
    """The term `slot`'s torque over inertia on the stroke and on the pitch (one is 0; both for
    an empty slot).
    """
    if slot[_EQUATION] == 0.0:
        return 0.0, 0.0
    x = slot[_COEFFICIENT] * _acting(slot, phi, dphi, psi, dpsi, v, t, dv, z)
    return (x, 0.0) if slot[_EQUATION] == 1.0 else (0.0, x)


@njit(cache=True, fastmath=_FMA, inline="always")
def _lowpass_rate(slot, phi, dphi, psi, dpsi, v, t, dv, z):
    """The rate w (monomial - z) of the term `slot` with a low-pass of corner w; else 0."""
    w = slot[_CORNER]
    if slot[_EQUATION] == 0.0 or w == 0.0:
        return 0.0
    return w * (_monomial(slot[_FACTORS_A], slot[_FACTORS_B], phi, dphi, psi, dpsi, v, t, dv) - z)


@njit(cache=True, fastmath=_FMA, inline="always")
def lowpass_rates(c, phi, dphi, psi, dpsi, v, t, dv, z0, z1):
    """The low-pass terms' filter states' rates, w (monomial - z) (0 for a slot without one):
    a first-order low-pass integrated with the mechanics, its input the monomial at each stage.
    The two slots written out (no list: a list is a heap allocation per stage).
    """
    s0, s1 = _slots_of(c)
    return (
        _lowpass_rate(s0, phi, dphi, psi, dpsi, v, t, dv, z0),
        _lowpass_rate(s1, phi, dphi, psi, dpsi, v, t, dv, z1),
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
    """The discovered terms' slots, each as `SLOT_FIELDS`: its factors (the primitives with a
    nonzero power, in primitive order) packed, so the kernel visits only the factors a monomial
    has, not every primitive.
    """
    s = np.zeros(MAX_DYNAMICS_TERMS * _SLOT_LEN)
    for slot in range(MAX_DYNAMICS_TERMS):
        src = pp.P_TERMS + slot * pp.TERM_SLOT
        dst = slot * _SLOT_LEN
        s[dst + _EQUATION], s[dst + _COEFFICIENT] = p[src], p[src + 1]
        s[dst + _CORNER] = p[src + pp.TERM_LOWPASS]
        q = 0
        for j in range(pp.TERM_LOWPASS - 2):
            power = int(p[src + 2 + j])
            if power != 0 and q < MAX_FACTORS:  # plant_params refuses more, or a larger power
                field = _FACTORS_A if q < FACTORS_PER_CODE else _FACTORS_B
                shift = FACTOR_BITS * (q % FACTORS_PER_CODE)
                s[dst + field] += ((j << POWER_BITS) + power) * 2.0**shift
                q += 1
    return s


@njit(cache=True, fastmath=_FMA)
def mechanical_constants(p):
    """The nominal constants tuple `c` of parameter vector `p` (order: `plant_params.C_*`)."""
    # an intrinsic: numba passes its typing context, so mypy sees one argument short
    return to_fixed_tuple(_constants(p), N_CONSTANTS)  # type: ignore[call-arg]


@njit(cache=True, fastmath=_FMA)
def constants_with_terms(p):
    """`mechanical_constants` followed by the discovered terms' slots (`_term_slots`), each a
    tuple of its `SLOT_FIELDS`: a longer tuple, so the kernels compiled for it are the only
    ones that evaluate terms.
    """
    s = _term_slots(p)
    # intrinsics: numba passes their typing context, so mypy sees one argument short
    slots = (
        to_fixed_tuple(s[:_SLOT_LEN], _SLOT_LEN),  # type: ignore[call-arg]
        to_fixed_tuple(s[_SLOT_LEN:], _SLOT_LEN),  # type: ignore[call-arg]
    )
    return mechanical_constants(p) + slots
