"""The project's hidden-effect datasets for the discrepancy workflow, built with the plant.

Each case is a "true robot": the nominal model plus hidden effects (or something outside the
vocabulary), measured with one standard run set at 20 kHz with sensor and tracking noise on
(`flaair_sim.core.measured_run.synthesize_measured_run`):

* ``chirp_full``: chirp 20-200 Hz, 1 s, 100 V amplitude (200 Vpp);
* ``chirp_half``: the same chirp at 50 V;
* ``stepped``: stepped sine 60-200 Hz in 10 Hz steps, 0.2 s each, 100 V.

Case groups
-----------
``single``
    each vocabulary effect alone, at two strengths, one of them at 3x noise, and four near the
    detection limit (wing_damage is carried hidden: a change of the fitted plant reproduces it,
    so the right answer names nothing);
``pair``
    two or more effects at once (different channels, two on the same sensor, two stroke-physics
    effects, three and four effects);
``null``
    the nominal model (expected status ``no_discrepancy``), at 1x and 3x noise;
``outside``
    physics the vocabulary lacks (expected status ``unexplained`` with the gap on the named
    channel): a pitch-sensor gain drifting over the session and a second stroke resonance;
``confusable``
    effects whose signatures resemble each other, at matched sizes: sensor_delay vs
    charge_amp_highpass (both sensor-only phase changes), hinge_stiffening vs
    transmission_nonlinearity (both cubic and amplitude dependent; hinge stiffening changes
    the pitch truth, the transmission nonlinearity only the actuator sensor), and structural vs
    aerodynamic damping.

How the aerodynamic-damping cases must be classified: the quadratic aerodynamic damping Gamma is
a fitted plant parameter (`identification`), so a robot whose Gamma differs from the model's is
parameter drift, not missing physics: x0.8 ends ``no_discrepancy`` with Gamma refitted, x1.5 with
a sensor delay ends ``explained`` naming only the delay. ``structural_damping`` is linear in
velocity; the viscous damping ratio that would mimic the quadratic term grows with stroke
amplitude, so reporting it counts as a wrong answer. Gamma x1.6 lies beyond the identification's
fit range (x1.5 of the model): the plant cannot reach it, and the only honest outcome is
``unexplained`` with the gap on ``stroke_deg`` and nothing named.

This module only builds data and scores results (no file I/O).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import signal

from flaair_model.effects import EFFECTS, ENTRIES
from flaair_model.model import Model, with_effects
from flaair_sim.core.drive import chirp, stepped_sine, stepped_sine_frequencies_hz
from flaair_sim.core.measured_run import synthesize_measured_run

from .runs import CHANNELS, Run
from .vocabulary import PLANT_PARAMETERS
from .workflow import DiscrepancyResult

__all__ = [
    "FS_HZ",
    "random_effect",
    "FULL_DRIVE_V",
    "OUTSIDE_KINDS",
    "DatasetCase",
    "CaseOutcome",
    "run_set_drives",
    "true_model",
    "make_runs",
    "dataset_cases",
    "score_case",
    "confusion_table",
    "expected_column",
    "found_label",
    "FAMILIES",
    "random_robot",
    "true_plant",
    "effective_plant",
]

FS_HZ = 20_000.0
FULL_DRIVE_V = 100.0
OUTSIDE_KINDS = ("aero_damping", "sensor_gain_drift", "second_resonance")
PARAMETER_TOLERANCE = 0.15  # found parameters within 15 % of the truth
MIN_GAP_REDUCTION = 0.5  # model-error NRMSE reduced by at least half on every channel with a gap


def run_set_drives(fs_hz: float = FS_HZ, amplitude_v: float = FULL_DRIVE_V) -> tuple[tuple[str, np.ndarray], ...]:
    """The standard run set: (name, drive_v) of chirp_full, chirp_half and stepped."""
    t = np.arange(int(round(1.0 * fs_hz))) / fs_hz
    full = chirp(t, amplitude_v, 20.0, 200.0, 1.0)
    half = chirp(t, 0.5 * amplitude_v, 20.0, 200.0, 1.0)
    stepped, _ = stepped_sine(fs_hz, amplitude_v, stepped_sine_frequencies_hz(60.0, 200.0, 10.0), 0.2)
    return (("chirp_full", full), ("chirp_half", half), ("stepped", np.asarray(stepped)))


@dataclass(frozen=True)
class DatasetCase:
    """One hidden-effect case.

    Attributes
    ----------
    name : unique case name.
    group : 'single', 'pair', 'null', 'outside' or 'confusable'.
    effects : vocabulary effects of the true robot, ((name, params), ...).
    outside : '' or one of OUTSIDE_KINDS (aero_damping: a Gamma change beyond the plant
        identification's fit range).
    outside_strength : its size (aero_damping: Gamma factor; sensor_gain_drift: gain lost over the
        session; second_resonance: mode gain relative to the stroke's static gain).
    noise_scale : noise relative to the model's noise section.
    seed : noise seed.
    note : what the case tests.
    plant_scale : ((plant key, factor), ...): the robot's plant differs from the model's.
    hidden : vocabulary effects the robot carries that a plant change reproduces exactly (not
        separable, e.g. wing_damage): the right answer does not name them.
    video_every : ground truth only every k-th sample (a video frame rate), NaN between; 1: DAQ rate.
    below_limit : the effects are below what the search on the fitted plant resolves (the joint fit
        absorbs them into the plant on the truth, and the sensors do not search physics): the right
        answer names nothing and leaves the gap located (``unexplained``).
    """

    name: str
    group: str
    effects: tuple = ()
    outside: str = ""
    outside_strength: float = 0.0
    noise_scale: float = 1.0
    seed: int = 0
    note: str = ""
    plant_scale: tuple = ()
    hidden: tuple = ()
    video_every: int = 1
    below_limit: bool = False

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the hidden vocabulary effects, sorted."""
        return tuple(sorted(n for n, _ in self.effects))

    @property
    def expected_names(self) -> tuple[str, ...]:
        """Names the workflow must report, sorted (none for effects below the limit)."""
        return () if self.below_limit else self.effect_names

    @property
    def expected_status(self) -> str:
        """Status the workflow must report."""
        if self.outside or self.below_limit:
            return "unexplained"
        return "explained" if self.effects else "no_discrepancy"

    @property
    def expected_gap_channel(self) -> str:
        """Channel where an outside case must leave its gap ('' otherwise)."""
        return {"aero_damping": "stroke_deg", "sensor_gain_drift": "pitch_sensor_v",
                "second_resonance": "stroke_deg"}.get(self.outside, "")

    @property
    def true_label(self) -> str:
        """Row label of the confusion table ('plant:' marks a hidden, not separable effect)."""
        below = "below:" if self.below_limit else ""
        parts = [below + n for n in self.effect_names] + [f"plant:{n}" for n in sorted(n for n, _ in self.hidden)]
        if self.outside:
            parts.append(f"outside:{self.outside}")
        return "+".join(parts) or "none"

    @property
    def expected_found_label(self) -> str:
        """The confusion-table column a right answer falls in."""
        names = "+".join(self.expected_names) or "none"
        return names + (" (gap left)" if self.expected_status == "unexplained" else "")


def true_model(case: DatasetCase, model: Model) -> Model:
    """The true robot's model (vocabulary effects and the aerodynamic-damping change)."""
    effects = dict(case.effects) | dict(case.hidden)
    m = with_effects(model, effects) if effects else model
    if case.plant_scale:
        m = replace(m, plant=replace(m.plant, **{k: getattr(m.plant, k) * f for k, f in case.plant_scale}))
    if case.outside == "aero_damping":
        m = replace(m, plant=replace(m.plant, aero_damping_nm_s2=m.plant.aero_damping_nm_s2 * case.outside_strength))
    if case.noise_scale != 1.0:
        m = replace(m, noise=replace(m.noise, sensor_noise_v_rms=m.noise.sensor_noise_v_rms * case.noise_scale,
                                     tracking_noise_deg_rms=m.noise.tracking_noise_deg_rms * case.noise_scale))
    return m


def _second_mode_deg(drive_v: np.ndarray, fs_hz: float, model: Model, strength: float,
                     f_hz: float = 175.0, zeta: float = 0.03) -> np.ndarray:
    """Stroke of an extra mode at f_hz: strength x (G_a / K) static gain, in degrees."""
    w = 2.0 * math.pi * f_hz
    static = model.plant.actuator_gain_nm_per_v / model.plant.stroke_stiffness_nm_per_rad
    b, a = signal.bilinear([strength * static * w * w], [1.0, 2.0 * zeta * w, w * w], fs=fs_hz)
    return np.degrees(signal.lfilter(b, a, drive_v))


def make_runs(case: DatasetCase, model: Model, fs_hz: float = FS_HZ) -> tuple[Run, ...]:
    """Synthesize the case's measured run set (noise on) from the nominal `model`.

    The session runs in the order chirp_full, chirp_half, stepped; the sensor gain drift
    follows session time.
    """
    truth = true_model(case, model)
    rng = np.random.default_rng(case.seed)
    drives = run_set_drives(fs_hz)
    total = sum(d.size for _, d in drives)
    t0 = 0
    runs = []
    vref = model.sensors.reference_voltage_v
    for name, drive in drives:
        cols = synthesize_measured_run(drive, fs_hz, truth, rng)
        n = drive.size
        if case.outside == "sensor_gain_drift":
            gain = 1.0 - case.outside_strength * (t0 + np.arange(n)) / total
            cols["pitch_sensor_v"] = vref + (cols["pitch_sensor_v"] - vref) * gain
        elif case.outside == "second_resonance":
            extra = _second_mode_deg(drive, fs_hz, model, case.outside_strength)
            cols["stroke_deg"] = cols["stroke_deg"] + extra
            cols["stroke_sensor_v"] = cols["stroke_sensor_v"] + math.radians(1.0) * model.stroke_volts_per_rad * extra
        t0 += n
        if case.video_every > 1:
            lost = np.arange(n) % case.video_every != 0
            cols["stroke_deg"] = np.where(lost, np.nan, cols["stroke_deg"])
            cols["pitch_deg"] = np.where(lost, np.nan, cols["pitch_deg"])
        runs.append(Run(name=name, fs_hz=fs_hz, drive_v=cols["drive_v"], stroke_sensor_v=cols["stroke_sensor_v"],
                        pitch_sensor_v=cols["pitch_sensor_v"], stroke_deg=cols["stroke_deg"],
                        pitch_deg=cols["pitch_deg"]))
    return tuple(runs)


def _e(name: str, **params: object) -> tuple[str, dict]:
    return (name, dict(params))


def dataset_cases() -> tuple[DatasetCase, ...]:
    """Every case of the project's hidden-effect datasets."""
    S, P, N, O, C = "single", "pair", "null", "outside", "confusable"
    return (
        # each effect alone, two strengths, one at 3x noise
        DatasetCase("delay_60us_both", S, (_e("sensor_delay", delay_s=60e-6, channel="both"),), seed=1),
        DatasetCase("delay_200us_pitch_noisy", S, (_e("sensor_delay", delay_s=200e-6, channel="pitch"),),
                    noise_scale=3.0, seed=2),
        DatasetCase("highpass_3hz_both", S, (_e("charge_amp_highpass", corner_hz=3.0, channel="both"),), seed=3),
        DatasetCase("highpass_12hz_stroke_noisy", S, (_e("charge_amp_highpass", corner_hz=12.0, channel="stroke"),),
                    noise_scale=3.0, seed=4),
        DatasetCase("feedthrough_2mv", S, (_e("feedthrough", gain_v_per_v=0.002),), seed=5),
        DatasetCase("feedthrough_neg6mv_noisy", S, (_e("feedthrough", gain_v_per_v=-0.006),), noise_scale=3.0, seed=6),
        DatasetCase("transmission_0p2", S, (_e("transmission_nonlinearity", cubic_per_rad2=0.2),), seed=7),
        DatasetCase("transmission_neg0p5_noisy", S, (_e("transmission_nonlinearity", cubic_per_rad2=-0.5),),
                    noise_scale=3.0, seed=8),
        DatasetCase("hinge_0p5", S, (_e("hinge_stiffening", cubic_per_rad2=0.5),), seed=9),
        DatasetCase("hinge_3_noisy", S, (_e("hinge_stiffening", cubic_per_rad2=3.0),), noise_scale=3.0, seed=10),
        DatasetCase("structural_0p02", S, (_e("structural_damping", damping_ratio=0.02),), seed=11),
        DatasetCase("structural_0p08_noisy", S, (_e("structural_damping", damping_ratio=0.08),), noise_scale=3.0,
                    seed=12),
        DatasetCase("strain_loss_pitch_0p23", S, (_e("strain_transfer_loss", efficiency=0.23, channel="pitch"),),
                    seed=13, note="the paper's robot: pitch sensor 4.3x below the model"),
        DatasetCase("strain_loss_stroke_0p7_noisy", S, (_e("strain_transfer_loss", efficiency=0.7, channel="stroke"),),
                    noise_scale=3.0, seed=14),
        DatasetCase("collision_40deg_full_only", S, (_e("collision", stroke_limit_deg=40.0),), seed=15,
                    note="the stop is reached at full drive only"),
        DatasetCase("collision_25deg_noisy", S, (_e("collision", stroke_limit_deg=25.0),), noise_scale=3.0, seed=16),
        DatasetCase("wing_damage_0p9", S, hidden=(_e("wing_damage", inertia_factor=0.9),), seed=17,
                    note="a plant change reproduces it: nothing named, the plant refitted"),
        DatasetCase("wing_damage_0p75_noisy", S, hidden=(_e("wing_damage", inertia_factor=0.75),), noise_scale=3.0,
                    seed=18,
                    note="a plant change reproduces it: nothing named, the plant refitted"),
        # near the detection limit
        DatasetCase("delay_5us_both_weak", S, (_e("sensor_delay", delay_s=5e-6, channel="both"),), seed=61,
                    note="a tenth of a sample"),
        DatasetCase("structural_0p005_noisy_weak", S, (_e("structural_damping", damping_ratio=0.005),),
                    noise_scale=3.0, seed=62, below_limit=True,
                    note="below the truth's noise: the joint fit absorbs it into Gamma (+3 %); the sensors "
                         "still see a low-band gap, which is reported, nothing named"),
        DatasetCase("wing_damage_0p98_weak", S, hidden=(_e("wing_damage", inertia_factor=0.98),), seed=63),
        DatasetCase("collision_46deg_barely", S, (_e("collision", stroke_limit_deg=46.0),), seed=64,
                    note="2 degrees below the largest stroke, full drive only"),
        # pairs and more
        DatasetCase("pair_paper_robot_strain_delay", P, (_e("strain_transfer_loss", efficiency=0.23, channel="pitch"),
                                                         _e("sensor_delay", delay_s=250e-6, channel="both")), seed=65,
                    note="the demo's bench robot: the efficiency must be re-fitted once the shared delay joins it"),
        DatasetCase("pair_delay_structural", P, (_e("sensor_delay", delay_s=100e-6, channel="both"),
                                                 _e("structural_damping", damping_ratio=0.04)), seed=21),
        DatasetCase("pair_feedthrough_hinge", P, (_e("feedthrough", gain_v_per_v=0.003),
                                                  _e("hinge_stiffening", cubic_per_rad2=1.0)), seed=22),
        DatasetCase("pair_transmission_strainloss", P, (_e("transmission_nonlinearity", cubic_per_rad2=0.3),
                                                        _e("strain_transfer_loss", efficiency=0.4, channel="pitch")),
                    seed=23),
        DatasetCase("pair_delay_feedthrough_same_sensor", P, (_e("sensor_delay", delay_s=80e-6, channel="stroke"),
                                                              _e("feedthrough", gain_v_per_v=0.003)), seed=24,
                    note="two effects on the same sensor"),
        DatasetCase("pair_collision_highpass", P, (_e("collision", stroke_limit_deg=35.0),
                                                   _e("charge_amp_highpass", corner_hz=5.0, channel="both")), seed=25),
        DatasetCase("pair_structural_wing_damage", P, (_e("structural_damping", damping_ratio=0.04),),
                    hidden=(_e("wing_damage", inertia_factor=0.9),), seed=26,
                    note="two stroke-physics effects; wing_damage is not separable from the plant, structural "
                         "damping is (its ratio on the refitted plant: 0.04 / sqrt(0.9))"),
        DatasetCase("triple_robot", P, (_e("structural_damping", damping_ratio=0.03),
                                        _e("sensor_delay", delay_s=100e-6, channel="both"),
                                        _e("strain_transfer_loss", efficiency=0.23, channel="pitch")), seed=27),
        DatasetCase("four_effects", P, (_e("structural_damping", damping_ratio=0.03),
                                        _e("hinge_stiffening", cubic_per_rad2=0.5),
                                        _e("feedthrough", gain_v_per_v=0.002),
                                        _e("sensor_delay", delay_s=50e-6, channel="both")), seed=28),
        # null
        DatasetCase("null", N, seed=31),
        DatasetCase("null_noisy", N, noise_scale=3.0, seed=32),
        # outside the vocabulary
        DatasetCase("outside_gain_drift", O, outside="sensor_gain_drift", outside_strength=0.3, seed=41,
                    note="pitch sensor gain falls 30 % over the session"),
        DatasetCase("outside_second_resonance", O, outside="second_resonance", outside_strength=0.15, seed=42,
                    note="an extra stroke mode at 175 Hz"),
        DatasetCase("aero_x1p5_plus_delay", P, (_e("sensor_delay", delay_s=100e-6, channel="both"),),
                    plant_scale=(("aero_damping_nm_s2", 1.5),), seed=43,
                    note="aerodynamic damping x1.5 (plant drift, refitted) plus a sensor delay: only the delay "
                         "is named"),
        # confusable pairs, each member at a matched size
        DatasetCase("confusable_delay_40us", C, (_e("sensor_delay", delay_s=40e-6, channel="both"),), seed=51,
                    note="vs charge_amp_highpass: both sensor-only phase changes"),
        DatasetCase("confusable_highpass_5hz", C, (_e("charge_amp_highpass", corner_hz=5.0, channel="both"),), seed=52,
                    note="vs sensor_delay"),
        DatasetCase("confusable_delay_and_highpass", C, (_e("sensor_delay", delay_s=80e-6, channel="both"),
                                                         _e("charge_amp_highpass", corner_hz=6.0, channel="both")),
                    seed=53, note="both at once"),
        DatasetCase("confusable_hinge_1", C, (_e("hinge_stiffening", cubic_per_rad2=1.0),), seed=54,
                    note="vs transmission_nonlinearity: changes the pitch truth"),
        DatasetCase("confusable_transmission_0p3", C, (_e("transmission_nonlinearity", cubic_per_rad2=0.3),), seed=55,
                    note="vs hinge_stiffening: truth untouched, actuator sensor only"),
        DatasetCase("confusable_structural_0p04", C, (_e("structural_damping", damping_ratio=0.04),), seed=56,
                    note="vs aerodynamic damping: linear damping, one ratio at every drive level"),
        DatasetCase("confusable_hinge_and_transmission", C, (_e("hinge_stiffening", cubic_per_rad2=1.0),
                                                             _e("transmission_nonlinearity", cubic_per_rad2=0.3)),
                    seed=58, note="both at once"),
        DatasetCase("confusable_aero_damping_x1p6", C, outside="aero_damping", outside_strength=1.6, seed=57,
                    note="quadratic damping Gamma x1.6: beyond the plant fit's range (x1.5), must stay "
                         "unexplained with nothing named"),
        DatasetCase("confusable_aero_damping_x0p8", C, plant_scale=(("aero_damping_nm_s2", 0.8),), seed=59,
                    note="less quadratic damping: plant drift, Gamma refitted, no structural damping named"),
    )


# ------------------------------------------------------------------------------------ scoring


@dataclass(frozen=True)
class CaseOutcome:
    """How the workflow did on one case.

    Attributes
    ----------
    case : case name.
    true_label, found_label : confusion-table row and column.
    status, expected_status : reported and expected status.
    found : names of the found effects, sorted.
    parameter_errors : {effect.key: relative error} of the hidden effects' parameters.
    gap_reduction : {channel: 1 - model-error NRMSE after / before} on channels with a gap before.
    correct : name(s) and status right, parameters within 15 %, gap reduced by >= 50 % on every
        channel that had one (outside cases: status unexplained, exactly the hidden vocabulary
        effects found (usually none), the gap on the expected channel).
    problems : why it is not correct.
    elapsed_s : analysis time.
    """

    case: str
    true_label: str
    found_label: str
    status: str
    expected_status: str
    found: tuple
    parameter_errors: dict
    gap_reduction: dict
    correct: bool
    problems: tuple
    elapsed_s: float = math.nan

    def as_dict(self) -> dict:
        """JSON-ready outcome."""
        return {"case": self.case, "true": self.true_label, "found": self.found_label, "status": self.status,
                "expected_status": self.expected_status, "found_effects": list(self.found),
                "parameter_errors": self.parameter_errors, "gap_reduction": self.gap_reduction,
                "correct": self.correct, "problems": list(self.problems), "elapsed_s": self.elapsed_s}


def expected_column(true_label: str) -> str:
    """Confusion-table column of a right answer for a row label ('a+outside:x' -> 'a (gap left)';
    hidden 'plant:' effects are not named: 'a+plant:wing_damage' -> 'a'; 'below:a' -> 'none (gap left)').
    """
    parts = true_label.split("+")
    names = "+".join(p for p in parts if p != "none" and not p.startswith(("outside:", "plant:", "below:")))
    gap = any(p.startswith(("outside:", "below:")) for p in parts)
    return (names or "none") + (" (gap left)" if gap else "")


def found_label(result: DiscrepancyResult) -> str:
    """Confusion-table column: found effect names, 'none', and ' (gap left)' if unexplained."""
    names = "+".join(sorted(e.name for e in result.effects)) or "none"
    return names + (" (gap left)" if result.status == "unexplained" else "")


def _excess(nrmse: float, floor: float) -> float:
    return math.sqrt(max(nrmse**2 - floor**2, 0.0))


def _split(params: dict) -> bool:
    return bool(params) and all(isinstance(v, dict) for v in params.values())


def per_chain(params: dict) -> dict:
    """An effect's numeric parameters per sensor chain it acts on: {'': {...}} for an effect without
    a chain; {'stroke': {...}, 'pitch': {...}} for one value on both chains or one per chain.
    """
    if _split(params):
        return {side: {k: float(v) for k, v in p.items() if not isinstance(v, str)} for side, p in params.items()}
    values = {k: float(v) for k, v in params.items() if not isinstance(v, str)}
    channel = params.get("channel")
    if channel is None:
        return {"": values}
    return {side: dict(values) for side in (("stroke", "pitch") if channel == "both" else (channel,))}


def score_case(case: DatasetCase, result: DiscrepancyResult, elapsed_s: float = math.nan) -> CaseOutcome:
    """Judge a workflow result against the case's hidden truth."""
    problems = []
    found = tuple(sorted(e.name for e in result.effects))
    if result.status != case.expected_status:
        problems.append(f"status {result.status}, expected {case.expected_status}")
    errors: dict = {}
    reduction: dict = {}
    if found != case.expected_names:
        problems.append(f"found {list(found) or 'nothing'}, expected {list(case.expected_names) or 'nothing'}"
                        + (f" + outside:{case.outside}" if case.outside else ""))
    by_name = {e.name: e for e in result.effects}
    for name, params in case.effects:
        if name not in by_name:
            continue
        hidden, got_sides = per_chain(params), per_chain(by_name[name].parameters)
        if set(hidden) != set(got_sides):
            problems.append(f"{name} acts on {'+'.join(got_sides)}, hidden on {'+'.join(hidden)}")
            continue
        for side, values in hidden.items():
            for key, value in values.items():
                got = float(got_sides[side][key])
                rel = abs(got - value) / abs(value) if value else abs(got)
                label = f"{name}.{key}" + (f"[{side}]" if len(hidden) > 1 and _split(params) else "")
                errors[label] = max(rel, errors.get(label, 0.0))
                if rel > PARAMETER_TOLERANCE:
                    problems.append(f"{label} = {got:.4g}, hidden {value:.4g} ({rel:.0%} off)")
    if case.outside:
        gap_channels = {r["channel"] for r in result.remaining}
        if case.expected_gap_channel not in gap_channels:
            problems.append(f"no gap reported on {case.expected_gap_channel} (gaps: {sorted(gap_channels)})")
    elif case.below_limit:
        if not result.remaining:
            problems.append("no gap reported")
    elif case.effects:
        for c in CHANNELS:
            if not result.diagnosis_before.channels[c].has_gap:
                continue
            floor = result.diagnosis_before.channels[c].noise_nrmse
            before = _excess(result.gap_before[c], floor)
            after = _excess(result.gap_after[c], floor)
            reduction[c] = 1.0 - after / before if before > 0 else 0.0
            if reduction[c] < MIN_GAP_REDUCTION:
                problems.append(f"{c}: gap reduced by {reduction[c]:.0%} only")
    return CaseOutcome(case=case.name, true_label=case.true_label, found_label=found_label(result),
                       status=result.status, expected_status=case.expected_status, found=found,
                       parameter_errors=errors, gap_reduction=reduction, correct=not problems,
                       problems=tuple(problems), elapsed_s=elapsed_s)


def confusion_table(outcomes: Sequence[CaseOutcome]) -> dict:
    """{"rows": true labels, "columns": found labels, "counts": [[...]], "correct": k, "total": n}."""
    rows = sorted({o.true_label for o in outcomes})
    cols = sorted({o.found_label for o in outcomes})
    counts = [[sum(1 for o in outcomes if o.true_label == r and o.found_label == c) for c in cols] for r in rows]
    return {"rows": rows, "columns": cols, "counts": counts, "correct": sum(o.correct for o in outcomes),
            "total": len(outcomes)}


# ------------------------------------------------------------------ randomized off-nominal robots

FAMILIES = ("offnominal_null", "offnominal_single", "offnominal_pair", "offnominal_outside")
# Fabrication spread of the plant: natural frequencies within +-3 %, damping, gain and
# couplings within +-15 % of nominal.
FREQUENCY_SPREAD = 0.03
COEFFICIENT_SPREAD = 0.15
_FREQUENCIES = ("stroke_natural_frequency_hz", "pitch_natural_frequency_hz")
_COEFFICIENTS = ("aero_damping_nm_s2", "actuator_gain_nm_per_v", "hinge_damping_nm_s_per_rad",
                 "inertial_coupling_kg_m2", "aero_coupling_nm_s2")
_SEPARABLE = tuple(e.name for e in EFFECTS if e.separable)


def random_effect(name: str, rng: np.random.Generator) -> dict:
    """One effect at a random strength, from its draw ranges in the effect table (inside the range
    the run set can resolve).
    """
    entry = ENTRIES[name]
    side = str(rng.choice(["stroke", "pitch", "both"]))
    sign = float(rng.choice([-1.0, 1.0]))
    params: dict = {}
    for r in entry.draw:
        value = float(np.exp(rng.uniform(np.log(r.low), np.log(r.high)))) if r.log else float(rng.uniform(r.low, r.high))
        params[r.key] = sign * value if r.signed else value
    if entry.per_sensor:
        params["channel"] = side
    return params


def random_robot(family: str, draw: int) -> DatasetCase:
    """Draw `draw` of a family of off-nominal robots (deterministic in family and draw).

    Every robot's plant is off nominal (natural frequencies within +-3 %, damping, gain and
    couplings within +-15 %), its noise 1-2x the model's, its truth at the DAQ rate or at a
    2 kHz video rate (NaN between frames). Families: ``offnominal_null`` (no effect),
    ``offnominal_single`` (each vocabulary effect in turn, random strength; wing_damage is hidden,
    since a plant change reproduces it), ``offnominal_pair`` (two separable effects),
    ``offnominal_outside`` (physics outside the vocabulary: a drifting pitch-sensor gain or a
    second stroke resonance).
    """
    if family not in FAMILIES:
        raise KeyError(f"unknown family {family!r} (known: {', '.join(FAMILIES)})")
    rng = np.random.default_rng([FAMILIES.index(family), draw])
    scale = tuple((k, float(1.0 + rng.uniform(-FREQUENCY_SPREAD, FREQUENCY_SPREAD))) for k in _FREQUENCIES) + tuple(
        (k, float(1.0 + rng.uniform(-COEFFICIENT_SPREAD, COEFFICIENT_SPREAD))) for k in _COEFFICIENTS)
    noise = float(rng.uniform(1.0, 2.0))
    video = int(rng.choice([1, 10]))
    effects: tuple = ()
    hidden: tuple = ()
    outside, strength = "", 0.0
    names = list(EFFECT_NAMES_ORDER)
    if family == "offnominal_single":
        name = names[draw % len(names)]
        pair = (name, random_effect(name, rng))
        hidden, effects = ((pair,), ()) if name == "wing_damage" else ((), (pair,))
    elif family == "offnominal_pair":
        a, b = rng.choice(len(_SEPARABLE), size=2, replace=False)
        effects = tuple((n, random_effect(n, rng)) for n in (_SEPARABLE[a], _SEPARABLE[b]))
    elif family == "offnominal_outside":
        outside = ("sensor_gain_drift", "second_resonance")[draw % 2]
        strength = float(rng.uniform(0.2, 0.4) if outside == "sensor_gain_drift" else rng.uniform(0.1, 0.2))
    group = {"offnominal_null": "null", "offnominal_single": "single", "offnominal_pair": "pair",
             "offnominal_outside": "outside"}[family]
    return DatasetCase(f"{family}_{draw:03d}", group, effects, outside, strength, noise, seed=1000 * (1 + FAMILIES.index(family)) + draw,
                       plant_scale=scale, hidden=hidden, video_every=video)


EFFECT_NAMES_ORDER = _SEPARABLE + ("wing_damage",)


def true_plant(case: DatasetCase, model: Model) -> dict:
    """{plant key: true value} of the case's robot."""
    return {k: float(getattr(true_model(case, model).plant, k)) for k, _ in case.plant_scale}


def effective_plant(case: DatasetCase, model: Model) -> dict:
    """{fitted plant key: value} the identification must find for the case's robot.

    The true plant, with a hidden wing_damage (inertias x f) folded in: dividing both equations of
    motion by f, the natural frequencies become f_n / sqrt(f) and the damping, gain and coupling
    coefficients c / f, at the model's inertias.
    """
    plant = true_model(case, model).plant
    damage = float(dict(case.hidden).get("wing_damage", {}).get("inertia_factor", 1.0))
    return {k: float(getattr(plant, k)) / (math.sqrt(damage) if k.endswith("_natural_frequency_hz") else damage)
            for k in PLANT_PARAMETERS}
