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

The cases are a table, `cases.yaml` (package data beside this module). The randomized
off-nominal robots are `offnominal`'s. This module only builds data (it reads no other file).
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache
from importlib.resources import files
from typing import Any, cast

import numpy as np
import yaml
from scipy import signal

from flaair_model.model import Model, with_effects
from flaair_sim.core.drive import chirp, stepped_sine, stepped_sine_frequencies_hz
from flaair_sim.core.measured_run import synthesize_measured_run

from .case import DatasetCase
from .runs import Run

__all__ = [
    "CASES_FILE",
    "FS_HZ",
    "FULL_DRIVE_V",
    "OUTSIDE_KINDS",
    "dataset_cases",
    "make_run",
    "make_runs",
    "run_set_drives",
    "true_model",
]

FS_HZ = 20_000.0
FULL_DRIVE_V = 100.0
OUTSIDE_KINDS = ("aero_damping", "sensor_gain_drift", "second_resonance")
CASES_FILE = "cases.yaml"  # the table of cases, package data beside this module


def run_set_drives(
    fs_hz: float = FS_HZ, amplitude_v: float = FULL_DRIVE_V
) -> tuple[tuple[str, np.ndarray], ...]:
    """The standard run set: (name, drive_v) of chirp_full, chirp_half and stepped."""
    t = np.arange(round(1.0 * fs_hz)) / fs_hz
    full = chirp(t, amplitude_v, 20.0, 200.0, 1.0)
    half = chirp(t, 0.5 * amplitude_v, 20.0, 200.0, 1.0)
    stepped, _ = stepped_sine(
        fs_hz, amplitude_v, stepped_sine_frequencies_hz(60.0, 200.0, 10.0).tolist(), 0.2
    )
    return (("chirp_full", full), ("chirp_half", half), ("stepped", np.asarray(stepped)))


def true_model(case: DatasetCase, model: Model) -> Model:
    """The true robot's model (vocabulary effects and the aerodynamic-damping change)."""
    effects = dict(case.effects) | dict(case.hidden)
    m = with_effects(model, effects) if effects else model
    if case.plant_scale:
        m = replace(
            m, plant=replace(m.plant, **{k: getattr(m.plant, k) * f for k, f in case.plant_scale})
        )
    if case.outside == "aero_damping":
        m = replace(
            m,
            plant=replace(
                m.plant, aero_damping_nm_s2=m.plant.aero_damping_nm_s2 * case.outside_strength
            ),
        )
    if case.terms:
        m = replace(m, discovered=tuple(case.terms))
    if case.noise_scale != 1.0:
        m = replace(
            m,
            noise=replace(
                m.noise,
                sensor_noise_v_rms=m.noise.sensor_noise_v_rms * case.noise_scale,
                tracking_noise_deg_rms=m.noise.tracking_noise_deg_rms * case.noise_scale,
            ),
        )
    return m


def _second_mode_deg(
    drive_v: np.ndarray,
    fs_hz: float,
    model: Model,
    strength: float,
    f_hz: float = 175.0,
    zeta: float = 0.03,
) -> np.ndarray:
    """Stroke of an extra mode at f_hz: strength x (G_a / K) static gain, in degrees."""
    w = 2.0 * math.pi * f_hz
    static = model.plant.actuator_gain_nm_per_v / model.plant.stroke_stiffness_nm_per_rad
    b, a = signal.bilinear([strength * static * w * w], [1.0, 2.0 * zeta * w, w * w], fs=fs_hz)
    return cast(np.ndarray, np.degrees(signal.lfilter(b, a, drive_v)))


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
            cols["stroke_sensor_v"] = (
                cols["stroke_sensor_v"] + math.radians(1.0) * model.stroke_volts_per_rad * extra
            )
        t0 += n
        runs.append(_as_run(case, name, fs_hz, cols))
    return tuple(runs)


def make_run(
    case: DatasetCase, model: Model, name: str, drive_v: np.ndarray, seed: int, fs_hz: float = FS_HZ
) -> Run:
    """One more measured run of the case's robot (noise from `seed`, truth at its video rate), as
    `make_runs` makes each: an experiment beside the standard set.

    Raises
    ------
    ValueError
        The case's physics is outside the model (`case.outside`): the run would lack it.
    """
    if case.outside and case.outside != "aero_damping":
        raise ValueError(f"case {case.name}: its {case.outside} is added to the standard runs only")
    cols = synthesize_measured_run(
        np.asarray(drive_v, float), fs_hz, true_model(case, model), np.random.default_rng(seed)
    )
    return _as_run(case, name, fs_hz, cols)


def _as_run(case: DatasetCase, name: str, fs_hz: float, cols: dict[str, np.ndarray]) -> Run:
    """A synthesized run's columns as a `Run`, its truth thinned to the case's video rate."""
    if case.video_every > 1:
        lost = np.arange(cols["drive_v"].size) % case.video_every != 0
        cols["stroke_deg"] = np.where(lost, np.nan, cols["stroke_deg"])
        cols["pitch_deg"] = np.where(lost, np.nan, cols["pitch_deg"])
    return Run.from_columns(name, fs_hz, cols)


@cache
def dataset_cases() -> tuple[DatasetCase, ...]:
    """Every case of the project's hidden-effect datasets (the table `cases.yaml`, beside this
    module).
    """
    rows = yaml.safe_load(files(__package__).joinpath(CASES_FILE).read_text(encoding="utf-8"))
    return tuple(_case(row) for row in rows)


def _case(row: dict[str, Any]) -> DatasetCase:
    """One row of the table as a DatasetCase (effects as ((name, params), ...))."""
    fields = dict(row)
    for key in ("effects", "hidden"):
        if key in fields:
            fields[key] = tuple((name, dict(p)) for e in fields[key] for name, p in e.items())
    if "plant_scale" in fields:
        fields["plant_scale"] = tuple(fields["plant_scale"].items())
    return DatasetCase(**fields)
