"""The effect table: every effect the nominal model leaves out, declared once.

One `EffectEntry` per effect holds all that the rest of FLAAIR knows of it:

- its parameters (`kind`, a frozen dataclass validated on construction; config/model.yaml
  `effects:` keys are the entry names);
- where it acts: the plant kernel coefficients it sets (`kernel_terms`, computed by `terms`
  from the effect, the nominal plant and the sample rate) and the measured channels it can
  change (`acts_on`);
- how the discrepancy search fits it (`searched_on`, `fit`, `trades_off`, `separable`);
- the range the hidden-effect generator draws it from (`draw`).

`flaair_sim.core.plant_params.prepare` writes `terms` into the kernels' parameter vector,
`flaair_analysis.discrepancy.vocabulary` builds its search vocabulary from `fit`, and
`flaair_analysis.discrepancy.offnominal` draws random robots from `draw`. Adding an effect is one
entry here; a new kernel number also a `KernelSlot` row in `flaair_sim.core.plant_params` and
its force in `flaair_sim.core.plant_kernel` (docs/CONTRIBUTING.md);
tests/test_effect_table.py checks that every entry reaches all three and that it changes the
channels it names and no others. The order of `EFFECTS` is the order effects are stored in a
model and searched in.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from flaair_model.validation import ModelError, check_channel, check_fields

__all__ = [
    "EFFECTS",
    "EFFECT_NAMES",
    "EFFECT_TYPES",
    "ENTRIES",
    "MEASURED_CHANNELS",
    "PER_CHANNEL_EFFECTS",
    "PLANT_TERMS",
    "SCALE_TERMS",
    "SENSOR_CHANNELS",
    "SENSOR_TERMS",
    "TRUTH_CHANNELS",
    "ActuatorHysteresis",
    "ChargeAmpHighpass",
    "Collision",
    "DrawRange",
    "Effect",
    "EffectEntry",
    "Feedthrough",
    "FitParam",
    "HingeStiffening",
    "SensorDelay",
    "SensorEffect",
    "StrainTransferLoss",
    "StructuralDamping",
    "TermContext",
    "TransmissionNonlinearity",
    "WingDamage",
]

# The measured channels an effect can change (truth from video, voltages from the films).
MEASURED_CHANNELS: tuple[str, ...] = (
    "stroke_deg",
    "pitch_deg",
    "stroke_sensor_v",
    "pitch_sensor_v",
)
TRUTH_CHANNELS: tuple[str, ...] = ("stroke_deg", "pitch_deg")
SENSOR_CHANNELS: tuple[str, ...] = ("stroke_sensor_v", "pitch_sensor_v")

# The kernel coefficients an entry's `terms` may name. Plant terms are set; scale terms multiply
# the nominal value; sensor terms are per sensor chain (the entry has a `channel`).
PLANT_TERMS: tuple[str, ...] = (
    "structural_damping_nm_s_per_rad",
    "hinge_cubic_per_rad2",
    "contact_on",
    "stroke_limit_rad",
    "contact_stiffness_nm_per_rad",
    "contact_damping_nm_s_per_rad",
    "transmission_cubic_per_rad2",
    "feedthrough_v_per_v",
    "hysteresis_fraction",
    "hysteresis_saturation_v",
)
SCALE_TERMS: tuple[str, ...] = ("inertia_factor",)
SENSOR_TERMS: tuple[str, ...] = (
    "delay_samples",
    "highpass_b0",
    "highpass_b1",
    "highpass_a1",
    "gain_factor",
)


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class SensorDelay:
    """Pure delay of the sensor voltage; fractional samples by linear interpolation."""

    delay_s: float
    channel: str = "both"

    def __post_init__(self) -> None:
        check_fields(self, "effects.sensor_delay", {"delay_s": "nonneg"})
        check_channel(self, "effects.sensor_delay")


@dataclass(frozen=True)
class ChargeAmpHighpass:
    """First-order high-pass (bilinear) of the charge-amplifier output about V_HREF."""

    corner_hz: float
    channel: str = "both"

    def __post_init__(self) -> None:
        check_fields(self, "effects.charge_amp_highpass", {"corner_hz": "pos"})
        check_channel(self, "effects.charge_amp_highpass")


@dataclass(frozen=True)
class Feedthrough:
    """Drive voltage added to the stroke-sensor output: gain * V."""

    gain_v_per_v: float

    def __post_init__(self) -> None:
        check_fields(self, "effects.feedthrough", {"gain_v_per_v": "finite"})


@dataclass(frozen=True)
class TransmissionNonlinearity:
    """Actuator sensor sees delta_a = (phi + c phi^3) / T_r; the dynamics are unchanged."""

    cubic_per_rad2: float

    def __post_init__(self) -> None:
        check_fields(self, "effects.transmission_nonlinearity", {"cubic_per_rad2": "finite"})


@dataclass(frozen=True)
class HingeStiffening:
    """Hinge torque k_h (psi + c psi^3)."""

    cubic_per_rad2: float

    def __post_init__(self) -> None:
        check_fields(self, "effects.hinge_stiffening", {"cubic_per_rad2": "finite"})


@dataclass(frozen=True)
class StructuralDamping:
    """Viscous stroke damping 2 zeta sqrt(K I) (nominal I, so independent of wing_damage)."""

    damping_ratio: float

    def __post_init__(self) -> None:
        check_fields(self, "effects.structural_damping", {"damping_ratio": "nonneg"})


@dataclass(frozen=True)
class StrainTransferLoss:
    """Sensor film sees `efficiency` x beam strain: the voltage deviation is scaled."""

    efficiency: float
    channel: str = "pitch"

    def __post_init__(self) -> None:
        check_fields(self, "effects.strain_transfer_loss", {"efficiency": "unit"})
        check_channel(self, "effects.strain_transfer_loss")


@dataclass(frozen=True)
class Collision:
    """One-sided stiff spring-damper stop when stroke exceeds `stroke_limit_deg`.

    Contact stiffness = ratio x K; contact damping = 2 zeta sqrt(k_c I) (nominal I).
    The contact only pushes (no sticking).
    """

    stroke_limit_deg: float
    contact_stiffness_ratio: float = 50.0
    contact_damping_ratio: float = 0.2

    def __post_init__(self) -> None:
        check_fields(
            self,
            "effects.collision",
            {
                "stroke_limit_deg": "finite",
                "contact_stiffness_ratio": "pos",
                "contact_damping_ratio": "nonneg",
            },
        )


@dataclass(frozen=True)
class WingDamage:
    """Stroke and pitch inertia scaled by `inertia_factor`; stiffnesses (and J_c) unchanged."""

    inertia_factor: float

    def __post_init__(self) -> None:
        check_fields(self, "effects.wing_damage", {"inertia_factor": "unit"})


@dataclass(frozen=True)
class ActuatorHysteresis:
    """Rate-independent hysteresis of the piezo actuator (a Bouc-Wen operator on the drive).

    The actuator's torque is G_a (V - h): the hysteretic voltage h follows the drive by
    dh = alpha dV - beta |dV| h - beta dV |h| (Bouc-Wen with n = 1 and gamma = beta), so after
    a reversal h takes `loop_fraction` (alpha) of each volt and saturates at
    +-`saturation_v` (alpha / (2 beta)). A loop's width over the drive's amplitude A is about
    2 `saturation_v` / A: small at full drive, large at low drive, which sets it apart from a
    change of the actuator's gain. The sensor feedthrough sees the drive itself.
    """

    loop_fraction: float
    saturation_v: float

    def __post_init__(self) -> None:
        check_fields(
            self,
            "effects.actuator_hysteresis",
            {"loop_fraction": "nonneg", "saturation_v": "pos"},
        )
        if not self.loop_fraction < 1.0:
            raise ModelError(
                "effects.actuator_hysteresis.loop_fraction must be below 1 (the actuator "
                f"keeps some of each volt), got {self.loop_fraction}"
            )


Effect = (
    SensorDelay
    | ChargeAmpHighpass
    | Feedthrough
    | TransmissionNonlinearity
    | HingeStiffening
    | StructuralDamping
    | StrainTransferLoss
    | Collision
    | WingDamage
    | ActuatorHysteresis
)
# The effects of one sensor chain (a `channel` parameter): each chain may hold its own value.
SensorEffect = SensorDelay | ChargeAmpHighpass | StrainTransferLoss


# --------------------------------------------------------------------------- the table


@dataclass(frozen=True)
class FitParam:
    """One parameter as the discrepancy search fits it: null value, bounds, starting grid, FD step.

    `null`: the value at which the effect does nothing (inf: collision, no contact). `grid`:
    starting values tried before the local fit (empty: start at the null). `log`: fit
    log(parameter).
    """

    key: str
    null: float
    lower: float
    upper: float
    grid: tuple[float, ...] = ()
    step: float = 1e-4
    log: bool = False


@dataclass(frozen=True)
class DrawRange:
    """Where the hidden-effect generator draws one parameter: uniform in [low, high] (in log
    space if `log`), times a random sign if `signed`.
    """

    key: str
    low: float
    high: float
    log: bool = False
    signed: bool = False


@dataclass(frozen=True)
class TermContext:
    """What an effect's kernel terms may depend on: the nominal plant and the sample rate."""

    stroke_inertia_kg_m2: float
    stroke_stiffness_nm_per_rad: float
    fs_hz: float


