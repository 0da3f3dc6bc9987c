"""Dynamics term forms composed from primitives: parsed, put in canonical form, generated.

A dynamics term's feature is a monomial over `PRIMITIVES` (the plant kernel's generic
evaluation multiplies the factors, each to an integer power). The forms the discovery step may
reach without a row of the term library (`flaair_model.terms`) are composed here from the four
mechanical states (`VARIABLES`: phi, psi, dphi, dpsi) and how they combine: each state, its
``abs()`` and its ``sign()``, to powers up to `MAX_POWER`, and products of up to
`MAX_VARIABLES` states' factors, of total degree at most `MAX_POWER` (``sign()`` counts 0).

Forms are compared by what they compute, not how they are written: over a state x,
``x**a * sign(x)**b * abs(x)**c`` is ``abs(x)**(a + c) * sign(x)**(a + b)``, so ``dphi*sign(dphi)``
is ``abs(dphi)`` and ``phi**2*sign(phi)`` is ``phi*abs(phi)``: a state's factor is its class
(degree, odd). `canonical` names each value once (`form_key` says when two monomials are one
form).
"""

from __future__ import annotations

import re
from itertools import combinations, product

__all__ = [
    "MAX_POWER",
    "MAX_VARIABLES",
    "PLANT_FORMS",
    "PRIMITIVES",
    "VARIABLES",
    "canonical",
    "composed_forms",
    "form_key",
    "parse_form",
]

# The factors a dynamics monomial multiplies, in kernel order (`flaair_sim` term kernel).
PRIMITIVES: tuple[str, ...] = (
    "phi",
    "dphi",
    "psi",
    "dpsi",
    "sign(dphi)",
    "sign(dpsi)",
    "abs(dphi)",
    "abs(dpsi)",
    "sign(phi)",
    "sign(psi)",
    "abs(phi)",
    "abs(psi)",
)
# The states a form is a product over, in the order a canonical name writes them.
VARIABLES: tuple[str, ...] = ("phi", "psi", "dphi", "dpsi")
# Forms the plant's equations already carry (stiffness, damping, aerodynamic drag and coupling).
PLANT_FORMS = {
    "stroke_dynamics": ("phi", "dphi*abs(dphi)"),
    "pitch_dynamics": ("psi", "dpsi", "dphi*abs(dphi)"),
}
# A factor's power, and a composed form's total degree (sign() counts 0), at most this.
MAX_POWER = 3
# A form multiplies the factors of at most this many states.
MAX_VARIABLES = 3
# Each state's places among the primitives: (itself, its sign(), its abs()).
_PLACES = {x: (PRIMITIVES.index(x), PRIMITIVES.index(f"sign({x})"), PRIMITIVES.index(f"abs({x})"))
           for x in VARIABLES}  # fmt: skip
_FACTOR = re.compile(r"^(sign\(d?(?:phi|psi)\)|abs\(d?(?:phi|psi)\)|d?(?:phi|psi))(?:\*\*(\d+))?$")

# What a monomial computes: each state's (degree, odd), in `VARIABLES` order.
FormKey = tuple[int, int, int, int, int, int, int, int]


def parse_form(expression: str) -> tuple[int, ...]:
    """The monomial (exponents over `PRIMITIVES`) of a product of primitives.

    ``'phi*abs(dphi)'``, ``'dpsi**3'``, ``'sign(dphi)*psi**2'``, ``'abs(phi)*psi'``. At most
    `MAX_VARIABLES` distinct states, each factor's power 1 to `MAX_POWER`.

    Raises
    ------
    ValueError
        The expression is not such a product (the message says why).
    """
    text = expression.replace(" ", "")
    if not text:
        raise ValueError("an empty expression")
    exponents = [0] * len(PRIMITIVES)
    for factor in _split(text):
        m = _FACTOR.match(factor)
        if m is None:
            raise ValueError(
                f"{factor!r} is not a primitive ({', '.join(PRIMITIVES)}) or its power"
            )
        power = int(m.group(2) or 1)
        if not 1 <= power <= MAX_POWER:
            raise ValueError(f"{factor!r}: powers are 1 to {MAX_POWER}")
        exponents[PRIMITIVES.index(m.group(1))] += power
    if max(exponents) > MAX_POWER:
        raise ValueError(f"a factor to a power above {MAX_POWER}")
    variables = {x for x, places in _PLACES.items() if any(exponents[j] for j in places)}
    if len(variables) > MAX_VARIABLES:
        raise ValueError(f"a product of more than {MAX_VARIABLES} states")
    return tuple(exponents)


