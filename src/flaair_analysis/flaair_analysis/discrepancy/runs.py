"""Measured runs, their validation and their simulation (channels, initial state, sensor chain)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import cast

import numpy as np

from flaair_model.effects import SENSOR_CHANNELS, TRUTH_CHANNELS
from flaair_model.model import Model
from flaair_sim.core.plant import SimOutput, sensor_chain, simulate_batch_from
from flaair_sim.core.plant_params import P_GP, P_GS, coefficients
from flaair_sim.core.torque_response import torque_responses

from .vocabulary import CHANNELS, SENSOR_EFFECTS, SENSOR_SIDE

__all__ = [
    "DiscrepancyInputError",
    "Run",
    "check_runs",
    "initial_mechanical_state",
    "measured_motion",
    "mechanics_model",
    "sensor_voltage",
    "simulate_motion",
    "simulate_runs",
]

# Initial state from the truth: a cubic fitted to the first INITIAL_WINDOW_S of each angle (at
# least INITIAL_MIN_FRAMES finite samples, the window widened up to INITIAL_MAX_WINDOW_S for a
# video-rate truth). A numerical setting: a fraction of the shortest period of the model.
INITIAL_WINDOW_S = 1.0e-3
INITIAL_MAX_WINDOW_S = 2.5e-3
INITIAL_MIN_FRAMES = 8
INITIAL_MIN_Z = 5.0  # standard errors from rest before a measured initial state is used


class DiscrepancyInputError(ValueError):
    """Input the workflow cannot use; the message names the run and what is wrong."""


# --------------------------------------------------------------------------------------- runs


@dataclass(frozen=True, eq=False)
class Run:
    """One measured run, independent of its file format.

    Attributes
    ----------
    name : run name (file stem or bag run marker).
    fs_hz : sample rate.
    drive_v, stroke_sensor_v, pitch_sensor_v : (n,) finite records (sensor volts include V_HREF).
    stroke_deg, pitch_deg : (n,) ground-truth angles, NaN where the truth is missing.
    mechanical0 : (4,) [phi rad, phi' rad/s, psi rad, psi' rad/s] at sample 0, measured from the
        truth (`initial_mechanical_state`); None: at rest.
    """

    name: str
    fs_hz: float
    drive_v: np.ndarray
    stroke_sensor_v: np.ndarray
    pitch_sensor_v: np.ndarray
    stroke_deg: np.ndarray
    pitch_deg: np.ndarray
    mechanical0: np.ndarray | None = None

    @classmethod
    def from_columns(cls, name: str, fs_hz: float, columns: Mapping[str, np.ndarray]) -> Run:
        """A run from a measured run's columns (`drive_v`, the two sensors, the two angles)."""
        return cls(
            name=name,
            fs_hz=fs_hz,
            drive_v=columns["drive_v"],
            stroke_sensor_v=columns["stroke_sensor_v"],
            pitch_sensor_v=columns["pitch_sensor_v"],
            stroke_deg=columns["stroke_deg"],
            pitch_deg=columns["pitch_deg"],
        )

    def channel(self, name: str) -> np.ndarray:
        """Measured record of one of `CHANNELS`."""
        if name not in CHANNELS:
            raise KeyError(f"unknown channel {name!r} (known: {', '.join(CHANNELS)})")
        return cast(np.ndarray, getattr(self, name))

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.drive_v.shape[0])

    @property
    def drive_level_v(self) -> float:
        """Drive amplitude: the 99.5th percentile of |drive| (robust peak)."""
        return float(np.percentile(np.abs(self.drive_v), 99.5))