@dataclass(frozen=True)
class EffectEntry:
    """One effect, declared once (see the module docstring).

    Attributes
    ----------
    name : its key under `effects:` in config/model.yaml.
    kind : its parameter dataclass.
    kernel_terms : the kernel coefficients `terms` returns (names from PLANT_TERMS, SCALE_TERMS,
        SENSOR_TERMS).
    terms : (effect, context) -> {kernel term: value}; a sensor effect's terms are per chain.
    acts_on : measured channels it changes.
    searched_on : channels it is searched on (physics on the truth, sensor effects on the sensors).
    fit : its parameters as fitted, the first one tested for significance; all fitted together.
    trades_off : fitted plant parameters (model.yaml `plant:` keys) it is fitted jointly with.
    separable : its signature differs from every change of the fitted plant parameters.
    note : why it is (not) separable.
    draw : the generator's range for each parameter (in draw order).
    own_family : the hidden-effect generator draws it in a benchmark family of its own, not
        among the single-effect and pair robots (whose draws do not depend on it).
    """

    name: str
    kind: type
    kernel_terms: tuple[str, ...]
    terms: Callable[[Any, TermContext], dict[str, float]]
    acts_on: tuple[str, ...]
    searched_on: tuple[str, ...]
    fit: tuple[FitParam, ...]
    draw: tuple[DrawRange, ...]
    trades_off: tuple[str, ...] = ()
    separable: bool = True
    note: str = ""
    own_family: bool = False

    @property
    def per_sensor(self) -> bool:
        """It acts on one sensor chain at a time (it has a `channel` parameter)."""
        return "channel" in {f.name for f in fields(self.kind)}