def _split(text: str) -> list[str]:
    """Factors of a product: split at '*' that is not part of '**'."""
    return [f for f in re.split(r"(?<!\*)\*(?!\*)", text)]


def form_key(monomial: tuple[int, ...]) -> FormKey:
    """What a monomial computes: each state's (degree, odd class), in `VARIABLES` order."""
    out: list[int] = []
    for x in VARIABLES:
        v, s, a = (monomial[j] for j in _PLACES[x])
        out += [v + a, (v + s) % 2 if v + s + a else 0]
    return tuple(out)  # type: ignore[return-value]


def _factor(x: str, degree: int, odd: int) -> tuple[str, ...]:
    """The simplest writing of abs(x)**degree * sign(x)**odd."""
    if degree == 0:
        return (f"sign({x})",) if odd else ()
    if degree % 2 == odd:
        return (x if degree == 1 else f"{x}**{degree}",)
    if degree == 1:
        return (f"abs({x})",)
    if degree == 2:
        return (x, f"abs({x})")
    return (f"abs({x})**{degree}",)


def canonical(monomial: tuple[int, ...]) -> str:
    """The form's one name, e.g. 'phi*abs(dphi)' ('1' for the constant)."""
    key = form_key(monomial)
    parts: list[str] = []
    for i, x in enumerate(VARIABLES):
        parts += _factor(x, key[2 * i], key[2 * i + 1])
    return "*".join(parts) or "1"


def _degree(key: FormKey) -> int:
    return sum(key[0::2])


def _n_variables(key: FormKey) -> int:
    return sum(1 for i in range(len(VARIABLES)) if key[2 * i] or key[2 * i + 1])


def _classes() -> list[tuple[int, int]]:
    """A state's factor classes (degree, odd): its sign, then each power of it and of its abs."""
    return [(d, o) for d in range(MAX_POWER + 1) for o in (0, 1) if d or o]


def _monomial(key: FormKey) -> tuple[int, ...]:
    """A monomial computing `key` (the canonical writing's exponents)."""
    e = [0] * len(PRIMITIVES)
    for i, x in enumerate(VARIABLES):
        v, s, a = _PLACES[x]
        d, o = key[2 * i], key[2 * i + 1]
        if d == 0:
            e[s] = o
        elif d % 2 == o:
            e[v] = d
        elif d == 2:
            e[v], e[a] = 1, 1
        else:
            e[a] = d
    return tuple(e)


def composed_forms() -> tuple[tuple[str, tuple[int, ...]], ...]:
    """Every composed form, (canonical name, monomial), simplest first (fewer states, then lower
    degree): each state's factor classes, and their products over two and three states, of total
    degree at most `MAX_POWER`.
    """
    keys: list[FormKey] = []
    for n in range(1, MAX_VARIABLES + 1):
        for states in combinations(range(len(VARIABLES)), n):
            for classes in product(_classes(), repeat=n):
                k = [0] * (2 * len(VARIABLES))
                for i, (d, o) in zip(states, classes, strict=True):
                    k[2 * i], k[2 * i + 1] = d, o
                key: FormKey = tuple(k)  # type: ignore[assignment]
                if _degree(key) <= MAX_POWER:
                    keys.append(key)
    keys.sort(key=lambda k: (_n_variables(k), _degree(k)))
    return tuple((canonical(_monomial(k)), _monomial(k)) for k in keys)