def check_runs(runs: Sequence[Run]) -> tuple[Run, ...]:  # noqa: C901  a check per way to be unusable
    """Validate runs for the workflow and return them with float64 arrays.

    Raises
    ------
    DiscrepancyInputError
        No runs, different sample rates, unequal lengths within a run, too short a run,
        non-finite drive or sensor samples, or a run without ground truth on a channel.
    """
    runs = tuple(runs)
    if not runs:
        raise DiscrepancyInputError("no runs given")
    names = [r.name for r in runs]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise DiscrepancyInputError(f"run names must be unique; repeated: {', '.join(duplicates)}")
    rates = sorted({float(r.fs_hz) for r in runs})
    if len(rates) > 1:
        detail = ", ".join(f"{r.name}: {float(r.fs_hz):g} Hz" for r in runs)
        raise DiscrepancyInputError(
            f"runs have different sample rates ({detail}); resample them to one rate first"
        )
    out = []
    for r in runs:
        fs = float(r.fs_hz)
        if not (math.isfinite(fs) and fs > 0):
            raise DiscrepancyInputError(
                f"run {r.name}: sample rate {r.fs_hz!r} is not a positive number"
            )
        arrays = {}
        n = -1  # the first column's length
        for name in ("drive_v", *CHANNELS):
            a = np.asarray(getattr(r, name), dtype=np.float64)
            if a.ndim != 1:
                raise DiscrepancyInputError(
                    f"run {r.name}: column {name} must be one-dimensional, got shape {a.shape}"
                )
            if n < 0:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise DiscrepancyInputError(
                    f"run {r.name}: column {name} has {a.shape[0]} samples, drive_v has {n}"
                )
            arrays[name] = a
        if n < int(0.05 * fs):
            raise DiscrepancyInputError(
                f"run {r.name}: only {n} samples ({n / fs:.3f} s); at least 0.05 s is needed"
            )
        for name in ("drive_v", *SENSOR_CHANNELS):
            bad = ~np.isfinite(arrays[name])
            if bad.any():
                raise DiscrepancyInputError(
                    f"run {r.name}: column {name} has non-finite samples "
                    f"(first at sample {int(np.argmax(bad))})"
                )
        for name in TRUTH_CHANNELS:
            finite = int(np.isfinite(arrays[name]).sum())
            if finite < max(16, n // 100):
                raise DiscrepancyInputError(
                    f"run {r.name}: ground truth {name} is missing ({finite} of {n} samples "
                    "finite); the workflow needs ground-truth angles to separate physics from "
                    "sensor effects"
                )
        if not np.any(arrays["drive_v"] != 0):
            raise DiscrepancyInputError(
                f"run {r.name}: drive_v is zero throughout; nothing excites the model"
            )
        x0 = initial_mechanical_state(arrays["stroke_deg"], arrays["pitch_deg"], fs)
        out.append(Run(str(r.name), fs, **arrays, mechanical0=x0))
    return tuple(out)


# -------------------------------------------------------------------------------- simulation


def _as_channels(out: SimOutput) -> dict[str, np.ndarray]:
    return {
        "stroke_deg": np.degrees(out.stroke_rad),
        "pitch_deg": np.degrees(out.pitch_rad),
        "stroke_sensor_v": out.stroke_sensor_v,
        "pitch_sensor_v": out.pitch_sensor_v,
    }


def initial_mechanical_state(
    stroke_deg: np.ndarray, pitch_deg: np.ndarray, fs_hz: float
) -> np.ndarray:
    """[phi, phi', psi, psi'] at sample 0 (rad, rad/s) from the first ground-truth samples.

    A cubic in time is fitted (least squares) to each angle's finite samples in the first
    `INITIAL_WINDOW_S` (widened up to `INITIAL_MAX_WINDOW_S` until `INITIAL_MIN_FRAMES` are finite);
    its value and slope at t = 0 are the state. Where too few frames exist, or neither differs from
    zero by `INITIAL_MIN_Z` standard errors, that angle starts at rest. A run that starts while the
    wing still moves (back-to-back runs) is then simulated from where the wing is, not from rest.
    """
    x0 = np.zeros(4)
    for k, angle in enumerate((stroke_deg, pitch_deg)):
        window = INITIAL_WINDOW_S
        while True:
            n = max(4, round(window * fs_hz))
            seg = np.asarray(angle[:n], float)
            ok = np.isfinite(seg)
            if ok.sum() >= INITIAL_MIN_FRAMES or window >= INITIAL_MAX_WINDOW_S or n >= len(angle):
                break
            window = min(2.0 * window, INITIAL_MAX_WINDOW_S)
        if ok.sum() < INITIAL_MIN_FRAMES:
            continue
        t = np.flatnonzero(ok) / fs_hz
        coef, cov = np.polyfit(t, np.radians(seg[ok]), 3, cov="unscaled")
        resid = np.radians(seg[ok]) - np.polyval(coef, t)
        s2 = float(np.dot(resid, resid)) / max(ok.sum() - 4, 1)
        se = np.sqrt(np.abs(np.diag(cov)) * s2)
        # a state indistinguishable from rest (tracking noise) is rest: no invented transient
        if abs(coef[3]) > INITIAL_MIN_Z * se[3] or abs(coef[2]) > INITIAL_MIN_Z * se[2]:
            x0[2 * k] = coef[3]
            x0[2 * k + 1] = coef[2]
    return x0


def _x0(run: Run) -> np.ndarray:
    return np.zeros(4) if run.mechanical0 is None else run.mechanical0


def simulate_motion(models: Sequence[Model], run: Run) -> SimOutput:
    """Every model over the run's drive from the run's measured initial state ((m, n) arrays)."""
    return simulate_batch_from(run.drive_v, run.fs_hz, list(models), _x0(run))


def torque_changes(
    model: Model, run: Run, equation: str, torque_nm: np.ndarray, angle: str
) -> np.ndarray:
    """(n, m) change of the run's `angle` ('stroke' or 'pitch', rad) made by each column of a
    small torque (N m) added to `equation`, to first order about the model's motion from the
    run's initial state (`flaair_sim.core.torque_response`).
    """
    return torque_responses(model, run.drive_v, run.fs_hz, _x0(run), equation, torque_nm, angle)


def simulate_runs(
    models: Sequence[Model], runs: Sequence[Run]
) -> list[list[dict[str, np.ndarray]]]:
    """Simulate each model with each run's drive from the run's initial state (no noise).

    Returns
    -------
    list
        ``sims[i][j]``: channel -> (n_j,) record of model i on run j (degrees and volts).
    """
    models = list(models)
    per_run = [_as_channels(simulate_motion(models, run)) for run in runs]
    return [
        [{c: per_run[j][c][i] for c in CHANNELS} for j in range(len(runs))]
        for i in range(len(models))
    ]


def sensor_gain_v_per_deg(model: Model, channel: str) -> float:
    """Model's sensor voltage per degree of its truth angle (nominal gain x strain transfer,
    as the plant's parameter vector resolves it).
    """
    p = coefficients(model)
    return math.radians(1.0) * float(p[P_GS] if SENSOR_SIDE[channel] == "stroke" else p[P_GP])


def mechanics_model(model: Model) -> Model:
    """`model` without its sensor effects and sensor terms: the part that sets the motion."""
    return replace(
        model,
        effects=tuple((n, e) for n, e in model.effects if n not in SENSOR_EFFECTS),
        discovered=tuple(t for t in model.discovered if t.acts_on not in SENSOR_CHANNELS),
    )


def sensor_voltage(
    model: Model,
    fs_hz: float,
    stroke_rad: np.ndarray,
    pitch_rad: np.ndarray,
    drive_v: np.ndarray,
    side: str,
) -> np.ndarray:
    """Charge-amplifier output of one sensor ('stroke' or 'pitch') for a given motion.

    The plant's own sensor chain (`flaair_sim.core.plant.sensor_chain`): used to try sensor effects
    without integrating the dynamics again; equal to `simulate` to rounding (tested).
    """
    vs, vp = sensor_chain(model, fs_hz, stroke_rad, pitch_rad, drive_v)
    return vs if side == "stroke" else vp


class MotionCache:
    """Simulated motion (stroke, pitch in rad) per (mechanics
    model, run), least recently used first out.
    """

    def __init__(self, size: int = 24) -> None:
        self.size = size
        self.data: dict[tuple[Model, int], tuple[np.ndarray, np.ndarray]] = {}

    def get(
        self, models: Sequence[Model], runs: Sequence[Run], run_ids: Sequence[int]
    ) -> dict[tuple[Model, int], tuple[np.ndarray, np.ndarray]]:
        """{(mechanics model, run id): (stroke_rad, pitch_rad)} for every model and run."""
        mechs = list(dict.fromkeys(mechanics_model(m) for m in models))
        out: dict[tuple[Model, int], tuple[np.ndarray, np.ndarray]] = {}
        for j in run_ids:
            missing = [m for m in mechs if (m, j) not in self.data]
            if missing:
                sim = simulate_motion(missing, runs[j])
                rows = [(sim.stroke_rad[i], sim.pitch_rad[i]) for i in range(len(missing))]
                for m, row in zip(missing, rows, strict=True):
                    self.data[(m, j)] = row
            for m in mechs:
                out[(m, j)] = self.data.pop((m, j))
                self.data[(m, j)] = out[(m, j)]
        while len(self.data) > self.size:
            self.data.pop(next(iter(self.data)))
        return out


def measured_motion(
    run: Run, stroke_rad: np.ndarray, pitch_rad: np.ndarray, side: str
) -> tuple[np.ndarray, np.ndarray]:
    """Model motion with one angle replaced by the
    measured one (gaps: model + interpolated error).
    """
    truth = run.stroke_deg if side == "stroke" else run.pitch_deg
    sim = stroke_rad if side == "stroke" else pitch_rad
    err = np.radians(truth) - sim
    ok = np.isfinite(err)
    if not ok.all():
        err = np.interp(np.arange(err.size), np.flatnonzero(ok), err[ok])
    return (sim + err, pitch_rad) if side == "stroke" else (stroke_rad, sim + err)
