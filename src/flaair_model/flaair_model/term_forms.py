"""Dynamics term forms composed from primitives: parsed, put in canonical form, generated.

A dynamics term's feature is a monomial over `PRIMITIVES` (the plant kernel's generic
evaluation multiplies the factors, each to an integer power). The forms the discovery step may
reach without a row of the term library (`flaair_model.terms`) are composed here from the drive
the actuator sees, the drive's rate, time and the four mechanical states (`VARIABLES`: drive_v,
ddrive_v, t, phi, psi, dphi, dpsi) and how they combine: each variable, its ``abs()`` and its
``sign()``, to powers up to `MAX_POWER`, and products of up to `MAX_VARIABLES` variables'
factors, of total degree at most
`MAX_POWER` (``sign()`` counts 0); time ``t`` (s from the run's start) is never negative, so it
enters by its powers only. A form with a drive factor (a piezo whose stiffness or damping follows
its field: ``drive_v*phi``), a drive-rate factor (a torque that follows how fast the field
changes: ``ddrive_v*phi``) or a time factor (a flexure drifting: ``t*phi``) acts in the
simulation; the describing functions, which take the plant at rest in time with the drive off,
leave it out.

Forms are compared by what they compute, not how they are written: over a state x,
``x**a * sign(x)**b * abs(x)**c`` is ``abs(x)**(a + c) * sign(x)**(a + b)``, so ``dphi*sign(dphi)``
is ``abs(dphi)`` and ``phi**2*sign(phi)`` is ``phi*abs(phi)``: a state's factor is its class
(degree, odd). `canonical` names each value once (`form_key` says when two monomials are one
form).

The drive and the sensor outputs take forms over signals instead (`SIGNALS`: the drive, its
rate, time, the angles, their rates and the sensors' voltages; `SITE_SIGNALS` says which a site
may read), composed the same way and evaluated on numpy blocks (`signal_value`); ``t`` (s from
the start of the simulation, every run's own) is never negative, so it enters by its powers only.
A product of the variables is one form in both grammars, with one name (`SIGNALS` writes them
in `VARIABLES`' order).

Memory: a form may also be a first-order low-pass of one signal or variable, ``lowpass(x)``
(`filtered_forms`), its corner a shape parameter fitted with the coefficient. At a dynamics site
it is a continuous first-order low-pass, z' = 2 pi f_c (x - z), its state integrated with the
mechanics (a spring relaxing through a dashpot: ``lowpass(phi)``); at the drive and the sensors,
the bilinear first order on the samples.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from itertools import combinations, product

import numpy as np

__all__ = [
    "MAX_POWER",
    "MAX_VARIABLES",
    "PLANT_FORMS",
    "PRIMITIVES",
    "SENSOR_ANGLE",
    "SIGNALS",
    "SIGNAL_PLANT_FORMS",
    "SITE_SIGNALS",
    "VARIABLES",
    "canonical",
    "composed_forms",
    "filtered_forms",
    "filtered_signal",
    "form_key",
    "parse_form",
    "parse_signal_form",
    "signal_forms",
    "signal_name",
    "signal_signals",
    "signal_value",
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
    "drive_v",
    "sign(drive_v)",
    "abs(drive_v)",
    "t",
    "ddrive_v",
    "sign(ddrive_v)",
    "abs(ddrive_v)",
)
# The variables a form is a product over, in the order a canonical name writes them (the drive
# the actuator sees, V; the commanded drive's rate, V/s, its backward difference; time, s from
# the run's start; the three held over a sample; then the mechanical states; `SIGNALS` writes
# them in the same order).
VARIABLES: tuple[str, ...] = ("drive_v", "ddrive_v", "t", "phi", "psi", "dphi", "dpsi")
_UNSIGNED = ("t",)  # never negative: its abs() is itself, its sign() a constant
# Forms the plant's equations already carry (the actuator, the stiffnesses, damping,
# aerodynamic drag and coupling).
PLANT_FORMS = {
    "stroke_dynamics": ("drive_v", "phi", "dphi*abs(dphi)"),
    "pitch_dynamics": ("psi", "dpsi", "dphi*abs(dphi)"),
}
# A factor's power, and a composed form's total degree (sign() counts 0), at most this.
MAX_POWER = 3
# A form multiplies the factors of at most this many variables.
MAX_VARIABLES = 3
# Each signed variable's places among the primitives: (itself, its sign(), its abs()); an
# unsigned one has itself only.
_PLACES = {x: (PRIMITIVES.index(x), PRIMITIVES.index(f"sign({x})"), PRIMITIVES.index(f"abs({x})"))
           for x in VARIABLES if x not in _UNSIGNED}  # fmt: skip
_VARIABLE = "(?:d?drive_v|d?(?:phi|psi))"
_FACTOR = re.compile(rf"^(sign\({_VARIABLE}\)|abs\({_VARIABLE}\)|{_VARIABLE}|t)(?:\*\*(\d+))?$")

# What a monomial computes: each variable's (degree, odd), in `VARIABLES` order.
FormKey = tuple[int, ...]


def parse_form(expression: str) -> tuple[int, ...]:
    """The monomial (exponents over `PRIMITIVES`) of a product of primitives.

    ``'phi*abs(dphi)'``, ``'dpsi**3'``, ``'sign(dphi)*psi**2'``, ``'abs(phi)*psi'``. At most
    `MAX_VARIABLES` distinct states, each factor's power 1 to `MAX_POWER`.

    Raises
    ------
    ValueError
        The expression is not such a product (the message says why).
    """
    exponents = [0] * len(PRIMITIVES)
    for factor in _factors(expression):
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
    variables |= {x for x in _UNSIGNED if exponents[PRIMITIVES.index(x)]}
    if len(variables) > MAX_VARIABLES:
        raise ValueError(f"a product of more than {MAX_VARIABLES} variables")
    return tuple(exponents)


def _factors(expression: str) -> list[str]:
    """Factors of a product: split at '*' that is not part of '**' (spaces ignored)."""
    text = expression.replace(" ", "")
    if not text:
        raise ValueError("an empty expression")
    return re.split(r"(?<!\*)\*(?!\*)", text)


def form_key(monomial: tuple[int, ...]) -> FormKey:
    """What a monomial computes: each state's (degree, odd class), in `VARIABLES` order."""
    out: list[int] = []
    for x in VARIABLES:
        if x in _UNSIGNED:
            d = monomial[PRIMITIVES.index(x)]
            out += [d, d % 2]
            continue
        v, s, a = (monomial[j] for j in _PLACES[x])
        out += [v + a, (v + s) % 2 if v + s + a else 0]
    return tuple(out)


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