def _highpass_terms(e: ChargeAmpHighpass, c: TermContext) -> dict[str, float]:
    if not e.corner_hz < c.fs_hz / 2:
        raise ModelError(
            "effects.charge_amp_highpass.corner_hz must be below fs_hz/2 = "
            f"{c.fs_hz / 2:g}, got {e.corner_hz:g}"
        )
    # deferred: scipy.signal takes about a second to import, and only this effect needs it here:
    # a process that loads the model (a plant, a health monitor, an experiment) is spared it
    from scipy.signal import butter

    b, a = butter(1, e.corner_hz, btype="highpass", fs=c.fs_hz)
    b, a = b / a[0], a / a[0]
    return {"highpass_b0": float(b[0]), "highpass_b1": float(b[1]), "highpass_a1": float(a[1])}


def _collision_terms(e: Collision, c: TermContext) -> dict[str, float]:
    stiffness = e.contact_stiffness_ratio * c.stroke_stiffness_nm_per_rad
    return {
        "contact_on": 1.0,
        "stroke_limit_rad": math.radians(e.stroke_limit_deg),
        "contact_stiffness_nm_per_rad": stiffness,
        "contact_damping_nm_s_per_rad": 2.0
        * e.contact_damping_ratio
        * math.sqrt(stiffness * c.stroke_inertia_kg_m2),
    }


