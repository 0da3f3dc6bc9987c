"""The RK4 kernel's constants tuple and the discovered dynamics terms (`flaair_model.terms`).

`mechanical_constants` is the nominal tuple `c` (coefficients over inertia); a model with
discovered dynamics terms gets `constants_with_terms`, the same tuple followed by the terms'
slots, so only kernels compiled for that longer tuple evaluate terms.

A dynamics term is a torque, coefficient x monomial of the mechanical state; `plant_params`
writes each into a slot of the kernel's parameter vector (equation, coefficient over the
equation's inertia, exponents over `flaair_model.terms.PRIMITIVES`) and
`plant.mechanical_constants` copies the slots into the constants tuple `c` from index
`C_TERMS` on (c[C_TERMS - 1] is the number of terms).
"""

from __future__ import annotations

from numba import njit

from flaair_sim.core import plant_params as pp

__all__ = [
    "C_TERMS",
    "N_CONSTANTS",
    "constants_with_terms",
    "dynamics_terms",
    "mechanical_constants",
    "primitive",
]

_FMA = {"contract"}
# length of the nominal constants tuple (`mechanical_constants`); a longer one carries terms:
# their count, then their slots from C_TERMS on
N_CONSTANTS = 12
C_TERMS = N_CONSTANTS + 1


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


@njit(cache=True, fastmath=_FMA)
def mechanical_constants(p):
    # coefficients pre-divided by the inertia of their equation: shortens the dependency chain
    inv_i = 1.0 / p[pp.P_I]
    inv_ip = 1.0 / p[pp.P_IP]
    return (
        p[pp.GA_INDEX] * inv_i,
        p[pp.P_GAMMA] * inv_i,
        p[pp.P_K] * inv_i,
        p[pp.P_CSTRUCT] * inv_i,
        p[pp.P_KH] * inv_ip,
        p[pp.P_HCUBIC],
        p[pp.P_CP] * inv_ip,
        p[pp.P_JC] * inv_ip,
        p[pp.P_DP] * inv_ip,
        p[pp.P_PHI_LIM],
        p[pp.P_KC] * inv_i,
        p[pp.P_CC] * inv_i,
    )


@njit(cache=True, fastmath=_FMA)
def constants_with_terms(p):
    """`mechanical_constants` followed by the term count and the discovered terms' slots: a
    longer tuple, so the kernels compiled for it are the only ones that evaluate terms.
    """
    t = pp.P_TERMS
    return (
        *mechanical_constants(p),
        p[pp.P_NTERMS],
        p[t],
        p[t + 1],
        p[t + 2],
        p[t + 3],
        p[t + 4],
        p[t + 5],
        p[t + 6],
        p[t + 7],
        p[t + 8],
        p[t + 9],
        p[t + 10],
        p[t + 11],
        p[t + 12],
        p[t + 13],
        p[t + 14],
        p[t + 15],
        p[t + 16],
        p[t + 17],
        p[t + 18],
        p[t + 19],
    )