def _classes(x: str = "") -> list[tuple[int, int]]:
    """A variable's factor classes (degree, odd): its sign, then each power of it and of its abs;
    an unsigned one's (`_UNSIGNED`), its powers.
    """
    if x in _UNSIGNED:
        return [(d, d % 2) for d in range(1, MAX_POWER + 1)]
    return [(d, o) for d in range(MAX_POWER + 1) for o in (0, 1) if d or o]


def _monomial(key: FormKey) -> tuple[int, ...]:
    """A monomial computing `key` (the canonical writing's exponents)."""
    e = [0] * len(PRIMITIVES)
    for i, x in enumerate(VARIABLES):
        d, o = key[2 * i], key[2 * i + 1]
        if x in _UNSIGNED:
            e[PRIMITIVES.index(x)] = d
            continue
        v, s, a = _PLACES[x]
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
            for classes in product(*(_classes(VARIABLES[i]) for i in states)):
                k = [0] * (2 * len(VARIABLES))
                for i, (d, o) in zip(states, classes, strict=True):
                    k[2 * i], k[2 * i + 1] = d, o
                key: FormKey = tuple(k)
                if _degree(key) <= MAX_POWER:
                    keys.append(key)
    keys.sort(key=lambda k: (_n_variables(k), _degree(k)))
    return tuple((canonical(_monomial(k)), _monomial(k)) for k in keys)


# ------------------------------------------------------------ the drive's and the sensors' forms