_HINGE_PLANT = (
    "pitch_natural_frequency_hz",
    "hinge_damping_nm_s_per_rad",
    "inertial_coupling_kg_m2",
    "aero_coupling_nm_s2",
)
_STROKE_PLANT = ("aero_damping_nm_s2", "actuator_gain_nm_per_v", "stroke_natural_frequency_hz")

EFFECTS: tuple[EffectEntry, ...] = (
    EffectEntry(
        "sensor_delay",
        SensorDelay,
        ("delay_samples",),
        lambda e, c: {"delay_samples": e.delay_s * c.fs_hz},
        SENSOR_CHANNELS,
        SENSOR_CHANNELS,
        (FitParam("delay_s", 0.0, 0.0, 2e-3, (0.0, 1e-4, 3e-4, 1e-3), 2e-7),),
        (DrawRange("delay_s", 30e-6, 300e-6),),
    ),
    EffectEntry(
        "charge_amp_highpass",
        ChargeAmpHighpass,
        ("highpass_b0", "highpass_b1", "highpass_a1"),
        _highpass_terms,
        SENSOR_CHANNELS,
        SENSOR_CHANNELS,
        (
            FitParam(
                "corner_hz", 0.0, 0.05, 100.0, tuple(np.geomspace(0.3, 100.0, 6)), 1e-3, log=True
            ),
        ),
        (DrawRange("corner_hz", 2.0, 15.0),),
    ),
    EffectEntry(
        "feedthrough",
        Feedthrough,
        ("feedthrough_v_per_v",),
        lambda e, c: {"feedthrough_v_per_v": e.gain_v_per_v},
        ("stroke_sensor_v",),
        ("stroke_sensor_v",),
        (FitParam("gain_v_per_v", 0.0, -0.05, 0.05, (), 1e-5),),
        (DrawRange("gain_v_per_v", 0.002, 0.008, signed=True),),
    ),
    EffectEntry(
        "transmission_nonlinearity",
        TransmissionNonlinearity,
        ("transmission_cubic_per_rad2",),
        lambda e, c: {"transmission_cubic_per_rad2": e.cubic_per_rad2},
        ("stroke_sensor_v",),
        ("stroke_sensor_v",),
        (FitParam("cubic_per_rad2", 0.0, -3.0, 3.0, (), 1e-3),),
        (DrawRange("cubic_per_rad2", 0.2, 0.6, signed=True),),
    ),
    EffectEntry(
        "strain_transfer_loss",
        StrainTransferLoss,
        ("gain_factor",),
        lambda e, c: {"gain_factor": e.efficiency},
        SENSOR_CHANNELS,
        SENSOR_CHANNELS,
        (FitParam("efficiency", 1.0, 0.01, 1.0, (), 1e-4),),
        (DrawRange("efficiency", 0.2, 0.8),),
    ),
    EffectEntry(
        "hinge_stiffening",
        HingeStiffening,
        ("hinge_cubic_per_rad2",),
        lambda e, c: {"hinge_cubic_per_rad2": e.cubic_per_rad2},
        ("pitch_deg", "pitch_sensor_v"),
        ("pitch_deg",),
        (FitParam("cubic_per_rad2", 0.0, -1.0, 50.0, (-0.5, 0.0, 0.5, 2.0, 8.0, 32.0), 1e-3),),
        (DrawRange("cubic_per_rad2", 0.5, 4.0),),
        trades_off=_HINGE_PLANT,
    ),
    EffectEntry(
        "structural_damping",
        StructuralDamping,
        ("structural_damping_nm_s_per_rad",),
        lambda e, c: {
            "structural_damping_nm_s_per_rad": 2.0
            * e.damping_ratio
            * math.sqrt(c.stroke_stiffness_nm_per_rad * c.stroke_inertia_kg_m2)
        },
        MEASURED_CHANNELS,
        TRUTH_CHANNELS,
        (FitParam("damping_ratio", 0.0, 0.0, 1.0, (0.0, 0.01, 0.03, 0.1, 0.3), 1e-4),),
        (DrawRange("damping_ratio", 0.02, 0.08),),
        trades_off=_STROKE_PLANT,
    ),
    EffectEntry(
        "collision",
        Collision,
        (
            "contact_on",
            "stroke_limit_rad",
            "contact_stiffness_nm_per_rad",
            "contact_damping_nm_s_per_rad",
        ),
        _collision_terms,
        MEASURED_CHANNELS,
        TRUTH_CHANNELS,
        (
            FitParam(
                "stroke_limit_deg", math.inf, 1.0, 90.0, tuple(np.arange(6.0, 62.0, 4.0)), 0.02
            ),
            FitParam("contact_stiffness_ratio", 50.0, 2.0, 2000.0, (), 1e-3, log=True),
            FitParam("contact_damping_ratio", 0.2, 0.01, 2.0, (), 1e-3, log=True),
        ),
        (
            DrawRange("stroke_limit_deg", 25.0, 40.0),
            DrawRange("contact_stiffness_ratio", 20.0, 200.0, log=True),
            DrawRange("contact_damping_ratio", 0.1, 0.5),
        ),
        trades_off=_STROKE_PLANT,
    ),
    EffectEntry(
        "wing_damage",
        WingDamage,
        ("inertia_factor",),
        lambda e, c: {"inertia_factor": e.inertia_factor},
        MEASURED_CHANNELS,
        TRUTH_CHANNELS,
        (FitParam("inertia_factor", 1.0, 0.3, 1.0, (0.5, 0.7, 0.85, 0.95, 1.0), 1e-4),),
        (DrawRange("inertia_factor", 0.75, 0.95),),
        separable=False,
        note="scaling the "
        "wing inertia "
        "equals raising "
        "both natural "
        "frequencies and "
        "scaling the "
        "damping, gain "
        "and coupling "
        "coefficients, "
        "all of which "
        "are fitted "
        "plant "
        "parameters",
    ),
    EffectEntry(
        "actuator_hysteresis",
        ActuatorHysteresis,
        ("hysteresis_fraction", "hysteresis_saturation_v"),
        lambda e, c: {
            "hysteresis_fraction": e.loop_fraction,
            "hysteresis_saturation_v": e.saturation_v,
        },
        MEASURED_CHANNELS,
        TRUTH_CHANNELS,
        (
            FitParam("loop_fraction", 0.0, 0.0, 0.95, (0.1, 0.3, 0.6), 1e-4),
            FitParam("saturation_v", 10.0, 0.5, 200.0, (), 1e-3, log=True),
        ),
        (
            DrawRange("loop_fraction", 0.2, 0.5),
            DrawRange("saturation_v", 5.0, 15.0),
        ),
        trades_off=_STROKE_PLANT,
        own_family=True,
    ),
)
ENTRIES: dict[str, EffectEntry] = {e.name: e for e in EFFECTS}
EFFECT_TYPES: dict[str, type] = {e.name: e.kind for e in EFFECTS}
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECT_TYPES)
# Effects of one sensor chain (a `channel` parameter): each chain may hold its own value.
PER_CHANNEL_EFFECTS: tuple[str, ...] = tuple(e.name for e in EFFECTS if e.per_sensor)
