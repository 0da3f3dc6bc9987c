"""The discovered dynamics terms inside the RK4 kernel (`flaair_model.terms`).

A dynamics term is a torque, coefficient x monomial of the mechanical state; `plant_params`
writes each into a slot of the kernel's parameter vector (equation, coefficient over the
equation's inertia, exponents over `flaair_model.terms.PRIMITIVES`) and
`plant.mechanical_constants` copies the slots into the constants tuple `c` from index
`C_TERMS` on (c[C_TERMS - 1] is the number of terms).
"""
from __future__ import annotations

from numba import njit

from flaair_sim.core import plant_params as pp

__all__ = ["C_TERMS", "primitive", "dynamics_terms"]

_FMA = {"contract"}
# where the discovered dynamics terms sit in `c` (after the 12 constants and their count)
C_TERMS = 13


@njit(cache=True, fastmath=_FMA)
def primitive(j, phi, dphi, psi, dpsi):
    """Factor j of a term's monomial (flaair_model.terms.PRIMITIVES)."""
    if j < 4:
        return phi if j == 0 else (dphi if j == 1 else (psi if j == 2 else dpsi))
    x = dphi if j % 2 == 0 else dpsi
    if j < 6:
        return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)
    return abs(x)


@njit(cache=True, fastmath=_FMA)
def dynamics_terms(c, equation, phi, dphi, psi, dpsi):
    """Sum of the discovered terms acting on `equation` (1 stroke, 2 pitch), over inertia."""
    total = 0.0
    for slot in range(pp.MAX_DYNAMICS_TERMS):
        base = C_TERMS + slot * pp.TERM_SLOT
        if c[base] == equation:
            f = c[base + 1]
            for j in range(pp.TERM_SLOT - 2):
                x = primitive(j, phi, dphi, psi, dpsi)
                for _ in range(int(c[base + 2 + j])):
                    f *= x
            total += f
    return total