# The signals a drive or sensor form multiplies (`flaair_model.terms.TermSignals`), in the order
# a canonical name writes them; the sensor voltages are the deviations from V_HREF.
SIGNALS: tuple[str, ...] = (
    "drive_v",
    "ddrive_v",
    "t",
    "phi",
    "psi",
    "dphi",
    "dpsi",
    "stroke_sensor_v",
    "pitch_sensor_v",
)
_MOTION = ("phi", "psi", "dphi", "dpsi")
# Where a form over them may act, and with which: the drive is a function of the drive and time
# alone; a sensor's output may also take the angles, their rates and that sensor's own voltage.
SITE_SIGNALS: dict[str, tuple[str, ...]] = {
    "drive": ("drive_v", "ddrive_v", "t"),
    "stroke_sensor_v": ("drive_v", "ddrive_v", "t", *_MOTION, "stroke_sensor_v"),
    "pitch_sensor_v": ("drive_v", "ddrive_v", "t", *_MOTION, "pitch_sensor_v"),
}
# Forms the plant or a vocabulary effect already computes at a site (the actuator's gain, a
# film's transduction gain and its strain transfer, the transmission's cubic, the feedthrough).
SIGNAL_PLANT_FORMS: dict[str, tuple[str, ...]] = {
    "drive": ("drive_v",),
    "stroke_sensor_v": ("phi", "phi**3", "stroke_sensor_v", "drive_v"),
    "pitch_sensor_v": ("psi", "pitch_sensor_v"),
}
# The angle each sensor's film reads, and its rate: its voltage is that angle through the chain.
SENSOR_ANGLE = {"stroke_sensor_v": ("phi", "dphi"), "pitch_sensor_v": ("psi", "dpsi")}
_SIGNAL_FACTOR = re.compile(
    r"^(?:(sign|abs)\((" + "|".join(SIGNALS) + r")\)|(" + "|".join(SIGNALS) + r"))(?:\*\*(\d+))?$"
)

# What a signal form computes: each signal's (degree, odd), in `SIGNALS` order.
SignalKey = tuple[int, ...]


def parse_signal_form(expression: str) -> SignalKey:
    """What a product of the signals' factors computes (`SignalKey`).

    ``'t*drive_v'``, ``'drive_v*abs(drive_v)'``, ``'sign(ddrive_v)*phi'``. At most
    `MAX_VARIABLES` distinct signals, each factor's power 1 to `MAX_POWER`; ``t`` is never
    negative, so it takes no ``abs()`` or ``sign()``.

    Raises
    ------
    ValueError
        The expression is not such a product (the message says why).
    """
    key = [0] * (2 * len(SIGNALS))
    for factor in _factors(expression):
        m = _SIGNAL_FACTOR.match(factor)
        if m is None:
            raise ValueError(
                f"{factor!r} is not a signal ({', '.join(SIGNALS)}), its abs() or sign()"
            )
        wrap, inside, bare, power_text = m.groups()
        name = inside or bare
        power = int(power_text or 1)
        if not 1 <= power <= MAX_POWER:
            raise ValueError(f"{factor!r}: powers are 1 to {MAX_POWER}")
        if wrap and name in _UNSIGNED:
            raise ValueError(f"{factor!r}: {name} is never negative (write {name})")
        i = 2 * SIGNALS.index(name)
        degree, odd = key[i], key[i + 1]
        if wrap == "sign":
            odd += power
        else:
            degree += power
            odd += 0 if wrap == "abs" else power
        key[i], key[i + 1] = degree, odd % 2
    if max(key[0::2]) > MAX_POWER:
        raise ValueError(f"a signal to a power above {MAX_POWER}")
    if sum(1 for i in range(len(SIGNALS)) if key[2 * i] or key[2 * i + 1]) > MAX_VARIABLES:
        raise ValueError(f"a product of more than {MAX_VARIABLES} signals")
    return tuple(key)


