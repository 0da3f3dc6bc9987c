"""The term library: generic candidate terms for physics the effect vocabulary lacks.

When the discrepancy workflow's vocabulary (`flaair_model.effects`) leaves a located gap, its
discovery step searches this table for the term that closes it (docs/DISCREPANCY.md). A term
found that way is a `DiscoveredTerm`: a `TermKind` of the table, the place it acts on and its
fitted parameters. A model carries its discovered terms (config/model.yaml `discovered:`) and
the plant applies them wherever it simulates (`flaair_sim.core.plant`).

Where a term acts (`SITES`) and what its coefficient means:

- ``stroke_dynamics``, ``pitch_dynamics``: a torque (N m) added to the right-hand side of the
  stroke or pitch equation of motion; its feature is a monomial of the mechanical state
  (`PRIMITIVES`: phi, dphi, psi, dpsi in rad and rad/s, and sign() and abs() of each),
  evaluated inside the plant's RK4 kernel;
- ``drive``: volts added to the drive before the actuator (a function of the drive alone);
- ``stroke_sensor_v``, ``pitch_sensor_v``: volts added to that charge amplifier's output, after
  its high-pass and delay, before noise. There, ``stroke_sensor_v`` and ``pitch_sensor_v`` name
  the outputs measured from the reference voltage V_HREF (the deviations).

Each `TermKind` is one row: its name, the sites it may act on, its form in the model's variable
names (`form`; ``{corner_hz}`` stands for a shape parameter), how it is evaluated (a monomial
for the dynamics, a numpy feature for the drive and the sensors), its shape parameters and the
vocabulary effect it duplicates at a site (`same_as`: the search reports that effect instead).
Adding a term is one row in `TERM_KINDS`; the search and the plant read the table. Besides the
rows, a term may be any form composed from the primitives at a dynamics site, or from the
signals at the drive and the sensors (`flaair_model.term_forms`; `row_of`, `composed_kinds`): its
kind is its expression, e.g. ``phi*abs(dphi)``, ``drive_v*t**2``.

Signals a drive or sensor feature may use (`TermSignals`): ``drive_v``; ``ddrive_v`` (V/s, the
backward difference of the held drive); ``t`` (s from the start of the simulation); ``phi`` and
``psi`` (rad, sensor sites only); the two sensor deviations (sensor sites only); and
``lowpass(x, corner_hz)`` (first-order, bilinear, one per term, its state carried across blocks).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from flaair_model import term_forms
from flaair_model.validation import ModelError, check_number

__all__ = [
    "DYNAMICS_SITES",
    "KINDS",
    "MAX_DYNAMICS_TERMS",
    "PRIMITIVES",
    "SENSOR_SITES",
    "SITES",
    "TERM_KINDS",
    "DiscoveredTerm",
    "ShapeParam",
    "TermKind",
    "TermSignals",
    "composed_kinds",
    "kinds_for",
    "lowpass_ba",
    "monomial",
    "primitive_values",
    "row_of",
]

SITES: tuple[str, ...] = (
    "stroke_dynamics",
    "pitch_dynamics",
    "drive",
    "stroke_sensor_v",
    "pitch_sensor_v",
)
DYNAMICS_SITES: tuple[str, ...] = SITES[:2]
SENSOR_SITES: tuple[str, ...] = SITES[3:]
# The factors a dynamics monomial multiplies (exponents 0-3 each), in kernel order: declared
# once, in `term_forms`, where the composed forms are built from them.
PRIMITIVES: tuple[str, ...] = term_forms.PRIMITIVES


def monomial(primitives: Sequence[np.ndarray], exponents: Sequence[int]) -> np.ndarray:
    """The product of `primitives` (`primitive_values`) each to its exponent: a dynamics form's
    feature. Computing the primitives once lets many forms share them.
    """
    out = None  # the product so far: 1 x a is a, so the ones it once started from are skipped
    for x, e in zip(primitives, exponents, strict=True):
        if e:
            factor = x if e == 1 else x**e
            out = factor if out is None else out * factor
    if out is None:
        return np.ones(np.shape(primitives[0]))
    # a new array, never a primitive itself (a caller may scale it in place)
    return np.array(out, dtype=np.float64) if any(out is x for x in primitives) else out


def primitive_values(
    phi: np.ndarray,
    dphi: np.ndarray,
    psi: np.ndarray,
    dpsi: np.ndarray,
    drive_v: np.ndarray | float = 0.0,
    t_s: np.ndarray | float = 0.0,
    ddrive_v: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, ...]:
    """The `PRIMITIVES` in numpy, in their order (the kernel's `term_kernel.primitive`); the
    drive the actuator sees is `drive_v` (0: the drive off), the time from the run's start `t_s`,
    the commanded drive's rate `ddrive_v` (V/s).
    """
    drive = np.broadcast_to(np.asarray(drive_v, dtype=np.float64), np.shape(phi))
    t = np.broadcast_to(np.asarray(t_s, dtype=np.float64), np.shape(phi))
    rate = np.broadcast_to(np.asarray(ddrive_v, dtype=np.float64), np.shape(phi))
    return (
        phi,
        dphi,
        psi,
        dpsi,
        np.sign(dphi),
        np.sign(dpsi),
        np.abs(dphi),
        np.abs(dpsi),
        np.sign(phi),
        np.sign(psi),
        np.abs(phi),
        np.abs(psi),
        drive,
        np.sign(drive),
        np.abs(drive),
        t,
        rate,
        np.sign(rate),
        np.abs(rate),
    )


# The plant kernel has this many slots for dynamics terms (the search adds one or two).
MAX_DYNAMICS_TERMS = 2


@dataclass(frozen=True)
class ShapeParam:
    """A term's shape parameter (fitted along with its coefficient): bounds and start values."""

    key: str
    lower: float
    upper: float
    grid: tuple[float, ...]


def lowpass_ba(corner_hz: float, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """First-order low-pass (bilinear, pre-warped corner) as normalized (b, a)."""
    k = math.tan(math.pi * min(corner_hz, 0.49 * fs_hz) / fs_hz)
    return np.array([k, k]) / (1.0 + k), np.array([1.0, (k - 1.0) / (k + 1.0)])


class TermSignals:
    """The signals a drive or sensor feature is evaluated on, for one block.

    `zi` is the term's low-pass state on entry; `lowpass` leaves the state after the block in
    `zf` (a feature may use one low-pass).
    """

    def __init__(
        self,
        fs_hz: float,
        drive_v: np.ndarray,
        ddrive_v: np.ndarray,
        t: np.ndarray,
        phi: np.ndarray | None = None,
        psi: np.ndarray | None = None,
        stroke_sensor_v: np.ndarray | None = None,
        pitch_sensor_v: np.ndarray | None = None,
        zi: float = 0.0,
        dphi: np.ndarray | None = None,
        dpsi: np.ndarray | None = None,
    ) -> None:
        self.fs_hz = fs_hz
        self.drive_v, self.ddrive_v, self.t = drive_v, ddrive_v, t
        self.phi, self.psi, self.dphi, self.dpsi = phi, psi, dphi, dpsi
        self.stroke_sensor_v, self.pitch_sensor_v = stroke_sensor_v, pitch_sensor_v
        self.zi = self.zf = float(zi)
        # each signal's factors (abs()**d sign()**o), kept for the forms evaluated on these signals
        self.factors: dict[tuple[str, int, int], np.ndarray] = {}

    @classmethod
    def of_block(
        cls,
        fs_hz: float,
        drive_v: np.ndarray,
        first_index: int = 0,
        last_drive_v: float = 0.0,
        zi: float = 0.0,
        last_angles_rad: tuple[float, float] = (0.0, 0.0),
        **sensors: np.ndarray,
    ) -> TermSignals:
        """The signals of a block of commanded drive starting at sample `first_index`:
        ``ddrive_v`` the backward difference from `last_drive_v`, ``t`` from the sample index;
        given the angles (rad), their rates ``dphi`` and ``dpsi`` (rad/s), backward differences
        from `last_angles_rad` (the sample before the block). The drive starts from 0 V, the wing
        wherever it is: at sample 0 an angle's rate is 0.
        """
        ddrive = np.diff(drive_v, prepend=last_drive_v) * fs_hz
        t = (first_index + np.arange(drive_v.shape[0])) / fs_hz
        for name, last in zip(("phi", "psi"), last_angles_rad, strict=True):
            angle = sensors.get(name)
            if angle is not None and angle.shape[0]:
                before = angle[0] if first_index == 0 else last
                sensors["d" + name] = np.diff(angle, prepend=before) * fs_hz
        return cls(fs_hz, drive_v, ddrive, t, zi=zi, **sensors)

    def lowpass(self, x: np.ndarray, corner_hz: float) -> np.ndarray:
        """`x` through the term's first-order low-pass at `corner_hz`."""
        # deferred: scipy.signal takes about a second to import, and only a low-pass term needs
        # it here: a process that loads the model (a plant, a health monitor) is spared it
        from scipy import signal

        b, a = lowpass_ba(corner_hz, self.fs_hz)
        y, zf = signal.lfilter(b, a, x, zi=np.array([self.zi]))
        self.zf = float(zf[0])
        out: np.ndarray = y
        return out

    def need(self, name: str) -> np.ndarray:
        """A sensor-site signal; a term that reads it elsewhere is a table error."""
        value: np.ndarray | None = getattr(self, name)
        if value is None:
            raise ModelError(f"term signal {name!r} exists at the sensor sites only")
        return value


Feature = Callable[[TermSignals, Mapping[str, float]], np.ndarray]


@dataclass(frozen=True)
class TermKind:
    """One row of the term library.

    Attributes
    ----------
    name : its key (`DiscoveredTerm.kind`).
    words : what it is, in words.
    sites : the sites it may act on.
    form : the feature in the model's variable names; ``{key}`` marks a shape parameter.
    monomial : exponents over `PRIMITIVES` (dynamics sites).
    feature : (signals, shape values) -> feature per sample (drive and sensor sites).
    shape : its shape parameters.
    same_as : {site: vocabulary effect} where the term is that effect under another name.
    examples : physics it stands for, for the report.
    composed : a form composed from the primitives or the signals (`row_of`), not a row of the
        table; its name is its expression (a product of the angles alone carries both its
        monomial and its feature).
    """

    name: str
    words: str
    sites: tuple[str, ...]
    form: str
    monomial: tuple[int, ...] = ()
    feature: Feature | None = None
    shape: tuple[ShapeParam, ...] = ()
    same_as: Mapping[str, str] = field(default_factory=dict)
    examples: str = ""
    composed: bool = False

    def __post_init__(self) -> None:
        dynamic = set(self.sites) & set(DYNAMICS_SITES)
        if dynamic and (
            len(self.monomial) != len(PRIMITIVES)
            or (not self.composed and (self.feature is not None or set(self.sites) - dynamic))
        ):
            raise ModelError(
                f"term {self.name}: a dynamics term is a monomial over "
                f"{len(PRIMITIVES)} primitives and acts on the dynamics only"
            )
        if set(self.sites) - dynamic and self.feature is None:
            raise ModelError(f"term {self.name}: a drive or sensor term needs a feature")
        unknown = set(self.sites) - set(SITES)
        if unknown:
            raise ModelError(f"term {self.name}: unknown site(s) {', '.join(sorted(unknown))}")


def _other(site: str) -> str:
    return {"stroke_sensor_v": "pitch_sensor_v", "pitch_sensor_v": "stroke_sensor_v"}.get(site, "")


def _mono(**exponents: int) -> tuple[int, ...]:
    keys = [p.replace("(", "_").rstrip(")") for p in PRIMITIVES]  # "sign(dphi)" -> sign_dphi
    names = {k: j for j, k in enumerate(keys)}
    e = [0] * len(PRIMITIVES)
    for k, v in exponents.items():
        e[names[k]] = v
    return tuple(e)


_S, _P = ("stroke_dynamics",), ("pitch_dynamics",)
_SP = _S + _P
_SENS = SENSOR_SITES
_CORNER = (ShapeParam("corner_hz", 20.0, 5000.0, (150.0, 400.0, 1200.0)),)

TERM_KINDS: tuple[TermKind, ...] = (
    # ---- dynamics: torques, monomials of the mechanical state
    TermKind(
        "constant",
        "a constant torque",
        _SP,
        "1",
        _mono(),
        examples="a hinge or flexure that does not rest at zero; a bias in the actuator",
    ),
    TermKind(
        "cross_angle",
        "a torque proportional to the other angle",
        _SP,
        "{y}",
        _mono(),
        examples="stroke-pitch stiffness coupling",
    ),
    TermKind(
        "square_angle",
        "a torque in the square of the angle",
        _SP,
        "{x}**2",
        _mono(),
        examples="an asymmetric flexure",
    ),
    TermKind(
        "cube_angle",
        "a torque in the cube of the angle",
        _SP,
        "{x}**3",
        _mono(),
        same_as={"pitch_dynamics": "hinge_stiffening"},
        examples="a stiffening flexure",
    ),
    TermKind(
        "sign_velocity",
        "a torque of constant size against the velocity's sign",
        _SP,
        "sign({v})",
        _mono(),
        examples="dry (Coulomb) friction",
    ),
    TermKind(
        "abs_velocity",
        "a torque in the velocity's magnitude",
        _SP,
        "abs({v})",
        _mono(),
        examples="an even (one-sided) drag",
    ),
    TermKind(
        "linear_velocity",
        "a viscous torque",
        _S,
        "dphi",
        _mono(dphi=1),
        same_as={"stroke_dynamics": "structural_damping"},
        examples="structural damping",
    ),
    TermKind(
        "cube_velocity",
        "a torque in the cube of the velocity",
        _SP,
        "{v}**3",
        _mono(),
        examples="a cubic damper",
    ),
    TermKind(
        "cross_product",
        "a torque in the product of the two angles",
        _SP,
        "phi*psi",
        _mono(phi=1, psi=1),
        examples="a geometric coupling",
    ),
    TermKind(
        "cross_rates",
        "a torque in the product of the two rates",
        _SP,
        "dphi*dpsi",
        _mono(dphi=1, dpsi=1),
        examples="a rotational (Coriolis-like) coupling",
    ),
    # ---- drive before the actuator
    TermKind(
        "drive_rate",
        "the drive's rate of change",
        ("drive",),
        "ddrive_v",
        feature=lambda s, p: s.ddrive_v,
        examples="a differentiating amplifier stage",
    ),
    TermKind(
        "drive_lag",
        "a first-order lag of the drive",
        ("drive",),
        "(lowpass(drive_v, {corner_hz}) - drive_v)",
        feature=lambda s, p: s.lowpass(s.drive_v, p["corner_hz"]) - s.drive_v,
        shape=_CORNER,
        examples="an amplifier with a finite bandwidth (coefficient 1)",
    ),
    TermKind(
        "drive_square",
        "the square of the drive",
        ("drive",),
        "drive_v**2",
        feature=lambda s, p: s.drive_v**2,
        examples="an asymmetric actuator",
    ),
    TermKind(
        "drive_cube",
        "the cube of the drive",
        ("drive",),
        "drive_v**3",
        feature=lambda s, p: s.drive_v**3,
        examples="an amplifier or piezo saturating",
    ),
    TermKind(
        "drive_drift",
        "a drive gain changing with time",
        ("drive",),
        "t*drive_v",
        feature=lambda s, p: s.t * s.drive_v,
        examples="an actuator warming up",
    ),
    # ---- each sensor chain's output
    TermKind(
        "drive_leak",
        "the drive leaking into the film",
        _SENS,
        "drive_v",
        feature=lambda s, p: s.drive_v,
        same_as={"stroke_sensor_v": "feedthrough"},
        examples="capacitive or resistive pickup of the drive",
    ),
    TermKind(
        "drive_rate_leak",
        "the drive's rate leaking into the film",
        _SENS,
        "ddrive_v",
        feature=lambda s, p: s.ddrive_v,
        examples="capacitive pickup through the substrate",
    ),
    TermKind(
        "drive_lowpass_leak",
        "a low-passed drive leaking into the film",
        _SENS,
        "lowpass(drive_v, {corner_hz})",
        feature=lambda s, p: s.lowpass(s.drive_v, p["corner_hz"]),
        shape=_CORNER,
        examples="pickup through a filtering path",
    ),
    TermKind(
        "crosstalk",
        "the other sensor's voltage",
        _SENS,
        "{other}",
        feature=lambda s, p: s.need("pitch_sensor_v" if p["_site"] == 0 else "stroke_sensor_v"),
        examples="crosstalk between the two charge amplifiers",
    ),
    TermKind(
        "gain_drift",
        "a sensor gain changing with time",
        _SENS,
        "t*{own}",
        feature=lambda s, p: (
            s.t * (s.need("stroke_sensor_v") if p["_site"] == 0 else s.need("pitch_sensor_v"))
        ),
        examples="a film debonding or warming over the session",
    ),
    TermKind(
        "square_angle_sensor",
        "the square of the chain's angle",
        _SENS,
        "{x}**2",
        feature=lambda s, p: (s.need("phi") if p["_site"] == 0 else s.need("psi")) ** 2,
        examples="an even-order transduction",
    ),
)

# The dynamics rows with an angle or velocity placeholder take the site's own variables.
_SITE_VARS = {
    "stroke_dynamics": {"x": "phi", "v": "dphi", "y": "psi"},
    "pitch_dynamics": {"x": "psi", "v": "dpsi", "y": "phi"},
    "stroke_sensor_v": {"x": "phi"},
    "pitch_sensor_v": {"x": "psi"},
}
_SITE_MONOMIALS = {
    "cross_angle": {"stroke_dynamics": _mono(psi=1), "pitch_dynamics": _mono(phi=1)},
    "square_angle": {"stroke_dynamics": _mono(phi=2), "pitch_dynamics": _mono(psi=2)},
    "cube_angle": {"stroke_dynamics": _mono(phi=3), "pitch_dynamics": _mono(psi=3)},
    "sign_velocity": {"stroke_dynamics": _mono(sign_dphi=1), "pitch_dynamics": _mono(sign_dpsi=1)},
    "abs_velocity": {"stroke_dynamics": _mono(abs_dphi=1), "pitch_dynamics": _mono(abs_dpsi=1)},
    "cube_velocity": {"stroke_dynamics": _mono(dphi=3), "pitch_dynamics": _mono(dpsi=3)},
}
KINDS: dict[str, TermKind] = {k.name: k for k in TERM_KINDS}
_COMPOSED: dict[str, TermKind] = {}


def _composed(expression: str) -> TermKind:
    """The form `expression` composed from the primitives (a torque at the dynamics sites) or from
    the signals (volts at the drive and the sensors whose signals it reads), named canonically;
    a product of the angles alone is both.

    Raises
    ------
    ValueError
        Neither grammar builds it (the message says why for each).
    """
    if expression.replace(" ", "").startswith("lowpass("):
        return _filtered(term_forms.filtered_signal(expression))
    monomial: tuple[int, ...] = ()
    key: term_forms.SignalKey | None = None
    try:
        name = term_forms.canonical(term_forms.parse_form(expression))
        monomial = term_forms.parse_form(name) if name != "1" else (0,) * len(PRIMITIVES)
    except ValueError as exc:
        dynamics_error = exc
    try:
        key = term_forms.parse_signal_form(expression)
        name = term_forms.signal_name(key)
    except ValueError as exc:
        if not monomial:
            raise ValueError(
                f"{dynamics_error}; nor from the drive's and sensors' signals: {exc}"
            ) from None
    if key is not None and not term_forms.signal_signals(key):
        key = None  # a constant: the dynamics' (a row's `constant` elsewhere)
    if name in _COMPOSED:
        return _COMPOSED[name]
    sites = DYNAMICS_SITES if monomial else ()
    if key is not None:
        reads = set(term_forms.signal_signals(key))
        sites += tuple(s for s, have in term_forms.SITE_SIGNALS.items() if reads <= set(have))
    feature = _signal_feature(key) if key is not None and sites != DYNAMICS_SITES else None
    words = (
        f"a torque in {name}"
        if feature is None
        else (f"volts in {name}" if not monomial else f"a torque, or volts at a sensor, in {name}")
    )
    _COMPOSED[name] = TermKind(
        name,
        words,
        sites,
        name,
        monomial,
        feature,
        examples="a form composed from the primitives or the signals, no row of the library",
        composed=True,
    )
    return _COMPOSED[name]


def _filtered(x: str) -> TermKind:
    """The low-pass form of signal `x`, ``lowpass(x)``: its corner a shape parameter. A variable
    of the dynamics forms (`term_forms.VARIABLES`) may also be low-passed into a torque: its
    monomial is the variable, the kernel filters it (`is_filtered`).
    """
    name = f"lowpass({x})"
    if name not in _COMPOSED:
        dynamic = x in term_forms.VARIABLES
        sites = (DYNAMICS_SITES if dynamic else ()) + tuple(
            s for s, have in term_forms.SITE_SIGNALS.items() if x in have
        )

        def feature(s: TermSignals, p: Mapping[str, float]) -> np.ndarray:
            return s.lowpass(getattr(s, x) if x in _EVERYWHERE else s.need(x), p["corner_hz"])

        _COMPOSED[name] = TermKind(
            name,
            f"a first-order low-pass of {x} (volts, or a torque at the dynamics)"
            if dynamic
            else f"volts in a first-order low-pass of {x}",
            sites,
            f"lowpass({x}, {{corner_hz}})",
            monomial=term_forms.parse_form(x) if dynamic else (),
            feature=feature,
            shape=_CORNER,
            examples="a memory: a filtering path, a viscoelastic film or flexure, a slow pickup",
            composed=True,
        )
    return _COMPOSED[name]


def _signal_feature(key: term_forms.SignalKey) -> Feature:
    """A signal form's feature on a block's `TermSignals`."""
    reads = term_forms.signal_signals(key)

    def feature(s: TermSignals, _p: Mapping[str, float]) -> np.ndarray:
        values = {x: getattr(s, x) if x in _EVERYWHERE else s.need(x) for x in reads}
        return term_forms.signal_value(key, values, s.factors)

    return feature


_EVERYWHERE = ("drive_v", "ddrive_v", "t")  # the signals every drive or sensor term may read


def row_of(kind: str) -> TermKind:
    """The library row `kind`, or the dynamics form its expression composes (e.g.
    'phi*abs(dphi)'); an expression not built from the primitives is refused by name.
    """
    if kind in KINDS:
        return KINDS[kind]
    if kind in _COMPOSED:  # a canonical name already built
        return _COMPOSED[kind]
    try:
        return _composed(kind)
    except ValueError as exc:
        raise ModelError(
            f"discovered: unknown term {kind!r}: no row of the library ({', '.join(KINDS)}) and "
            f"cannot be built from the primitives ({', '.join(PRIMITIVES)}): {exc}"
        ) from None


def composed_kinds(site: str) -> tuple[TermKind, ...]:
    """The composed forms at `site` that neither a row of the table nor the plant
    (`term_forms.PLANT_FORMS`) computes there, simplest first, then the low-passes of its
    variables or signals that no row computes.
    """
    if site not in DYNAMICS_SITES:
        return _signal_kinds(site)
    key, parse = term_forms.form_key, term_forms.parse_form
    known = {key(DiscoveredTerm(k.name, site, 1.0).monomial) for k in kinds_for(site)}
    known |= {key(parse(f)) for f in term_forms.PLANT_FORMS[site]}
    products = tuple(_composed(n) for n, m in term_forms.composed_forms() if key(m) not in known)
    lowpasses = tuple(
        _composed(n) for n in term_forms.filtered_forms(site) if n not in _ROW_LOWPASSES[site]
    )
    return products + lowpasses


# Low-passes a row computes at a dynamics site with the plant refitted: the stroke's
# lowpass(drive_v) is the drive's `drive_lag` row with the actuator's gain refitted.
_ROW_LOWPASSES = {"stroke_dynamics": ("lowpass(drive_v)",), "pitch_dynamics": ()}


def _signal_kinds(site: str) -> tuple[TermKind, ...]:
    """The signal forms at the drive or sensor site `site` that neither a row there nor the plant
    or a vocabulary effect (`term_forms.SIGNAL_PLANT_FORMS`) computes, simplest first, then the
    low-passes of its signals that no row there computes.
    """
    known = {term_forms.parse_signal_form(f) for f in term_forms.SIGNAL_PLANT_FORMS.get(site, ())}
    filtered = set()
    for k in kinds_for(site):
        filtered |= set(_LOWPASS_OF.findall(k.form))
        try:
            known.add(
                term_forms.parse_signal_form(
                    DiscoveredTerm(k.name, site, 1.0, _mid(k)).feature_expression
                )
            )
        except ValueError:  # a low-pass, another sensor's voltage: not a product of signals
            continue
    products = tuple(_composed(n) for n, k in term_forms.signal_forms(site) if k not in known)
    lowpasses = tuple(
        _composed(n)
        for n in term_forms.filtered_forms(site)
        if term_forms.filtered_signal(n) not in filtered
    )
    return products + lowpasses


# What a row low-passes (its form's `lowpass(x, ...)`): the low-pass form of x is that row.
_LOWPASS_OF = re.compile(r"lowpass\((\w+),")


def _mid(kind: TermKind) -> tuple[tuple[str, float], ...]:
    return tuple((p.key, p.grid[0]) for p in kind.shape)


def kinds_for(site: str) -> tuple[TermKind, ...]:
    """The library rows that may act on `site`, in table order."""
    return tuple(k for k in TERM_KINDS if site in k.sites)


@dataclass(frozen=True)
class DiscoveredTerm:
    """A library term acting on one site with fitted parameters (a model's `discovered` entry).

    Attributes
    ----------
    kind : its `TERM_KINDS` row.
    acts_on : one of `SITES`.
    coefficient : multiplies the feature (N m at a dynamics site, V at the drive and sensors).
    shape : its shape parameters ((key, value) pairs, e.g. corner_hz).
    """

    kind: str
    acts_on: str
    coefficient: float
    shape: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        where = f"discovered.{self.kind}"
        row = row_of(self.kind)
        object.__setattr__(self, "kind", row.name)  # a composed form: its canonical name
        if self.acts_on not in row.sites:
            raise ModelError(
                f"{where}.acts_on must be one of {', '.join(row.sites)}, got {self.acts_on!r}"
            )
        object.__setattr__(
            self, "coefficient", check_number(f"{where}.coefficient", self.coefficient)
        )
        shape = dict(self.shape)
        keys = [s.key for s in row.shape]
        if sorted(shape) != sorted(keys):
            raise ModelError(
                f"{where}: shape parameters must be {keys or 'none'}, got {sorted(shape) or 'none'}"
            )
        for s in row.shape:
            value = check_number(f"{where}.{s.key}", shape[s.key])
            if s.lower * (1 - 1e-9) <= value <= s.upper * (1 + 1e-9):  # exp(log(bound)) rounds
                value = min(max(value, s.lower), s.upper)
            if not s.lower <= value <= s.upper:
                raise ModelError(
                    f"{where}.{s.key} must be in [{s.lower:g}, {s.upper:g}], got {value:g}"
                )
            shape[s.key] = value
        object.__setattr__(self, "shape", tuple((k, shape[k]) for k in keys))

    @property
    def row(self) -> TermKind:
        """Its library row (or composed form)."""
        return row_of(self.kind)

    @property
    def feature_expression(self) -> str:
        """The feature in the model's variables, e.g. 'sign(dphi)'."""
        names = _SITE_VARS.get(self.acts_on, {})
        form = self.row.form.format(
            **names,
            **{k: "{" + k + "}" for k, _ in self.shape},
            own=self.acts_on,
            other=_other(self.acts_on),
        )
        return form.format(**{k: f"{v:.6g}" for k, v in self.shape})

    @property
    def expression(self) -> str:
        """'coefficient * feature', e.g. '-2.1e-07 * sign(dphi)'."""
        return f"{self.coefficient:.6g} * {self.feature_expression}"

    @property
    def monomial(self) -> tuple[int, ...]:
        """Exponents over `PRIMITIVES` (a dynamics term)."""
        return _SITE_MONOMIALS.get(self.kind, {}).get(self.acts_on, self.row.monomial)

    def monomial_value(
        self,
        phi: np.ndarray,
        dphi: np.ndarray,
        psi: np.ndarray,
        dpsi: np.ndarray,
        drive_v: np.ndarray | float = 0.0,
        t_s: np.ndarray | float = 0.0,
        ddrive_v: np.ndarray | float = 0.0,
    ) -> np.ndarray:
        """A dynamics term's feature in numpy (the kernel's `term_kernel.dynamics_terms`), at
        the drive the actuator sees (0: the drive off), the time from the run's start and the
        commanded drive's rate (V/s).
        """
        return monomial(
            primitive_values(phi, dphi, psi, dpsi, drive_v, t_s, ddrive_v), self.monomial
        )

    @property
    def is_filtered(self) -> bool:
        """A low-pass form (``lowpass(x)``): at a dynamics site the kernel filters its monomial."""
        return self.kind.startswith("lowpass(")

    @property
    def is_dynamics(self) -> bool:
        """It acts inside the equations of motion."""
        return self.acts_on in DYNAMICS_SITES

    def feature(self, sig: TermSignals) -> np.ndarray:
        """The feature on one block (a drive or sensor term)."""
        values: dict[str, Any] = dict(self.shape)
        values["_site"] = SENSOR_SITES.index(self.acts_on) if self.acts_on in SENSOR_SITES else -1
        assert self.row.feature is not None
        return np.asarray(self.row.feature(sig, values), dtype=np.float64)
