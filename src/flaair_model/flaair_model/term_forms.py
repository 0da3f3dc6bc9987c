"""Dynamics term forms composed from primitives: parsed, put in canonical form, generated.

A dynamics term's feature is a monomial over `PRIMITIVES` (the plant kernel's generic
evaluation multiplies the factors, each to an integer power). The forms the discovery step may
reach without a row of the term library (`flaair_model.terms`) are composed here from the
primitives and how they combine: each state alone, ``abs()`` and ``sign()`` of each velocity,
powers up to `MAX_POWER`, and products of two (a state times the other axis's state, or a
velocity times its own ``abs()`` or ``sign()``), of total degree at most `MAX_POWER`.

Forms are compared by what they compute, not how they are written: over a velocity v,
``v**a * sign(v)**b * abs(v)**c`` is ``abs(v)**(a + c) * sign(v)**(a + b)``, so ``dphi*sign(dphi)``
is ``abs(dphi)`` and ``dphi**2*sign(dphi)`` is ``dphi*abs(dphi)``; `canonical` names each value
once (`form_key` says when two monomials are one form).
"""

from __future__ import annotations

import re
from itertools import combinations

__all__ = [
    "MAX_POWER",
    "PLANT_FORMS",
    "PRIMITIVES",
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
)
# Forms the plant's equations already carry (stiffness, damping, aerodynamic drag and coupling).
PLANT_FORMS = {
    "stroke_dynamics": ("phi", "dphi*abs(dphi)"),
    "pitch_dynamics": ("psi", "dpsi", "dphi*abs(dphi)"),
}
# A factor's power, and a composed form's total degree (sign() counts 0), at most this.
MAX_POWER = 3
_ANGLES = ("phi", "psi")
_RATES = ("dphi", "dpsi")
_FACTOR = re.compile(r"^(sign\(d(?:phi|psi)\)|abs\(d(?:phi|psi)\)|d?(?:phi|psi))(?:\*\*(\d+))?$")

FormKey = tuple[int, int, int, int, int, int]


def parse_form(expression: str) -> tuple[int, ...]:
    """The monomial (exponents over `PRIMITIVES`) of a product of primitives.

    ``'phi*abs(dphi)'``, ``'dpsi**3'``, ``'sign(dphi)*psi**2'``. At most two distinct state
    variables, each factor's power 1 to `MAX_POWER`.

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
    variables = {_variable(j) for j, e in enumerate(exponents) if e}
    if len(variables) > 2:
        raise ValueError("a product of more than two states")
    return tuple(exponents)


def _split(text: str) -> list[str]:
    """Factors of a product: split at '*' that is not part of '**'."""
    return [f for f in re.split(r"(?<!\*)\*(?!\*)", text)]


def _variable(j: int) -> str:
    return PRIMITIVES[j] if j < 4 else _RATES[j % 2]


def form_key(monomial: tuple[int, ...]) -> FormKey:
    """What a monomial computes: (phi, psi) powers, then (degree, odd) of each velocity."""
    e = monomial
    rates = []
    for v, s, a in ((e[1], e[4], e[6]), (e[3], e[5], e[7])):
        rates += [v + a, (v + s) % 2 if v + s + a else 0]
    return (e[0], e[2], *rates)  # type: ignore[return-value]


def _rate_factor(rate: str, degree: int, odd: int) -> tuple[str, ...]:
    """The simplest writing of abs(v)**degree * sign(v)**odd."""
    if degree == 0:
        return (f"sign({rate})",) if odd else ()
    if degree % 2 == odd:
        return (rate if degree == 1 else f"{rate}**{degree}",)
    if degree == 1:
        return (f"abs({rate})",)
    if degree == 2:
        return (rate, f"abs({rate})")
    return (f"abs({rate})**{degree}",)


def canonical(monomial: tuple[int, ...]) -> str:
    """The form's one name, e.g. 'phi*abs(dphi)' ('1' for the constant)."""
    phi, psi, d1, o1, d2, o2 = form_key(monomial)
    parts: list[str] = []
    for name, power in (("phi", phi), ("psi", psi)):
        if power:
            parts.append(name if power == 1 else f"{name}**{power}")
    parts += _rate_factor("dphi", d1, o1) + _rate_factor("dpsi", d2, o2)
    return "*".join(parts) or "1"


def _degree(key: FormKey) -> int:
    return key[0] + key[1] + key[2] + key[4]


def _atoms() -> list[tuple[str, FormKey]]:
    """Every one-variable form: an angle to a power, or a velocity's (degree, odd) class."""
    out: list[tuple[str, FormKey]] = []
    for i, angle in enumerate(_ANGLES):
        for p in range(1, MAX_POWER + 1):
            k = [0] * 6
            k[i] = p
            out.append((angle, tuple(k)))  # type: ignore[arg-type]
    for i, rate in enumerate(_RATES):
        for degree in range(MAX_POWER + 1):
            for odd in (0, 1):
                if degree == 0 and not odd:
                    continue
                k = [0] * 6
                k[2 + 2 * i], k[3 + 2 * i] = degree, odd
                out.append((rate, tuple(k)))  # type: ignore[arg-type]
    return out


def _monomial(key: FormKey) -> tuple[int, ...]:
    """A monomial computing `key` (the canonical writing's exponents)."""
    phi, psi, d1, o1, d2, o2 = key
    e = [phi, 0, psi, 0, 0, 0, 0, 0]
    for v, s, a, d, o in ((1, 4, 6, d1, o1), (3, 5, 7, d2, o2)):
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
    """Every composed form, (canonical name, monomial), simplest first: each one-variable form,
    then each product of two variables' forms, of total degree at most `MAX_POWER`.
    """
    atoms = _atoms()
    keys = [k for _v, k in atoms]
    for (va, ka), (vb, kb) in combinations(atoms, 2):
        if va != vb:
            key = tuple(x + y for x, y in zip(ka, kb, strict=True))
            if _degree(key) <= MAX_POWER:  # type: ignore[arg-type]
                keys.append(key)  # type: ignore[arg-type]
    keys = [k for k in keys if _degree(k) <= MAX_POWER]
    keys.sort(
        key=lambda k: (sum(1 for x in (k[0], k[1], k[2] or k[3], k[4] or k[5]) if x), _degree(k))
    )
    return tuple((canonical(_monomial(k)), _monomial(k)) for k in keys)