def signal_name(key: SignalKey) -> str:
    """A signal form's one name, e.g. 't*drive_v' ('1' for the constant)."""
    parts: list[str] = []
    for i, x in enumerate(SIGNALS):
        parts += _factor(x, key[2 * i], key[2 * i + 1])
    return "*".join(parts) or "1"


def signal_signals(key: SignalKey) -> tuple[str, ...]:
    """The signals a form reads."""
    return tuple(x for i, x in enumerate(SIGNALS) if key[2 * i] or key[2 * i + 1])


def signal_forms(site: str) -> tuple[tuple[str, SignalKey], ...]:
    """Every form over `site`'s signals (`SITE_SIGNALS`), (name, key), simplest first: each
    signal's factor classes and their products over two and three signals, of total degree at
    most `MAX_POWER`; none at a dynamics site. A sensor's voltage and the angle its film reads
    (`SENSOR_ANGLE`) are one signal seen twice: no form multiplies the voltage by that angle or
    its rate.
    """
    names = SITE_SIGNALS.get(site, ())
    keys: list[SignalKey] = []
    for n in range(1, MAX_VARIABLES + 1):
        for chosen in combinations(names, n):
            if site in SENSOR_ANGLE and site in chosen and set(SENSOR_ANGLE[site]) & set(chosen):
                continue
            options = [_classes(x) for x in chosen]
            for classes in product(*options):
                k = [0] * (2 * len(SIGNALS))
                for x, (d, o) in zip(chosen, classes, strict=True):
                    i = 2 * SIGNALS.index(x)
                    k[i], k[i + 1] = d, o
                if sum(k[0::2]) <= MAX_POWER:
                    keys.append(tuple(k))
    keys.sort(key=lambda k: (len(signal_signals(k)), sum(k[0::2])))
    return tuple((signal_name(k), k) for k in keys)


def signal_value(
    key: SignalKey,
    values: Mapping[str, np.ndarray],
    factors: dict[tuple[str, int, int], np.ndarray] | None = None,
) -> np.ndarray:
    """A signal form on arrays of its signals (`values`: signal name -> samples); `factors`, a
    cache of each signal's factors kept by the caller across the forms of one set of signals.
    """
    cache = {} if factors is None else factors
    out: np.ndarray | None = None
    for i, x in enumerate(SIGNALS):
        degree, odd = key[2 * i], key[2 * i + 1]
        if not (degree or odd):
            continue
        f = cache.get((x, degree, odd))
        if f is None:
            f = cache[(x, degree, odd)] = _signal_factor(values[x], degree, odd)
        out = f if out is None else out * f
    if out is None:
        raise ValueError("the constant form has no signal")
    return out


def _signal_factor(values: np.ndarray, degree: int, odd: int) -> np.ndarray:
    """abs(x)**degree * sign(x)**odd on samples of x."""
    v = np.asarray(values, dtype=np.float64)
    magnitude = np.abs(v)
    f = np.ones_like(v) if degree == 0 else magnitude
    for _ in range(degree - 1):
        f = f * magnitude
    return f * np.sign(v) if odd else f


# ------------------------------------------------------------------- first-order low-passes

_FILTERED = re.compile(r"^lowpass\((" + "|".join(SIGNALS) + r")\)$")


def filtered_signal(expression: str) -> str:
    """The signal a low-pass form ``'lowpass(x)'`` filters.

    Raises
    ------
    ValueError
        The expression is not a low-pass of one signal (time is never filtered: it would be time
        delayed).
    """
    m = _FILTERED.match(expression.replace(" ", ""))
    if m is None or m.group(1) in _UNSIGNED:
        raise ValueError(
            f"{expression!r} is not lowpass() of one signal "
            f"({', '.join(x for x in SIGNALS if x not in _UNSIGNED)})"
        )
    return m.group(1)


def filtered_forms(site: str) -> tuple[str, ...]:
    """Every low-pass form at `site`: ``lowpass(x)`` of each signal it reads but time (at a
    dynamics site, of each variable but time).
    """
    reads = VARIABLES if site in PLANT_FORMS else SITE_SIGNALS.get(site, ())
    return tuple(f"lowpass({x})" for x in reads if x not in _UNSIGNED)
