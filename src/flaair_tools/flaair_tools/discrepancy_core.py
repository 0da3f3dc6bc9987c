"""Model-vs-measurement discrepancy workflow: the pure core (numpy, scipy, numba via flaair_sim).

Given measured runs (drive, both sensor voltages, ground-truth angles) and a model, the core

1. simulates the model with each run's recorded drive and compares all four channels
   (``stroke_deg``, ``pitch_deg``, ``stroke_sensor_v``, ``pitch_sensor_v``);
2. localises the disagreement (`diagnose`): channel, frequency band, drive level (full vs half
   drive error ratio), harmonics, worst stretch of time, residual whiteness (Ljung-Box on the
   decimated residual) and cross-correlation with the drive (a residual correlated with the
   drive means a mis-modelled input path; a white, uncorrelated one is noise);
3. names the missing effects (`find_effects`): every vocabulary effect that can act on a channel
   is fitted by nonlinear least squares (`scipy.optimize.least_squares`, Jacobian by finite
   differences computed with `simulate_batch`), run by run; its evidence is judged on held-out
   runs; accepted effects are added greedily until nothing significant is left;
4. returns the input model with the found effects added, the gap before and after (per-channel
   NRMSE on held-out runs) and an honest status.

Signal path and order of analysis
---------------------------------
The four measured channels sit on a directed signal path, and each channel is analysed in turn,
upstream first, with only the effects that can act on it (`EFFECT_CHANNELS`)::

    drive -> stroke dynamics -> stroke_deg  (truth)   candidates: structural_damping, collision, wing_damage
    stroke -> pitch dynamics -> pitch_deg   (truth)   candidates: hinge_stiffening (and the stroke
                                                       physics, in case only the pitch truth shows it)
    stroke -> actuator sensor -> stroke_sensor_v      candidates: sensor_delay, charge_amp_highpass,
                                                       feedthrough, transmission_nonlinearity,
                                                       strain_transfer_loss (channel stroke)
    pitch  -> hinge sensor    -> pitch_sensor_v       candidates: sensor_delay, charge_amp_highpass,
                                                       strain_transfer_loss (channel pitch)

The ground-truth channels separate physics from sensor effects: sensor effects cannot change
``stroke_deg``/``pitch_deg``, so physics effects are judged on the truth channels alone (where an
unmodelled sensor effect cannot bias them), sensor effects on the sensor channels with the
physics already corrected. When a truth channel keeps an unexplained gap, the sensor channel
below it is judged *truth-referenced*: the sensor model is driven by the measured angle (model
angle + interpolated measured-minus-model error) instead of the simulated one, so a propagated
physics error is not blamed on the sensor; the pitch truth below an unexplained stroke gap is
not analysed (its gap is reported as possibly propagated). On the second sensor, the sensor
effects found on the first are tried first on both sensors at the same values (no new
parameter); a sensor effect found on both sensors with consistent parameters becomes one effect
with ``channel: both``. Sensor effects are tried without re-integrating the dynamics: the motion
is simulated once and `sensor_voltage` (the plant's sensor chain in numpy) does the rest.

Decision rules (`Settings`, all documented constants)
-----------------------------------------------------
A channel *has a gap* when its residual RMS exceeds the noise estimate by more than
``gap_noise_ratio`` (noise from the median absolute second difference of the residual, which a
smooth model error barely touches) AND the decimated residual is not white (Ljung-Box p below
``whiteness_alpha``). Status ``no_discrepancy``: no channel has a gap with the input model.

Each candidate effect is fitted on each run alone (per-run estimates theta_r with standard
errors; a coarse grid, then least squares); the all-run estimate is their inverse-variance mean;
each run is predicted with the inverse-variance mean of the *other* runs' estimates
(leave-one-run-out; a single run is split into two halves). It is accepted only if ALL of:

* R1 held-out: the channel's model error above noise (pooled held-out RSS minus the noise's
  share, as an NRMSE) drops by more than ``min_heldout_drop``;
* R2 evidence: held-out Delta-BIC < ``max_delta_bic`` (BIC = sum over runs of
  n ln(RSS/n) + k ln N, Gaussian errors of unknown variance, on the held-out residuals);
* R3 significance: the all-run parameter is more than ``min_z`` standard errors from its null
  value (collision: the limit more than ``min_z`` SE below the largest stroke the model reaches)
  and inside its search range (an estimate stuck at a bound other than the null value is not a
  fit);
* R4 consistency: the per-run estimates agree (chi-square of their scatter about the mean, with
  each variance widened by (``consistency_rel_tol`` x effect size)^2, has p >= ``consistency_alpha``).
  Runs differ in drive level (full and half chirp) and in time, so an effect whose parameter
  would have to change with the drive level or over time (an effect outside the vocabulary that
  a vocabulary effect only mimics) is refused here;
* R5 (a sensor effect already found on the other sensor, extended to both): the two sensors'
  estimates agree within 3 combined standard errors + the R4 allowance;
* R6 (stroke physics judged on pitch_deg): stroke_deg keeps no gap with the effect added.

Among the passing candidates the lowest held-out BIC wins; the loop repeats on the channel (the
effects found there re-fitted jointly) until no gap is left, no candidate passes, or
``max_effects_per_channel`` is reached. If a gap is left, pairs of candidates are fitted jointly
(effects that mask each other, like a delay and a high-pass); a pair that passes every rule and
predicts the held-out runs better replaces the greedy choice.

Structural vs aerodynamic damping: a larger quadratic aerodynamic damping Gamma than the model's
is *not* the vocabulary's ``structural_damping`` (linear in velocity). A viscous damping ratio
fitted to it must shrink at half drive (the quadratic term's equivalent viscous damping scales
with stroke amplitude), so R4 refuses it and the case is reported ``unexplained`` at the stroke
channel near resonance, naming the refused damping ratio of each run (e.g. 0.083 at full drive,
0.058 at half drive for Gamma x1.6).

Status ``explained``: effects were added and no channel has a gap left (in-sample, final model);
``unexplained``: a gap remains (its channel, band, drive level and time stretch are reported).
``gap_before``/``gap_after`` are NRMSE per channel on held-out runs (after: effect parameters
re-fitted without the run they predict).

Effects already in the input model are kept as they are and are not offered as candidates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Mapping, Optional, Sequence

import numpy as np
from scipy import optimize, signal, stats

from flaair_sensors.characterization import frequency_track_from_drive
from flaair_model.model import Model, ModelError, with_effects
from flaair_sim.plant import SimOutput, simulate, simulate_batch

__all__ = [
    "CHANNELS",
    "TRUTH_CHANNELS",
    "SENSOR_CHANNELS",
    "SENSOR_EFFECTS",
    "mechanics_model",
    "measured_motion",
    "sensor_voltage",
    "EFFECT_CHANNELS",
    "STATUSES",
    "DiscrepancyInputError",
    "Run",
    "Settings",
    "EffectSpec",
    "candidate_specs",
    "ChannelGap",
    "Diagnosis",
    "FoundEffect",
    "CandidateEvidence",
    "DiscrepancyResult",
    "check_runs",
    "simulate_runs",
    "noise_estimates",
    "nrmse_by_channel",
    "diagnose",
    "find_effects",
    "analyse",
    "bode_points",
]

CHANNELS: tuple[str, ...] = ("stroke_deg", "pitch_deg", "stroke_sensor_v", "pitch_sensor_v")
TRUTH_CHANNELS: tuple[str, ...] = ("stroke_deg", "pitch_deg")
SENSOR_CHANNELS: tuple[str, ...] = ("stroke_sensor_v", "pitch_sensor_v")
STATUSES: tuple[str, ...] = ("no_discrepancy", "explained", "unexplained")

# Which measured channels each effect can possibly change (the model's structure).
EFFECT_CHANNELS: dict[str, tuple[str, ...]] = {
    "sensor_delay": SENSOR_CHANNELS,
    "charge_amp_highpass": SENSOR_CHANNELS,
    "feedthrough": ("stroke_sensor_v",),
    "transmission_nonlinearity": ("stroke_sensor_v",),
    "strain_transfer_loss": SENSOR_CHANNELS,
    "hinge_stiffening": ("pitch_deg", "pitch_sensor_v"),
    "structural_damping": CHANNELS,
    "collision": CHANNELS,
    "wing_damage": CHANNELS,
}
# Truth channel upstream of each sensor channel, and the model-channel name of the sensors.
_UPSTREAM_TRUTH = {"stroke_sensor_v": "stroke_deg", "pitch_sensor_v": "pitch_deg"}
_SENSOR_SIDE = {"stroke_sensor_v": "stroke", "pitch_sensor_v": "pitch"}


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
    """

    name: str
    fs_hz: float
    drive_v: np.ndarray
    stroke_sensor_v: np.ndarray
    pitch_sensor_v: np.ndarray
    stroke_deg: np.ndarray
    pitch_deg: np.ndarray

    def channel(self, name: str) -> np.ndarray:
        """Measured record of one of `CHANNELS`."""
        if name not in CHANNELS:
            raise KeyError(f"unknown channel {name!r} (known: {', '.join(CHANNELS)})")
        return getattr(self, name)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.drive_v.shape[0])

    @property
    def drive_level_v(self) -> float:
        """Drive amplitude: the 99.5th percentile of |drive| (robust peak)."""
        return float(np.percentile(np.abs(self.drive_v), 99.5))


def check_runs(runs: Sequence[Run]) -> tuple[Run, ...]:
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
        raise DiscrepancyInputError(f"runs have different sample rates ({detail}); resample them to one rate first")
    out = []
    for r in runs:
        fs = float(r.fs_hz)
        if not (math.isfinite(fs) and fs > 0):
            raise DiscrepancyInputError(f"run {r.name}: sample rate {r.fs_hz!r} is not a positive number")
        arrays = {}
        n = None
        for name in ("drive_v",) + CHANNELS:
            a = np.asarray(getattr(r, name), dtype=np.float64)
            if a.ndim != 1:
                raise DiscrepancyInputError(f"run {r.name}: column {name} must be one-dimensional, got shape {a.shape}")
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise DiscrepancyInputError(f"run {r.name}: column {name} has {a.shape[0]} samples, drive_v has {n}")
            arrays[name] = a
        if n < int(0.05 * fs):
            raise DiscrepancyInputError(f"run {r.name}: only {n} samples ({n / fs:.3f} s); at least 0.05 s is needed")
        for name in ("drive_v",) + SENSOR_CHANNELS:
            bad = ~np.isfinite(arrays[name])
            if bad.any():
                raise DiscrepancyInputError(f"run {r.name}: column {name} has non-finite samples (first at sample {int(np.argmax(bad))})")
        for name in TRUTH_CHANNELS:
            finite = int(np.isfinite(arrays[name]).sum())
            if finite < max(16, n // 100):
                raise DiscrepancyInputError(
                    f"run {r.name}: ground truth {name} is missing ({finite} of {n} samples finite); "
                    "the workflow needs ground-truth angles to separate physics from sensor effects")
        if not np.any(arrays["drive_v"] != 0):
            raise DiscrepancyInputError(f"run {r.name}: drive_v is zero throughout; nothing excites the model")
        out.append(Run(str(r.name), fs, **arrays))
    return tuple(out)


# ----------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class Settings:
    """Decision rules and numerical settings (see the module docstring for the rules).

    Attributes
    ----------
    decimate : keep every k-th sample in fits (noise stays white; 20 kHz -> 5 kHz).
    gap_noise_ratio : residual RMS / noise RMS above which a channel may have a gap.
    whiteness_alpha : Ljung-Box p-value below which the residual is not white.
    ljung_box_lags : lags of the Ljung-Box test.
    whiteness_decimate : decimation of the residual before the Ljung-Box test.
    min_heldout_drop : R1, relative drop of the held-out model error (above noise) an effect must bring.
    max_delta_bic : R2, held-out Delta-BIC must be below this.
    min_z : R3, distance of the parameter from its null value in standard errors.
    consistency_alpha : R4, p-value of the per-run scatter test below which an effect is refused.
    consistency_rel_tol : R4, allowance for model imperfection, as a fraction of the effect size.
    max_effects_per_channel : greedy steps per channel.
    pair_fallback : try pairs of effects on a channel when no single effect passes.
    max_nfev : function evaluations per least-squares fit.
    band_edges_hz : drive-frequency bands of the localisation.
    window_s : window of the harmonic and worst-stretch analysis.
    xcorr_max_lag_s : largest residual-after-drive lag of the cross-correlation test.
    xcorr_z : |rho| sqrt(n) above which the cross-correlation with the drive is significant.
    """

    decimate: int = 4
    gap_noise_ratio: float = 1.05
    whiteness_alpha: float = 1e-4
    ljung_box_lags: int = 20
    whiteness_decimate: int = 10
    min_heldout_drop: float = 0.20
    max_delta_bic: float = -10.0
    min_z: float = 5.0
    consistency_alpha: float = 1e-3
    consistency_rel_tol: float = 0.05
    max_effects_per_channel: int = 3
    pair_fallback: bool = True
    max_nfev: int = 40
    band_edges_hz: tuple[float, ...] = (0.0, 40.0, 60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 180.0, 200.0, 1e9)
    window_s: float = 0.05
    xcorr_max_lag_s: float = 0.005
    xcorr_z: float = 5.0


# ------------------------------------------------------------------------------ effect specs


@dataclass(frozen=True)
class EffectSpec:
    """One fittable effect parameter on one measured channel.

    Attributes
    ----------
    name : effect name (model vocabulary).
    key : the fitted parameter's key in the model file.
    judged_on : measured channel the effect is judged on.
    null : parameter value at which the effect does nothing (inf: collision, no contact).
    lower, upper : bounds of the fit.
    grid : starting values tried before the local fit (empty: start at the null value; the
        residual of feedthrough, transmission_nonlinearity and strain_transfer_loss is affine
        in the parameter, so the first Gauss-Newton step is exact).
    step : finite-difference step (in fit space).
    log : fit log(parameter) instead of the parameter.
    channel_param : value of the effect's `channel` parameter, if it has one.
    """

    name: str
    key: str
    judged_on: str
    null: float
    lower: float
    upper: float
    grid: tuple[float, ...]
    step: float
    log: bool = False
    channel_param: Optional[str] = None

    @property
    def label(self) -> str:
        """Name with its sensor channel, e.g. 'sensor_delay[pitch]'."""
        return f"{self.name}[{self.channel_param}]" if self.channel_param else self.name

    def to_fit(self, value: float) -> float:
        """Physical parameter -> fit-space value."""
        return math.log(value) if self.log else float(value)

    def from_fit(self, u: float) -> float:
        """Fit-space value -> physical parameter."""
        return math.exp(u) if self.log else float(u)

    def params(self, value: float, channel: Optional[str] = None) -> dict:
        """Effect parameter dict for the model."""
        p: dict = {self.key: float(value)}
        if self.channel_param is not None:
            p["channel"] = channel or self.channel_param
        return p

    def effect_size(self, value: float) -> float:
        """Distance of `value` from the null value (|value| for a null at infinity)."""
        return abs(value) if math.isinf(self.null) else abs(value - self.null)


def candidate_specs(channel: str) -> tuple[EffectSpec, ...]:
    """Vocabulary effects judged on `channel` (see the module docstring for the signal path)."""
    if channel == "stroke_deg":
        return (
            EffectSpec("structural_damping", "damping_ratio", channel, 0.0, 0.0, 1.0,
                       (0.0, 0.01, 0.03, 0.1, 0.3), 1e-4),
            EffectSpec("collision", "stroke_limit_deg", channel, math.inf, 1.0, 90.0,
                       tuple(np.arange(6.0, 62.0, 4.0)), 0.02),
            EffectSpec("wing_damage", "inertia_factor", channel, 1.0, 0.3, 1.0,
                       (0.5, 0.7, 0.85, 0.95, 1.0), 1e-4),
        )
    if channel == "pitch_deg":
        # stroke physics also drives the pitch; offered here in case only the pitch truth shows it
        # (rule R6: it must then leave stroke_deg without a gap)
        return (EffectSpec("hinge_stiffening", "cubic_per_rad2", channel, 0.0, -1.0, 50.0,
                           (-0.5, 0.0, 0.5, 2.0, 8.0, 32.0), 1e-3),) + tuple(
            replace(s, judged_on=channel) for s in candidate_specs("stroke_deg"))
    if channel in SENSOR_CHANNELS:
        side = _SENSOR_SIDE[channel]
        specs = [
            EffectSpec("sensor_delay", "delay_s", channel, 0.0, 0.0, 2e-3,
                       (0.0, 1e-4, 3e-4, 1e-3), 2e-7, channel_param=side),
            EffectSpec("charge_amp_highpass", "corner_hz", channel, 0.0, 0.05, 100.0,
                       tuple(np.geomspace(0.3, 100.0, 6)), 1e-3, log=True, channel_param=side),
        ]
        if channel == "stroke_sensor_v":
            specs += [
                EffectSpec("feedthrough", "gain_v_per_v", channel, 0.0, -0.05, 0.05,
                           (), 1e-5),
                EffectSpec("transmission_nonlinearity", "cubic_per_rad2", channel, 0.0, -3.0, 3.0,
                           (), 1e-3),
            ]
        specs.append(EffectSpec("strain_transfer_loss", "efficiency", channel, 1.0, 0.01, 1.0,
                                (), 1e-4, channel_param=side))
        return tuple(specs)
    raise KeyError(f"unknown channel {channel!r}")


# -------------------------------------------------------------------------------- simulation


def _as_channels(out: SimOutput) -> dict[str, np.ndarray]:
    return {
        "stroke_deg": np.degrees(out.stroke_rad),
        "pitch_deg": np.degrees(out.pitch_rad),
        "stroke_sensor_v": out.stroke_sensor_v,
        "pitch_sensor_v": out.pitch_sensor_v,
    }


def simulate_runs(models: Sequence[Model], runs: Sequence[Run]) -> list[list[dict[str, np.ndarray]]]:
    """Simulate each model with each run's drive (no noise).

    Returns
    -------
    list
        ``sims[i][j]``: channel -> (n_j,) record of model i on run j (degrees and volts).
    """
    models = list(models)
    per_run = []
    for run in runs:
        if len(models) == 1:
            out = simulate(run.drive_v, run.fs_hz, models[0])
            per_run.append([_as_channels(SimOutput(*(a[None, :] for a in out)))])
        else:
            out = simulate_batch(run.drive_v, run.fs_hz, models)
            per_run.append([_as_channels(out)])
    sims = []
    for i in range(len(models)):
        sims.append([{c: per_run[j][0][c][i] if per_run[j][0][c].ndim == 2 else per_run[j][0][c]
                      for c in CHANNELS} for j in range(len(runs))])
    return sims


def _sensor_gain_v_per_deg(model: Model, channel: str) -> float:
    """Model's sensor voltage per degree of its truth angle (nominal gain x strain transfer)."""
    side = _SENSOR_SIDE[channel]
    gain = model.stroke_volts_per_rad if side == "stroke" else model.pitch_volts_per_rad
    loss = model.effect("strain_transfer_loss")
    if loss is not None and loss.channel in (side, "both"):
        gain *= loss.efficiency
    return math.radians(1.0) * gain


SENSOR_EFFECTS: tuple[str, ...] = ("sensor_delay", "charge_amp_highpass", "feedthrough", "transmission_nonlinearity",
                                   "strain_transfer_loss")


def mechanics_model(model: Model) -> Model:
    """`model` without its sensor effects: the part that sets the stroke and pitch motion."""
    return replace(model, effects=tuple((n, e) for n, e in model.effects if n not in SENSOR_EFFECTS))


def sensor_voltage(model: Model, fs_hz: float, stroke_rad: np.ndarray, pitch_rad: np.ndarray, drive_v: np.ndarray,
                   side: str) -> np.ndarray:
    """Charge-amplifier output of one sensor ('stroke' or 'pitch') from the motion, in numpy.

    The plant's sensor chain (flaair_sim.plant docstring), in its order: transduction (with
    transmission_nonlinearity and strain_transfer_loss), feedthrough (stroke), first-order
    bilinear high-pass (lfilter from rest), delay (whole samples + linear interpolation),
    + V_HREF. Used to try sensor effects without re-integrating the dynamics; equal to
    `simulate` to rounding (tested).
    """
    if side == "stroke":
        gain = model.stroke_volts_per_rad
        x = stroke_rad
        nl = model.effect("transmission_nonlinearity")
        if nl is not None:
            x = x + nl.cubic_per_rad2 * x * x * x
    else:
        gain = model.pitch_volts_per_rad
        x = pitch_rad
    loss = model.effect("strain_transfer_loss")
    if loss is not None and loss.channel in (side, "both"):
        gain *= loss.efficiency
    dev = gain * x
    feed = model.effect("feedthrough")
    if side == "stroke" and feed is not None:
        dev = dev + feed.gain_v_per_v * drive_v
    hp = model.effect("charge_amp_highpass")
    if hp is not None and hp.channel in (side, "both"):
        k = math.tan(math.pi * hp.corner_hz / fs_hz)  # bilinear with pre-warped corner (= scipy butter)
        b0 = 1.0 / (1.0 + k)
        dev = signal.lfilter([b0, -b0], [1.0, (k - 1.0) / (k + 1.0)], dev)
    delay = model.effect("sensor_delay")
    if delay is not None and delay.channel in (side, "both"):
        samples = delay.delay_s * fs_hz
        whole = math.floor(samples + 1e-9)
        frac = samples - whole
        frac = 0.0 if frac < 1e-9 else frac
        padded = np.concatenate([np.zeros(whole + 1), dev])
        n = dev.size
        dev = (1.0 - frac) * padded[1: n + 1] + frac * padded[:n] if frac else padded[1: n + 1]
    return model.sensors.reference_voltage_v + dev


class _MotionCache:
    """Simulated motion (stroke, pitch in rad) per (mechanics model, run), least recently used first out."""

    def __init__(self, size: int = 24) -> None:
        self.size = size
        self.data: dict = {}

    def get(self, models: Sequence[Model], runs: Sequence[Run], run_ids: Sequence[int]) -> dict:
        """{(mechanics model, run id): (stroke_rad, pitch_rad)} for every model and run."""
        mechs = list(dict.fromkeys(mechanics_model(m) for m in models))
        out = {}
        for j in run_ids:
            missing = [m for m in mechs if (m, j) not in self.data]
            if missing:
                if len(missing) == 1:
                    sim = simulate(runs[j].drive_v, runs[j].fs_hz, missing[0])
                    rows = [(sim.stroke_rad, sim.pitch_rad)]
                else:
                    sim = simulate_batch(runs[j].drive_v, runs[j].fs_hz, missing)
                    rows = [(sim.stroke_rad[i], sim.pitch_rad[i]) for i in range(len(missing))]
                for m, row in zip(missing, rows):
                    self.data[(m, j)] = row
            for m in mechs:
                out[(m, j)] = self.data.pop((m, j))
                self.data[(m, j)] = out[(m, j)]
        while len(self.data) > self.size:
            self.data.pop(next(iter(self.data)))
        return out


# ---------------------------------------------------------------------------- residual stats


def _demean(r: np.ndarray) -> np.ndarray:
    ok = np.isfinite(r)
    if ok.any():
        return r - np.mean(r[ok])
    return r


def measured_motion(run: Run, stroke_rad: np.ndarray, pitch_rad: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Model motion with one angle replaced by the measured one (gaps: model + interpolated error)."""
    truth = run.stroke_deg if side == "stroke" else run.pitch_deg
    sim = stroke_rad if side == "stroke" else pitch_rad
    err = np.radians(truth) - sim
    ok = np.isfinite(err)
    if not ok.all():
        err = np.interp(np.arange(err.size), np.flatnonzero(ok), err[ok])
    return (sim + err, pitch_rad) if side == "stroke" else (stroke_rad, sim + err)


def _residual(run: Run, sim: Mapping[str, np.ndarray], channel: str, model: Optional[Model] = None,
              truth_referenced: bool = False) -> np.ndarray:
    """Measured minus simulated record (mean removed); NaN where the measurement is missing.

    truth_referenced (sensor channels): the sensor is simulated with the *measured* angle as its
    input (`measured_motion`), so an error of the simulated angle is not counted against the
    sensor; NaN where the truth is missing.
    """
    if truth_referenced and channel in SENSOR_CHANNELS:
        side = _SENSOR_SIDE[channel]
        stroke, pitch = measured_motion(run, np.radians(sim["stroke_deg"]), np.radians(sim["pitch_deg"]), side)
        r = run.channel(channel) - sensor_voltage(model, run.fs_hz, stroke, pitch, run.drive_v, side)
        r = np.where(np.isfinite(run.channel(_UPSTREAM_TRUTH[channel])), r, np.nan)
    else:
        r = run.channel(channel) - sim[channel]
    return _demean(r)


def _signal_ss(run: Run, channel: str) -> tuple[float, int]:
    x = run.channel(channel)
    x = x[np.isfinite(x)]
    return float(np.sum((x - x.mean()) ** 2)), int(x.size)


def noise_estimates(runs: Sequence[Run], sims: Sequence[Mapping[str, np.ndarray]], model: Model) -> dict[str, float]:
    """Noise RMS of each channel from the residual's second differences (MAD, robust).

    A smooth model error hardly changes second differences at the sample rate (a 200 Hz error
    is scaled by (2 pi 200 / fs)^2 = 0.004 at 20 kHz), while white noise of RMS s gives second
    differences of RMS s sqrt(6). Where fewer than 64 triples of consecutive finite samples
    exist (ground truth at a low frame rate), the model's noise section is used instead.
    """
    spec = {"stroke_deg": model.noise.tracking_noise_deg_rms, "pitch_deg": model.noise.tracking_noise_deg_rms,
            "stroke_sensor_v": model.noise.sensor_noise_v_rms, "pitch_sensor_v": model.noise.sensor_noise_v_rms}
    out = {}
    for c in CHANNELS:
        parts = []
        for run, sim in zip(runs, sims):
            r = run.channel(c) - sim[c]
            d2 = r[2:] - 2.0 * r[1:-1] + r[:-2]
            parts.append(d2[np.isfinite(d2)])
        d2 = np.concatenate(parts) if parts else np.zeros(0)
        if d2.size >= 64:
            mad = float(np.median(np.abs(d2 - np.median(d2))))
            est = 1.4826 * mad / math.sqrt(6.0)
            out[c] = est if est > 0 else max(spec[c], 1e-12)
        else:
            out[c] = max(spec[c], 1e-12)
    return out


def _autocorr_sums(x: np.ndarray, lags: int) -> np.ndarray:
    """sum_t x[t] x[t+k] for k = 0..lags (FFT)."""
    n = x.size
    size = 1 << int(math.ceil(math.log2(max(2 * n, 2))))
    f = np.fft.rfft(x, size)
    return np.fft.irfft(f * np.conj(f), size)[: lags + 1]


def _ljung_box(r: np.ndarray, lags: int) -> tuple[float, float]:
    """Ljung-Box Q and p-value of a record with NaN gaps (pairs with a NaN are skipped)."""
    ok = np.isfinite(r)
    n = int(ok.sum())
    if n < 4 * lags:
        return math.nan, math.nan
    x = np.where(ok, r, 0.0)
    x[ok] -= x[ok].mean()
    var = float(np.dot(x, x)) / n
    if var <= 0:
        return 0.0, 1.0
    sums = _autocorr_sums(x, lags)
    pairs = np.round(_autocorr_sums(ok.astype(float), lags)).astype(np.int64)
    k = np.arange(1, lags + 1)
    m = pairs[1:]
    valid = m >= 8
    rho = np.where(valid, sums[1:] / np.maximum(m, 1) / var, 0.0)
    q = float(n * (n + 2) * np.sum(rho**2 / np.maximum(n - k, 1)))
    return q, float(stats.chi2.sf(q, lags))


def _xcorr_with_drive(r: np.ndarray, drive: np.ndarray, max_lag: int) -> tuple[float, int, int]:
    """Largest |normalised cross-correlation| of residual r(t) with drive(t - lag), lag 0..max_lag."""
    ok = np.isfinite(r)
    n = int(ok.sum())
    if n < 16:
        return 0.0, 0, n
    x = np.where(ok, r, 0.0)
    x[ok] -= x[ok].mean()
    d = np.where(ok, drive - drive.mean(), 0.0)
    den = math.sqrt(float(np.dot(x, x)) * float(np.dot(d, d)))
    if den <= 0:
        return 0.0, 0, n
    size = 1 << int(math.ceil(math.log2(2 * x.size)))
    cc = np.fft.irfft(np.fft.rfft(x, size) * np.conj(np.fft.rfft(d, size)), size)[: max_lag + 1] / den
    lag = int(np.argmax(np.abs(cc)))
    return float(cc[lag]), lag, n


# ------------------------------------------------------------------------------- diagnostics


@dataclass(frozen=True)
class ChannelGap:
    """Where and how one channel's model disagrees with the measurement.

    Attributes
    ----------
    channel : measured channel.
    nrmse : residual RMS / measured RMS, all runs pooled.
    noise_nrmse : noise RMS / measured RMS (the floor an exact model reaches).
    noise_ratio : residual RMS / noise RMS.
    model_error_nrmse : sqrt(max(residual^2 - noise^2, 0)) / measured RMS.
    ljung_box_q, ljung_box_p : whiteness test of the decimated residual.
    xcorr_drive : largest normalised cross-correlation of residual with the drive.
    xcorr_lag_s : its lag (residual after drive).
    xcorr_significant : |rho| sqrt(n) > Settings.xcorr_z.
    band_nrmse : {"lo-hi Hz": model-error NRMSE of the samples whose drive frequency is in the band}.
    worst_band_hz : band with the largest model-error NRMSE.
    level_nrmse : {drive level V: model-error NRMSE of the runs at that level}.
    level_ratio : model-error NRMSE at the highest over the lowest drive level (NaN: one level).
    harmonic_fraction : residual power fraction at drive harmonics 1..4 (rest: broadband).
    worst_stretch : (run, start s, stop s, model-error NRMSE) of the worst window.
    has_gap : the channel disagrees beyond noise (see module docstring).
    interpretation : one-line reading of the tests.
    """

    channel: str
    nrmse: float
    noise_nrmse: float
    noise_ratio: float
    model_error_nrmse: float
    ljung_box_q: float
    ljung_box_p: float
    xcorr_drive: float
    xcorr_lag_s: float
    xcorr_significant: bool
    band_nrmse: dict
    worst_band_hz: str
    level_nrmse: dict
    level_ratio: float
    harmonic_fraction: dict
    worst_stretch: tuple
    has_gap: bool
    interpretation: str


@dataclass(frozen=True)
class Diagnosis:
    """Gap of every channel for one model on a set of runs."""

    channels: dict  # channel -> ChannelGap
    noise: dict  # channel -> noise RMS

    @property
    def gaps(self) -> tuple[str, ...]:
        """Channels that have a gap."""
        return tuple(c for c in CHANNELS if self.channels[c].has_gap)


def _excess(rss: float, n: int, sigma: float, ss: float) -> float:
    if n == 0 or ss <= 0:
        return math.nan
    return math.sqrt(max(rss / n - sigma**2, 0.0)) / math.sqrt(ss / n)


def _harmonic_fractions(r: np.ndarray, phase: np.ndarray, win: int, orders: int = 4) -> dict:
    """Residual power at drive harmonics 1..orders over tiled windows (fractions of total)."""
    k = r.size // win
    if k == 0:
        return {}
    w = np.isfinite(r[: k * win]).reshape(k, win).astype(float)
    x = np.where(w > 0, r[: k * win].reshape(k, win), 0.0)
    total = float(np.sum(x * x))
    if total <= 0:
        return {}
    ph = phase[: k * win].reshape(k, win)
    cols = [np.ones_like(ph)]
    for h in range(1, orders + 1):
        cols += [np.cos(h * ph), np.sin(h * ph)]
    a = np.stack(cols, axis=-1)  # (k, win, 1 + 2 orders)
    aw = a * w[..., None]
    normal = np.einsum("kwi,kwj->kij", aw, a) + 1e-9 * np.eye(a.shape[-1])
    coef = np.linalg.solve(normal, np.einsum("kwi,kw->ki", aw, x)[..., None])[..., 0]
    fractions = {}
    for h in range(orders):
        sl = slice(1 + 2 * h, 3 + 2 * h)
        comp = np.einsum("kwi,ki->kw", a[..., sl], coef[:, sl]) * w
        fractions[str(h + 1)] = float(np.sum(comp * comp) / total)
    return fractions


def _drive_tracks(runs: Sequence[Run]) -> list[tuple[np.ndarray, np.ndarray]]:
    return [frequency_track_from_drive(r.drive_v, r.fs_hz) for r in runs]


def _level_groups(runs: Sequence[Run]) -> list[float]:
    """Drive level of each run rounded to 5 % so that equal nominal levels group together."""
    levels = [r.drive_level_v for r in runs]
    top = max(levels)
    return [round(lv / top * 20.0) / 20.0 * top for lv in levels]


def diagnose(
    runs: Sequence[Run],
    sims: Sequence[Mapping[str, np.ndarray]],
    model: Model,
    noise: Mapping[str, float],
    settings: Settings = Settings(),
    tracks: Optional[Sequence[tuple[np.ndarray, np.ndarray]]] = None,
) -> Diagnosis:
    """Localise the disagreement of `sims` (one per run) with the runs, channel by channel.

    Parameters
    ----------
    runs, sims
        Measured runs and the model's simulation of each.
    model
        The simulated model (sensor gains for truth-referenced residuals are not used here).
    noise
        Noise RMS per channel (`noise_estimates`).
    settings
        Thresholds.
    tracks
        Drive phase and frequency of each run (computed if not given).
    """
    tracks = list(tracks) if tracks is not None else _drive_tracks(runs)
    levels = _level_groups(runs)
    edges = settings.band_edges_hz
    win = max(8, int(round(settings.window_s * runs[0].fs_hz)))
    out = {}
    for c in CHANNELS:
        sigma = float(noise[c])
        res = [_residual(run, sim, c) for run, sim in zip(runs, sims)]
        ss_n = [_signal_ss(run, c) for run in runs]
        rss = sum(float(np.nansum(r**2)) for r in res)
        n = sum(int(np.isfinite(r).sum()) for r in res)
        ss = sum(s for s, _ in ss_n)
        nrmse = math.sqrt(rss / ss) if ss > 0 else math.nan
        noise_nrmse = sigma / math.sqrt(ss / n) if ss > 0 and n else math.nan
        excess = _excess(rss, n, sigma, ss)
        has_gap, ratio, q, p = _gap_test(res, sigma, settings)
        # cross-correlation with the drive (strongest run)
        max_lag = max(1, int(round(settings.xcorr_max_lag_s * runs[0].fs_hz / settings.decimate)))
        best = (0.0, 0, 0)
        for run, r in zip(runs, res):
            rho, lag, m = _xcorr_with_drive(r[:: settings.decimate], run.drive_v[:: settings.decimate], max_lag)
            if abs(rho) * math.sqrt(max(m, 1)) > abs(best[0]) * math.sqrt(max(best[2], 1)):
                best = (rho, lag, m)
        xsig = abs(best[0]) * math.sqrt(max(best[2], 1)) > settings.xcorr_z
        # frequency bands (drive instantaneous frequency)
        band = {}
        worst_band, worst_val = "", -1.0
        for lo, hi in zip(edges[:-1], edges[1:]):
            rss_b = n_b = 0
            ss_b = 0.0
            for run, r, (_, f) in zip(runs, res, tracks):
                sel = (f >= lo) & (f < hi) & np.isfinite(r)
                if sel.sum() < win:
                    continue
                x = run.channel(c)[sel]
                rss_b += float(np.sum(r[sel] ** 2))
                n_b += int(sel.sum())
                ss_b += float(np.sum((x - np.nanmean(run.channel(c))) ** 2))
            if n_b:
                label = f"{lo:g}-{hi:g}" if hi < 1e8 else f">{lo:g}"
                band[label] = _excess(rss_b, n_b, sigma, ss_b)
                if band[label] > worst_val:
                    worst_band, worst_val = label, band[label]
        # drive levels
        level_vals = {}
        for lv in sorted(set(levels)):
            idx = [i for i, l in enumerate(levels) if l == lv]
            rss_l = sum(float(np.nansum(res[i] ** 2)) for i in idx)
            n_l = sum(int(np.isfinite(res[i]).sum()) for i in idx)
            ss_l = sum(ss_n[i][0] for i in idx)
            level_vals[f"{lv:.3g}"] = _excess(rss_l, n_l, sigma, ss_l)
        if len(level_vals) > 1:
            keys = sorted(level_vals, key=float)
            lo_v, hi_v = level_vals[keys[0]], level_vals[keys[-1]]
            level_ratio = hi_v / lo_v if lo_v > 0 else (math.inf if hi_v > 0 else math.nan)
        else:
            level_ratio = math.nan
        # harmonics (all runs pooled, power-weighted)
        hp = np.zeros(4)
        total = 0.0
        for r, (phase, _) in zip(res, tracks):
            fr = _harmonic_fractions(r, phase, win)
            tot = float(np.nansum(r**2))
            for h in range(4):
                hp[h] += fr.get(str(h + 1), 0.0) * tot
            total += tot
        harmonics = {str(h + 1): float(hp[h] / total) if total > 0 else 0.0 for h in range(4)}
        # worst stretch
        worst = ("", math.nan, math.nan, -1.0)
        for run, r in zip(runs, res):
            k = r.size // win
            if k == 0:
                continue
            x = run.channel(c)
            blocks = r[: k * win].reshape(k, win)
            ok = np.isfinite(blocks)
            cnt = ok.sum(axis=1)
            ms = np.where(cnt > 0, np.nansum(blocks**2, axis=1) / np.maximum(cnt, 1), np.nan)
            sig_ms = np.nanvar(x[np.isfinite(x)]) if np.isfinite(x).any() else math.nan
            if not sig_ms > 0:
                continue
            ex = np.sqrt(np.maximum(ms - sigma**2, 0.0) / sig_ms)
            if np.all(np.isnan(ex)):
                continue
            j = int(np.nanargmax(ex))
            if ex[j] > worst[3]:
                worst = (run.name, j * win / run.fs_hz, (j + 1) * win / run.fs_hz, float(ex[j]))
        out[c] = ChannelGap(
            channel=c, nrmse=nrmse, noise_nrmse=noise_nrmse, noise_ratio=ratio, model_error_nrmse=excess,
            ljung_box_q=q, ljung_box_p=p, xcorr_drive=best[0],
            xcorr_lag_s=best[1] * settings.decimate / runs[0].fs_hz, xcorr_significant=bool(xsig),
            band_nrmse=band, worst_band_hz=worst_band, level_nrmse=level_vals, level_ratio=level_ratio,
            harmonic_fraction=harmonics, worst_stretch=worst, has_gap=has_gap,
            interpretation=_interpret(ratio, p, xsig, harmonics, level_ratio, has_gap, settings),
        )
    return Diagnosis(channels=out, noise=dict(noise))


def _interpret(ratio: float, p: float, xsig: bool, harmonics: Mapping[str, float], level_ratio: float,
               has_gap: bool, settings: Settings) -> str:
    if not has_gap:
        return "residual at noise level and white: the model explains this channel"
    parts = [f"residual {ratio:.2f}x noise, not white (Ljung-Box p={p:.1e})"]
    parts.append("correlated with the drive: a linear path from the drive is mis-modelled" if xsig
                 else "not linearly correlated with the drive: a nonlinear or time-varying path")
    if harmonics:
        higher = sum(v for k, v in harmonics.items() if k != "1")
        if higher > 0.05:
            parts.append(f"{higher:.0%} of it at drive harmonics 2-4 (a nonlinearity)")
    if math.isinf(level_ratio):
        parts.append("only at the highest drive level (an amplitude threshold, e.g. a stop)")
    elif level_ratio == 0:
        parts.append("only at the lower drive levels (none at full drive)")
    elif math.isfinite(level_ratio):
        if level_ratio > 1.5:
            parts.append(f"relative error {level_ratio:.2f}x larger at full drive (grows with amplitude)")
        elif level_ratio < 1 / 1.5:
            parts.append(f"relative error {1 / level_ratio:.2f}x larger at low drive (shrinks with amplitude)")
        else:
            parts.append("relative error about the same at every drive level (amplitude independent)")
    return "; ".join(parts)


def nrmse_by_channel(runs: Sequence[Run], sims: Sequence[Mapping[str, np.ndarray]]) -> dict[str, float]:
    """Residual RMS / measured RMS per channel, pooled over runs (means removed per run)."""
    out = {}
    for c in CHANNELS:
        rss = sum(float(np.nansum(_residual(run, sim, c) ** 2)) for run, sim in zip(runs, sims))
        ss = sum(_signal_ss(run, c)[0] for run in runs)
        out[c] = math.sqrt(rss / ss) if ss > 0 else math.nan
    return out


# ------------------------------------------------------------------------------------ fitting


@dataclass(frozen=True, eq=False)
class _Fold:
    """A run and the sample range judged in it (whole run, or half of a lone run)."""

    run: int
    start: int
    stop: int
    name: str


def _folds(runs: Sequence[Run]) -> tuple[_Fold, ...]:
    if len(runs) >= 2:
        return tuple(_Fold(i, 0, r.n, r.name) for i, r in enumerate(runs))
    r = runs[0]
    h = r.n // 2
    return (_Fold(0, 0, h, f"{r.name}[first half]"), _Fold(0, h, r.n, f"{r.name}[second half]"))


class _Problem:
    """Weighted residuals of one channel, for a family of models, on a set of folds.

    The weight (noise RMS; truth-referenced: sqrt(noise_V^2 + (g noise_deg)^2) with the gain g
    of `weight_model`) is fixed per problem so that costs of different models compare.
    """

    def __init__(self, runs: Sequence[Run], folds: Sequence[_Fold], channel: str, sigma: float,
                 truth_referenced: bool, decimate: int, truth_sigma: float = 0.0,
                 weight_model: Optional[Model] = None, motion: Optional[_MotionCache] = None) -> None:
        self.runs = runs
        self.motion = motion if motion is not None else _MotionCache()
        self._measured: dict = {}
        self.folds = list(folds)
        self.channel = channel
        self.truth_referenced = truth_referenced and channel in SENSOR_CHANNELS
        self.weight = sigma
        if self.truth_referenced:
            g = _sensor_gain_v_per_deg(weight_model, channel)
            self.weight = math.sqrt(sigma**2 + (g * truth_sigma) ** 2)
        self.run_ids = sorted({f.run for f in self.folds})
        self.idx = []
        for f in self.folds:
            sl = np.arange(f.start, f.stop, decimate)
            ok = np.isfinite(runs[f.run].channel(channel)[sl])
            if self.truth_referenced:
                ok &= np.isfinite(runs[f.run].channel(_UPSTREAM_TRUTH[channel])[sl])
            self.idx.append(sl[ok])

    def n_per_fold(self) -> list[int]:
        """Residual samples per fold."""
        return [int(i.size) for i in self.idx]

    def signal_ss(self) -> float:
        """Weighted sum of squares of the measured channel about its fold means."""
        total = 0.0
        for f, idx in zip(self.folds, self.idx):
            x = self.runs[f.run].channel(self.channel)[idx]
            total += float(np.sum(((x - x.mean()) / self.weight) ** 2))
        return total

    def residuals(self, models: Sequence[Model]) -> list[list[np.ndarray]]:
        """``res[i][k]``: weighted residual of model i on fold k (fold mean removed)."""
        models = list(models)
        motion = self.motion.get(models, self.runs, self.run_ids) if self.channel in SENSOR_CHANNELS else None
        sims = None if motion is not None else {j: simulate_runs(models, [self.runs[j]]) for j in self.run_ids}
        out = []
        side = _SENSOR_SIDE.get(self.channel)
        for i, m in enumerate(models):
            row = []
            mech = mechanics_model(m) if motion is not None else None
            for f, idx in zip(self.folds, self.idx):
                run = self.runs[f.run]
                if motion is not None:
                    stroke, pitch = motion[(mech, f.run)]
                    if self.truth_referenced:
                        key = (mech, f.run)
                        if key not in self._measured:
                            if len(self._measured) >= 8:
                                self._measured.pop(next(iter(self._measured)))
                            self._measured[key] = measured_motion(run, stroke, pitch, side)
                        stroke, pitch = self._measured[key]
                    v = sensor_voltage(m, run.fs_hz, stroke, pitch, run.drive_v, side)
                    r = run.channel(self.channel)[idx] - v[idx]
                else:
                    r = run.channel(self.channel)[idx] - sims[f.run][i][0][self.channel][idx]
                if not np.all(np.isfinite(r)):
                    r = np.where(np.isfinite(r), r, 1e6 * self.weight)
                row.append((r - r.mean()) / self.weight)
            out.append(row)
        return out


def _models_for(base: Model, specs: Sequence[EffectSpec], xs: np.ndarray) -> list[Model]:
    """Models with the effects of `specs` at the fit-space parameter rows `xs`."""
    models = []
    for x in np.atleast_2d(xs):
        effects = {}
        for s, u in zip(specs, x):
            effects[s.name] = s.params(s.from_fit(u), channel=_merged_channel(base, s))
        models.append(with_effects(base, effects))
    return models


def _merged_channel(base: Model, spec: EffectSpec) -> Optional[str]:
    """Channel parameter for `spec`: 'both' if the base model has it on the other sensor."""
    if spec.channel_param is None:
        return None
    existing = base.effect(spec.name)
    if existing is not None and getattr(existing, "channel", None) not in (None, spec.channel_param):
        return "both"
    return spec.channel_param


@dataclass(frozen=True)
class _Fit:
    x: np.ndarray  # fit-space optimum
    se: np.ndarray  # fit-space standard errors (inf: not identifiable)
    rss: float  # weighted RSS
    n: int
    rss_per_fold: tuple


def _fit(base: Model, specs: Sequence[EffectSpec], problem: _Problem, x0: np.ndarray, settings: Settings,
         grid: bool = True) -> _Fit:
    """Least-squares fit of the specs' parameters on `problem` (grid start, then TRF)."""
    specs = list(specs)
    lo = np.array([s.to_fit(s.lower) for s in specs])
    hi = np.array([s.to_fit(s.upper) for s in specs])
    steps = np.array([s.step for s in specs])
    x0 = np.clip(np.asarray(x0, float), lo, hi)
    if grid and len(specs) == 1 and specs[0].grid:
        s = specs[0]
        xs = np.array([[s.to_fit(v)] for v in s.grid if s.lower <= v <= s.upper] + [list(x0)])
        res = problem.residuals(_models_for(base, specs, xs))
        costs = [sum(float(np.dot(r, r)) for r in row) for row in res]
        x0 = xs[int(np.argmin(costs))]

    cache: dict = {}

    def stack(rows: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(rows) if rows else np.zeros(0)

    def fun(x: np.ndarray) -> np.ndarray:
        key = tuple(np.round(x, 15))
        if key not in cache:
            cache.clear()
            cache[key] = stack(problem.residuals(_models_for(base, specs, x[None, :]))[0])
        return cache[key]

    def jac(x: np.ndarray) -> np.ndarray:
        f0 = fun(x)
        h = np.where(x + steps <= hi, steps, -steps)
        xs = np.repeat(x[None, :], len(specs), axis=0) + np.diag(h)
        rows = problem.residuals(_models_for(base, specs, xs))
        return np.column_stack([(stack(rows[i]) - f0) / h[i] for i in range(len(specs))])

    x_scale = np.maximum(np.abs(steps) * 100.0, 1e-12)
    try:
        sol = optimize.least_squares(fun, x0, jac=jac, bounds=(lo, hi), method="trf", x_scale=x_scale,
                                     max_nfev=settings.max_nfev, xtol=1e-6, ftol=1e-9, gtol=1e-9)
        x = sol.x
    except (ValueError, ModelError):
        x = x0
    f = fun(x)
    J = jac(x)
    n = f.size
    rss = float(np.dot(f, f))
    p = len(specs)
    s2 = rss / max(n - p, 1)
    jtj = J.T @ J
    se = np.full(p, math.inf)
    try:
        if np.all(np.isfinite(jtj)) and np.linalg.matrix_rank(jtj) == p:
            cov = np.linalg.inv(jtj) * s2
            d = np.diag(cov)
            se = np.where(d > 0, np.sqrt(np.abs(d)), math.inf)
    except np.linalg.LinAlgError:
        pass
    # a parameter whose column barely moves the residual is not identifiable here
    col = np.sqrt(np.sum(J * J, axis=0))
    se = np.where(col * np.abs(steps) < 1e-9 * math.sqrt(max(rss, 1e-300)), math.inf, se)
    sizes = problem.n_per_fold()
    per_fold, k = [], 0
    for m in sizes:
        per_fold.append(float(np.dot(f[k:k + m], f[k:k + m])))
        k += m
    return _Fit(x=np.asarray(x, float), se=np.asarray(se, float), rss=rss, n=n, rss_per_fold=tuple(per_fold))


# ------------------------------------------------------------------------------ evidence


@dataclass(frozen=True)
class CandidateEvidence:
    """Evidence for one candidate (an effect, or a pair on one channel).

    Attributes
    ----------
    labels : effect labels (name[channel]).
    channel : measured channel judged.
    values : fitted physical parameters (all runs), one per effect.
    se : their standard errors.
    z : distance from the null value in standard errors.
    per_run : per-run estimates [(run, value, se)] per effect.
    consistency_p : p-value of the per-run scatter test per effect (NaN: fewer than 2 runs identify it).
    heldout_nrmse_before, heldout_nrmse_after : channel NRMSE on held-out runs without / with it.
    heldout_drop : 1 - after / before.
    heldout_gap_drop : the same for the model error above noise (R1): 1 - sqrt(max(RSS_after - n, 0)
        / max(RSS_before - n, 0)) in noise-weighted units.
    delta_bic_heldout : held-out BIC change (negative favours the effect).
    delta_bic_fit : in-sample BIC change on all runs.
    rules : {rule: passed}.
    accepted : all rules passed.
    """

    labels: tuple
    channel: str
    values: tuple
    se: tuple
    z: tuple
    per_run: tuple
    consistency_p: tuple
    heldout_nrmse_before: float
    heldout_nrmse_after: float
    heldout_drop: float
    heldout_gap_drop: float
    delta_bic_heldout: float
    delta_bic_fit: float
    rules: dict
    accepted: bool

    def as_dict(self) -> dict:
        """JSON-ready evidence."""
        return {
            "candidate": "+".join(self.labels), "judged_on": self.channel,
            "values": list(self.values), "standard_errors": list(self.se), "z_from_null": list(self.z),
            "per_run": [[{"run": n, "value": v, "se": s} for n, v, s in pr] for pr in self.per_run],
            "consistency_p": list(self.consistency_p),
            "heldout_nrmse_before": self.heldout_nrmse_before, "heldout_nrmse_after": self.heldout_nrmse_after,
            "heldout_drop": self.heldout_drop, "heldout_gap_drop": self.heldout_gap_drop,
            "delta_bic_heldout": self.delta_bic_heldout,
            "delta_bic_fit": self.delta_bic_fit, "rules": dict(self.rules), "accepted": self.accepted,
        }


@dataclass(frozen=True)
class FoundEffect:
    """An effect the workflow added to the model.

    Attributes
    ----------
    name : effect name (model vocabulary).
    channel : measured channel(s) it was found on.
    parameters : its parameters as written to the model file.
    evidence : the accepted candidate's evidence (`CandidateEvidence.as_dict`).
    explains : channels this effect can possibly change.
    """

    name: str
    channel: str
    parameters: dict
    evidence: dict
    explains: tuple


def _bic(rss_list: Sequence[float], n_list: Sequence[int], k: int) -> float:
    n_tot = sum(n_list)
    val = sum(n * math.log(max(r, 1e-300) / n) for r, n in zip(rss_list, n_list) if n > 0)
    return val + k * math.log(max(n_tot, 2))


def _gap_drop(rss_before: float, rss_after: float, n: int) -> float:
    """Relative drop of the model error above noise (noise-weighted residuals: noise RSS = n)."""
    before = math.sqrt(max(rss_before - n, 0.0))
    after = math.sqrt(max(rss_after - n, 0.0))
    return 1.0 - after / before if before > 0 else 0.0


def _consistency(est: Sequence[tuple[float, float]], size: float, settings: Settings) -> float:
    """p-value of the scatter of (value, se) estimates about their weighted mean."""
    pts = [(v, s) for v, s in est if math.isfinite(s) and s > 0]
    if len(pts) < 2:
        return math.nan
    v = np.array([p[0] for p in pts])
    var = np.array([p[1] ** 2 for p in pts]) + (settings.consistency_rel_tol * size) ** 2
    if np.any(var <= 0):
        var = np.maximum(var, 1e-300)
    w = 1.0 / var
    mean = float(np.sum(w * v) / np.sum(w))
    q = float(np.sum((v - mean) ** 2 * w))
    return float(stats.chi2.sf(q, len(pts) - 1))


def _pooled(est: Sequence[tuple[float, float]], fallback: float) -> float:
    pts = [(v, s) for v, s in est if math.isfinite(s) and s > 0]
    if not pts:
        return fallback
    w = np.array([1.0 / p[1] ** 2 for p in pts])
    return float(np.sum(w * np.array([p[0] for p in pts])) / np.sum(w))


class _Context:
    """Data shared by the candidate evaluations of one analysis."""

    def __init__(self, runs: Sequence[Run], noise: Mapping[str, float], settings: Settings,
                 tracks: Optional[Sequence[tuple[np.ndarray, np.ndarray]]] = None) -> None:
        self.runs = tuple(runs)
        self.noise = dict(noise)
        self.settings = settings
        self.folds = _folds(self.runs)
        self.tracks = list(tracks) if tracks is not None else _drive_tracks(self.runs)
        self.motion = _MotionCache()

    def problem(self, channel: str, folds: Sequence[_Fold], truth_referenced: bool, weight_model: Model) -> _Problem:
        """Residual problem of `channel` on `folds`."""
        truth_sigma = self.noise[_UPSTREAM_TRUTH[channel]] if channel in SENSOR_CHANNELS else 0.0
        return _Problem(self.runs, folds, channel, self.noise[channel], truth_referenced,
                        self.settings.decimate, truth_sigma, weight_model, self.motion)


def _reach_deg(ctx: _Context, model: Model) -> float:
    sims = simulate_runs([model], ctx.runs)[0]
    return max(float(np.max(s["stroke_deg"])) for s in sims)


def _phys_se(spec: EffectSpec, u: float, se_u: float) -> float:
    if not math.isfinite(se_u):
        return math.inf
    return spec.from_fit(u) * se_u if spec.log else se_u


def _null_fit_value(spec: EffectSpec) -> float:
    if math.isfinite(spec.null) and (not spec.log or spec.null > 0):
        return spec.to_fit(spec.null)
    if math.isinf(spec.null):
        return spec.to_fit(spec.upper)
    return spec.to_fit(spec.lower)


def _evaluate(ctx: _Context, base: Model, specs: Sequence[EffectSpec], channel: str, truth_referenced: bool,
              x_start: Optional[np.ndarray] = None,
              merge_with: Optional[tuple[float, float]] = None) -> tuple[CandidateEvidence, Model]:
    """Fit `specs` on top of `base` per fold and on all folds, judge on held-out folds (R1-R4).

    merge_with: (value, se) of the same effect already found on the other sensor channel; the
    candidate then extends it to channel 'both' and must agree with it (rule R5).
    """
    st = ctx.settings
    specs = list(specs)
    p = len(specs)
    null_x = np.array([_null_fit_value(s) for s in specs])
    x0 = null_x if x_start is None else np.asarray(x_start, float)
    folds = ctx.folds
    per_fold = [_fit(base, specs, ctx.problem(channel, [f], truth_referenced, base), x0, st,
                     grid=(p == 1 and x_start is None)) for f in folds]
    all_prob = ctx.problem(channel, folds, truth_referenced, base)
    # all-run estimate: inverse-variance pooling of the per-run fits (equivalent to one fit on all
    # runs for independent runs); if no run identifies the effect, the best run's value
    identified = [pf for pf in per_fold if np.all(np.isfinite(pf.se)) and np.all(pf.se > 0)]
    if identified:
        x_all = np.array([_pooled([(pf.x[j], pf.se[j]) for pf in identified], x0[j]) for j in range(p)])
        se_all = np.array([1.0 / math.sqrt(sum(1.0 / pf.se[j] ** 2 for pf in identified)) for j in range(p)])
    else:
        x_all = min(per_fold, key=lambda pf: pf.rss / max(pf.n, 1)).x
        se_all = np.full(p, math.inf)
    res_all = all_prob.residuals(_models_for(base, specs, x_all[None, :]))[0]
    fit_all = _Fit(x=x_all, se=se_all, rss=sum(float(np.dot(r, r)) for r in res_all), n=sum(r.size for r in res_all),
                   rss_per_fold=tuple(float(np.dot(r, r)) for r in res_all))
    values = [s.from_fit(u) for s, u in zip(specs, fit_all.x)]
    se_phys = [_phys_se(s, u, e) for s, u, e in zip(specs, fit_all.x, fit_all.se)]
    res_null = all_prob.residuals([base])[0]
    rss_null = [float(np.dot(r, r)) for r in res_null]
    n_f = all_prob.n_per_fold()
    # held-out: each fold predicted with the pooled estimates of the other folds
    models_ho = []
    for k in range(len(folds)):
        others = [per_fold[i] for i in range(len(folds)) if i != k]
        x_ho = [_pooled([(pf.x[j], pf.se[j]) for pf in others], null_x[j]) for j in range(p)]
        models_ho.append(_models_for(base, specs, np.array([x_ho]))[0])
    rss_ho = []
    for k, f in enumerate(folds):
        r = ctx.problem(channel, [f], truth_referenced, base).residuals([models_ho[k]])[0][0]
        rss_ho.append(float(np.dot(r, r)))
    ss = all_prob.signal_ss()
    before = math.sqrt(sum(rss_null) / ss) if ss > 0 else math.nan
    after = math.sqrt(sum(rss_ho) / ss) if ss > 0 else math.nan
    drop = 1.0 - after / before if before > 0 else 0.0
    gap_drop = _gap_drop(sum(rss_null), sum(rss_ho), sum(n_f))
    dbic_ho = _bic(rss_ho, n_f, p) - _bic(rss_null, n_f, 0)
    dbic_fit = _bic(list(fit_all.rss_per_fold), n_f, p) - _bic(rss_null, n_f, 0)
    z, cons, per_run, n_ident, inside = [], [], [], [], []
    reach = None
    for j, s in enumerate(specs):
        lo, hi = s.to_fit(s.lower), s.to_fit(s.upper)
        near = 1e-3 * (hi - lo)
        at_lo = fit_all.x[j] - lo < near and s.lower != s.null
        at_hi = hi - fit_all.x[j] < near and s.upper != s.null
        inside.append(not (at_lo or at_hi))
        v, e = values[j], se_phys[j]
        if math.isinf(s.null):
            if reach is None:
                reach = _reach_deg(ctx, base)
            z.append((reach - v) / e if 0 < e < math.inf and v < reach else 0.0)
        else:
            z.append(abs(v - s.null) / e if 0 < e < math.inf else 0.0)
        est = [(s.from_fit(pf.x[j]), _phys_se(s, pf.x[j], pf.se[j])) for pf in per_fold]
        per_run.append(tuple((f.name, ev, es) for f, (ev, es) in zip(folds, est)))
        cons.append(_consistency(est, s.effect_size(v), st))
        n_ident.append(sum(1 for _, es in est if 0 < es < math.inf))
    rules = {
        "R1_heldout_gap_drop": bool(gap_drop > st.min_heldout_drop),
        "R2_delta_bic": bool(dbic_ho < st.max_delta_bic),
        "R3_significance": bool(all(zz > st.min_z for zz in z) and all(inside)),
        "R4_consistency": bool(all(k >= 2 for k in n_ident)
                               and all(c >= st.consistency_alpha for c in cons if math.isfinite(c))),
    }
    model = _models_for(base, specs, fit_all.x[None, :])[0]
    if merge_with is not None:
        v_old, se_old = merge_with
        v_new, se_new = values[0], se_phys[0]
        tol = 3.0 * math.hypot(se_old, se_new) + st.consistency_rel_tol * specs[0].effect_size(v_old)
        rules["R5_same_on_both_sensors"] = bool(abs(v_new - v_old) <= tol)
        w_old, w_new = (1 / se_old**2 if 0 < se_old < math.inf else 0.0), (1 / se_new**2 if 0 < se_new < math.inf else 0.0)
        merged = (w_old * v_old + w_new * v_new) / (w_old + w_new) if w_old + w_new > 0 else v_new
        values = [merged]
        model = with_effects(base, {specs[0].name: specs[0].params(merged, channel="both")})
    ev = CandidateEvidence(
        labels=tuple(s.label for s in specs), channel=channel, values=tuple(values), se=tuple(se_phys),
        z=tuple(z), per_run=tuple(per_run), consistency_p=tuple(cons), heldout_nrmse_before=before,
        heldout_nrmse_after=after, heldout_drop=drop, heldout_gap_drop=gap_drop, delta_bic_heldout=dbic_ho,
        delta_bic_fit=dbic_fit, rules=rules, accepted=all(rules.values()),
    )
    return ev, model


# ------------------------------------------------------------------------------ the search


@dataclass(frozen=True)
class ChannelSearch:
    """Record of the greedy search on one channel.

    Attributes
    ----------
    channel : measured channel.
    truth_referenced : the sensor channel was judged against the measured truth.
    skipped : why the channel was not searched ('' if it was).
    steps : per greedy step, the evidence of every candidate tried.
    """

    channel: str
    truth_referenced: bool
    skipped: str
    steps: tuple


@dataclass(frozen=True)
class DiscrepancyResult:
    """Outcome of the whole workflow.

    Attributes
    ----------
    status : 'no_discrepancy', 'explained' or 'unexplained'.
    effects : found effects (`FoundEffect`), in the order they were found.
    model_in, model_out : input model and input model + found effects.
    gap_before, gap_after : NRMSE per channel on held-out runs (after: parameters re-fitted
        without the run they predict; before: the input model, which is not fitted).
    gap_in_sample_after : NRMSE per channel of model_out on all runs.
    noise : noise RMS per channel (data estimate).
    diagnosis_before, diagnosis_after : `Diagnosis` of the input and the output model.
    searches : the greedy search on each channel.
    remaining : where a gap remains: ({channel, band_hz, drive_level_ratio, stretch, note}, ...).
    sims_before, sims_after : simulated channels per run (for figures).
    summary : the outcome in words.
    run_names : names of the runs.
    """

    status: str
    effects: tuple
    model_in: Model
    model_out: Model
    gap_before: dict
    gap_after: dict
    gap_in_sample_after: dict
    noise: dict
    diagnosis_before: Diagnosis
    diagnosis_after: Diagnosis
    searches: tuple
    remaining: tuple
    sims_before: tuple
    sims_after: tuple
    summary: str
    run_names: tuple = ()


_CHANNEL_ORDER = ("stroke_deg", "pitch_deg", "stroke_sensor_v", "pitch_sensor_v")


def _channel_has_gap(ctx: _Context, model: Model, channel: str, truth_ref: bool) -> bool:
    """The gap test of one channel (noise ratio and whiteness only)."""
    sims = simulate_runs([model], ctx.runs)[0]
    res = [_residual(run, sim, channel, model, truth_referenced=truth_ref) for run, sim in zip(ctx.runs, sims)]
    sigma = ctx.noise[channel]
    if truth_ref:
        g = _sensor_gain_v_per_deg(model, channel)
        sigma = math.sqrt(sigma**2 + (g * ctx.noise[_UPSTREAM_TRUTH[channel]]) ** 2)
    return _gap_test(res, sigma, ctx.settings)[0]


def _gap_test(res: Sequence[np.ndarray], sigma: float, settings: Settings) -> tuple[bool, float, float, float]:
    """(has_gap, noise ratio, Ljung-Box Q, p) of residual records."""
    rss = sum(float(np.nansum(r**2)) for r in res)
    n = sum(int(np.isfinite(r).sum()) for r in res)
    ratio = math.sqrt(rss / n) / sigma if n and sigma > 0 else math.inf
    dec = settings.whiteness_decimate
    joined = np.concatenate([np.r_[r[::dec], np.full(settings.ljung_box_lags, np.nan)] for r in res])
    q, p = _ljung_box(joined, settings.ljung_box_lags)
    has_gap = bool(ratio > settings.gap_noise_ratio and (not math.isfinite(p) or p < settings.whiteness_alpha))
    return has_gap, ratio, q, p


def _offer(model_in: Model, current: Model, spec: EffectSpec, found_here: Sequence[EffectSpec]) -> Optional[str]:
    """'new', 'merge' (extend the other sensor's effect to both) or None (not offered)."""
    if model_in.effect(spec.name) is not None or any(s.name == spec.name for s in found_here):
        return None
    existing = current.effect(spec.name)
    if existing is None:
        return "new"
    if spec.channel_param is not None and getattr(existing, "channel", None) not in (spec.channel_param, "both"):
        return "merge"
    return None


def _polish(ctx: _Context, base: Model, specs: Sequence[EffectSpec], current: Model, channel: str,
            truth_ref: bool, folds: Optional[Sequence[_Fold]] = None) -> Model:
    """Joint least-squares re-fit of the effects `specs` of one channel, from their current values."""
    folds = ctx.folds if folds is None else folds
    x0 = np.array([s.to_fit(_param_value(current, s)) for s in specs])
    prob = ctx.problem(channel, folds, truth_ref, base)
    fit = _fit(base, specs, prob, x0, ctx.settings, grid=False)
    effects = {}
    for s, u in zip(specs, fit.x):
        old = current.effect(s.name)
        effects[s.name] = s.params(s.from_fit(u), channel=getattr(old, "channel", None))
    return with_effects(base, effects)


def _evaluate_shared(ctx: _Context, current: Model, specs: Sequence[EffectSpec], channel: str,
                     truth_ref: bool) -> tuple[CandidateEvidence, Model]:
    """Zero-parameter test: the other sensor's effects `specs`, at their values, on both sensors."""
    st = ctx.settings
    model = with_effects(current, {s.name: s.params(_param_value(current, s), channel="both") for s in specs})
    prob = ctx.problem(channel, ctx.folds, truth_ref, current)
    res_old, res_new = prob.residuals([current, model])
    rss_old = [float(np.dot(r, r)) for r in res_old]
    rss_new = [float(np.dot(r, r)) for r in res_new]
    n_f = prob.n_per_fold()
    ss = prob.signal_ss()
    before, after = math.sqrt(sum(rss_old) / ss), math.sqrt(sum(rss_new) / ss)
    drop = 1.0 - after / before if before > 0 else 0.0
    gap_drop = _gap_drop(sum(rss_old), sum(rss_new), sum(n_f))
    dbic = _bic(rss_new, n_f, 0) - _bic(rss_old, n_f, 0)
    rules = {"R1_heldout_gap_drop": bool(gap_drop > st.min_heldout_drop), "R2_delta_bic": bool(dbic < st.max_delta_bic)}
    values = tuple(_param_value(current, s) for s in specs)
    ev = CandidateEvidence(
        labels=tuple(f"{s.name}[both]" for s in specs), channel=channel, values=values,
        se=tuple(math.nan for _ in specs), z=tuple(math.nan for _ in specs), per_run=tuple(() for _ in specs),
        consistency_p=tuple(math.nan for _ in specs), heldout_nrmse_before=before, heldout_nrmse_after=after,
        heldout_drop=drop, heldout_gap_drop=gap_drop, delta_bic_heldout=dbic, delta_bic_fit=dbic, rules=rules,
        accepted=all(rules.values()))
    return ev, model


@dataclass
class _ChannelState:
    model: Model
    specs: list
    evidence: dict  # effect name -> CandidateEvidence that added it
    last: Optional[CandidateEvidence] = None


def _greedy(ctx: _Context, model_in: Model, state: _ChannelState, channel: str, truth_ref: bool,
            found: Sequence[FoundEffect], steps: list, max_steps: int) -> tuple[_ChannelState, bool, list]:
    """Forward selection on one channel; returns (state, has_gap, first-step single evaluations)."""
    st = ctx.settings
    has_gap = _channel_has_gap(ctx, state.model, channel, truth_ref)
    first = []
    for step in range(max_steps):
        if not has_gap:
            break
        offers = [(s, _offer(model_in, state.model, s, state.specs)) for s in candidate_specs(channel)]
        offers = [(s, kind) for s, kind in offers if kind is not None]
        if not offers:
            break
        evals = []
        for s, kind in offers:
            merge = None
            base = state.model
            if kind == "merge":
                prev = next((f for f in found if f.name == s.name), None)
                se_prev = (prev.evidence.get("standard_errors") or [math.inf])[0] if prev is not None else math.inf
                merge = (_param_value(state.model, s), float(se_prev))
                base = _strip(state.model, [s])
            ev, m = _evaluate(ctx, base, [s], channel, truth_ref, merge_with=merge)
            if kind == "merge":
                m = with_effects(state.model, {s.name: s.params(ev.values[0], channel="both")})
            ev = _check_upstream_truth(ctx, ev, m, channel, s)
            evals.append((ev, m, (s,), kind))
        if step == 0:
            first = evals
        steps.append(tuple(e[0] for e in evals))
        passing = [e for e in evals if e[0].accepted]
        if not passing:
            break
        ev, m, chosen, _ = min(passing, key=lambda e: e[0].delta_bic_heldout)
        state = _ChannelState(m, state.specs + list(chosen), {**state.evidence, **{s.name: ev for s in chosen}}, ev)
        own = [s for s in state.specs if getattr(state.model.effect(s.name), "channel", None) in (None, s.channel_param)]
        # Re-fit this channel's own effects whenever anything joined them, a shared (merged)
        # effect included: an efficiency fitted before a delay was found is biased by cos(w tau).
        if own and len(state.specs) >= 2:
            state.model = _polish(ctx, _strip(state.model, own), own, state.model, channel, truth_ref)
        has_gap = _channel_has_gap(ctx, state.model, channel, truth_ref)
    return state, has_gap, first


def _check_upstream_truth(ctx: _Context, ev: CandidateEvidence, model: Model, channel: str,
                          spec: EffectSpec) -> CandidateEvidence:
    """R6: a stroke-physics effect judged on pitch_deg must leave stroke_deg without a gap."""
    if channel != "pitch_deg" or "stroke_deg" not in EFFECT_CHANNELS[spec.name] or not ev.accepted:
        return ev
    ok = not _channel_has_gap(ctx, model, "stroke_deg", False)
    rules = {**ev.rules, "R6_stroke_truth_intact": ok}
    return replace(ev, rules=rules, accepted=all(rules.values()))


def _search_channel(ctx: _Context, model_in: Model, start: Model, channel: str, truth_ref: bool,
                    found: Sequence[FoundEffect]) -> tuple[_ChannelState, bool, list]:
    """Shared-sensor test, greedy forward selection, then pair backtracking if a gap is left."""
    st = ctx.settings
    steps: list = []
    state = _ChannelState(start, [], {})
    if channel in SENSOR_CHANNELS:
        shared = [s for s in candidate_specs(channel) if _offer(model_in, start, s, []) == "merge"]
        tries = ([shared] if shared else []) + ([[s] for s in shared] if len(shared) > 1 else [])
        for group in tries:
            ev, m = _evaluate_shared(ctx, start, group, channel, truth_ref)
            steps.append((ev,))
            if ev.accepted:
                state = _ChannelState(m, list(group), {s.name: ev for s in group}, ev)
                break
    base_state = _ChannelState(state.model, list(state.specs), dict(state.evidence), state.last)
    state, has_gap, first = _greedy(ctx, model_in, state, channel, truth_ref, found, steps, st.max_effects_per_channel)
    if has_gap and st.pair_fallback:
        singles = [e for e in first if e[3] == "new"]
        best = None
        for i in range(len(singles)):
            for j in range(i + 1, len(singles)):
                a, b = singles[i], singles[j]
                specs = [a[2][0], b[2][0]]
                x_start = np.array([specs[0].to_fit(a[0].values[0]), specs[1].to_fit(b[0].values[0])])
                ev, m = _evaluate(ctx, base_state.model, specs, channel, truth_ref, x_start)
                for s in specs:
                    ev = _check_upstream_truth(ctx, ev, m, channel, s)
                steps.append((ev,))
                if ev.accepted and (best is None or ev.delta_bic_heldout < best[0].delta_bic_heldout):
                    best = (ev, m, specs)
        greedy_after = state.last.heldout_nrmse_after if state.last is not None and state.specs != base_state.specs \
            else math.inf
        if best is not None and best[0].heldout_nrmse_after < greedy_after:
            ev, m, specs = best
            pair_state = _ChannelState(m, base_state.specs + specs,
                                       {**base_state.evidence, **{s.name: ev for s in specs}}, ev)
            state, has_gap, _ = _greedy(ctx, model_in, pair_state, channel, truth_ref, found, steps,
                                        max(st.max_effects_per_channel - 2, 0))
    return state, has_gap, steps


def find_effects(
    runs: Sequence[Run],
    model: Model,
    noise: Mapping[str, float],
    settings: Settings = Settings(),
    progress: Optional[Callable[[str], None]] = None,
    tracks: Optional[Sequence[tuple[np.ndarray, np.ndarray]]] = None,
) -> tuple[Model, tuple[FoundEffect, ...], tuple[ChannelSearch, ...]]:
    """Greedy, channel-by-channel search for the missing effects (rules in the module docstring).

    Returns
    -------
    (model_out, found effects, per-channel search records)
    """
    ctx = _Context(runs, noise, settings, tracks)
    current = model
    found: list[FoundEffect] = []
    searches = []
    unexplained_truth: set[str] = set()
    for channel in _CHANNEL_ORDER:
        if progress:
            progress(channel)
        if channel == "pitch_deg" and "stroke_deg" in unexplained_truth:
            if _channel_has_gap(ctx, current, channel, False):
                unexplained_truth.add(channel)
            searches.append(ChannelSearch(channel, False, "downstream of an unexplained stroke_deg gap", ()))
            continue
        truth_ref = channel in SENSOR_CHANNELS and _UPSTREAM_TRUTH[channel] in unexplained_truth
        if not _channel_has_gap(ctx, current, channel, truth_ref):
            searches.append(ChannelSearch(channel, truth_ref, "no gap", ()))
            continue
        state, has_gap, steps = _search_channel(ctx, model, current, channel, truth_ref, found)
        current = state.model
        for s in state.specs:
            ev = state.evidence.get(s.name)
            found.append(FoundEffect(name=s.name, channel=channel, parameters={},
                                     evidence=ev.as_dict() if ev is not None else {}, explains=EFFECT_CHANNELS[s.name]))
        if has_gap and channel in TRUTH_CHANNELS:
            unexplained_truth.add(channel)
        searches.append(ChannelSearch(channel, truth_ref, "", tuple(steps)))
    return current, tuple(_merge_sensor_channels(found, current)), tuple(searches)


def _strip(model: Model, specs: Sequence[EffectSpec]) -> Model:
    names = {s.name for s in specs}
    return replace(model, effects=tuple((n, e) for n, e in model.effects if n not in names))


def _param_value(model: Model, spec: EffectSpec) -> float:
    return float(getattr(model.effect(spec.name), spec.key))


def _effect_params_dict(model: Model, name: str) -> dict:
    e = model.effect(name)
    return {k: (v if isinstance(v, str) else float(v)) for k, v in e.__dict__.items()}


def _merge_sensor_channels(found: list[FoundEffect], model: Model) -> list[FoundEffect]:
    """One entry per effect name (a sensor effect on both sensors once, channel 'a+b')."""
    by_name: dict[str, FoundEffect] = {}
    order = []
    for f in found:
        params = _effect_params_dict(model, f.name)
        if f.name in by_name:
            prev = by_name[f.name]
            by_name[f.name] = replace(prev, channel=f"{prev.channel}+{f.channel}", parameters=params,
                                      evidence={**prev.evidence, "merged_from": f.evidence})
        else:
            by_name[f.name] = replace(f, parameters=params)
            order.append(f.name)
    return [by_name[n] for n in order]


# ------------------------------------------------------------------------- held-out gap after


def _refit_on(ctx: _Context, effects: Sequence[FoundEffect], model_out: Model, folds: Sequence[_Fold]) -> Model:
    """Re-fit the found effects' parameters on `folds`, channel by channel (upstream first)."""
    current = model_out
    for channel in _CHANNEL_ORDER:
        names = [f.name for f in effects if f.channel.split("+")[0] == channel]
        specs = [s for s in candidate_specs(channel) if s.name in names]
        if specs:
            current = _polish(ctx, _strip(current, specs), specs, current, channel, False, folds)
    return current


def _heldout_nrmse(ctx: _Context, effects: Sequence[FoundEffect], model_out: Model) -> dict:
    """Per-channel NRMSE of held-out predictions: each fold predicted by a re-fit on the others."""
    rss = {c: 0.0 for c in CHANNELS}
    ss = {c: 0.0 for c in CHANNELS}
    for k, f in enumerate(ctx.folds):
        others = [g for i, g in enumerate(ctx.folds) if i != k]
        m = _refit_on(ctx, effects, model_out, others) if effects else model_out
        run = ctx.runs[f.run]
        sim = simulate_runs([m], [run])[0][0]
        for c in CHANNELS:
            r = (run.channel(c) - sim[c])[f.start:f.stop]
            x = run.channel(c)[f.start:f.stop]
            ok = np.isfinite(r)
            r = r[ok] - r[ok].mean()
            x = x[ok] - x[ok].mean()
            rss[c] += float(np.dot(r, r))
            ss[c] += float(np.dot(x, x))
    return {c: math.sqrt(rss[c] / ss[c]) if ss[c] > 0 else math.nan for c in CHANNELS}


# ------------------------------------------------------------------------------- the workflow


def analyse(
    runs: Sequence[Run],
    model: Model,
    settings: Settings = Settings(),
    progress: Optional[Callable[[str], None]] = None,
) -> DiscrepancyResult:
    """The whole workflow: compare, localise, name, add, show the gap shrink, decide the status.

    Parameters
    ----------
    runs
        Measured runs (same sample rate, ground truth present; see `check_runs`).
    model
        Input model (its effects are kept).
    settings
        Decision rules.
    progress
        Called with a short label before each long step (the CLI drives a progress bar with it).

    Raises
    ------
    DiscrepancyInputError
        Unusable runs.
    """
    runs = check_runs(runs)
    for r in runs:
        try:
            simulate(r.drive_v[:8], r.fs_hz, model)
        except ModelError as exc:
            raise DiscrepancyInputError(f"model cannot be simulated at {r.fs_hz:g} Hz: {exc}") from None
    if progress:
        progress("compare")
    sims_before = simulate_runs([model], runs)[0]
    noise = noise_estimates(runs, sims_before, model)
    tracks = _drive_tracks(runs)
    diag_before = diagnose(runs, sims_before, model, noise, settings, tracks=tracks)
    gap_before = nrmse_by_channel(runs, sims_before)
    if not diag_before.gaps:
        return DiscrepancyResult(
            status="no_discrepancy", effects=(), model_in=model, model_out=model, gap_before=gap_before,
            gap_after=dict(gap_before), gap_in_sample_after=dict(gap_before), noise=noise,
            diagnosis_before=diag_before, diagnosis_after=diag_before, searches=(), remaining=(),
            sims_before=tuple(sims_before), sims_after=tuple(sims_before),
            summary=_summary("no_discrepancy", (), diag_before, ()), run_names=tuple(r.name for r in runs))
    model_out, effects, searches = find_effects(runs, model, noise, settings, progress, tracks)
    if progress:
        progress("held-out gap")
    sims_after = simulate_runs([model_out], runs)[0]
    diag_after = diagnose(runs, sims_after, model_out, noise, settings, tracks=tracks)
    gap_after = (_heldout_nrmse(_Context(runs, noise, settings, tracks), effects, model_out) if effects
                 else dict(gap_before))
    in_sample = nrmse_by_channel(runs, sims_after)
    ctx = _Context(runs, noise, settings, tracks)
    sensor_ok = {c: not _channel_has_gap(ctx, model_out, c, True) for c in SENSOR_CHANNELS
                 if any(s.channel == c and s.truth_referenced for s in searches)}
    remaining = _remaining(diag_after, searches, sensor_ok)
    status = "explained" if effects and not remaining else "unexplained"
    return DiscrepancyResult(
        status=status, effects=tuple(effects), model_in=model, model_out=model_out, gap_before=gap_before,
        gap_after=gap_after, gap_in_sample_after=in_sample, noise=noise, diagnosis_before=diag_before,
        diagnosis_after=diag_after, searches=searches, remaining=remaining, sims_before=tuple(sims_before),
        sims_after=tuple(sims_after), summary=_summary(status, effects, diag_after, remaining),
        run_names=tuple(r.name for r in runs))


def _remaining(diag: Diagnosis, searches: Sequence[ChannelSearch], sensor_ok: Mapping[str, bool]) -> tuple:
    """Where gaps remain; sensor_ok: sensor channel explained when driven by the measured angle."""
    skipped = {s.channel: s.skipped for s in searches}
    out = []
    for c in diag.gaps:
        g = diag.channels[c]
        note = g.interpretation
        if skipped.get(c, "").startswith("downstream"):
            note = "possibly propagated from the unexplained stroke_deg gap; " + note
        if c in sensor_ok:
            note = ("the sensor itself is explained when driven by the measured angle: this gap is the "
                    f"{_UPSTREAM_TRUTH[c]} gap propagated; " if sensor_ok[c] else
                    "a sensor gap beyond the propagated physics error (judged against the measured angle); ") + note
        near = _near_misses(searches, c)
        if near:
            note = note + "; " + near
        out.append({
            "channel": c, "band_hz": g.worst_band_hz, "drive_level_ratio": g.level_ratio,
            "level_nrmse": g.level_nrmse, "stretch": list(g.worst_stretch), "model_error_nrmse": g.model_error_nrmse,
            "note": note,
        })
    return tuple(out)


def _near_misses(searches: Sequence[ChannelSearch], channel: str) -> str:
    """Candidates on `channel` refused only because their per-run estimates disagree (R4)."""
    notes = []
    for search in searches:
        if search.channel != channel:
            continue
        for step in search.steps:
            for ev in step:
                failed = [k for k, v in ev.rules.items() if not v]
                if failed == ["R4_consistency"]:
                    runs = "; ".join(", ".join(f"{n} {v:.4g}" for n, v, _ in pr) for pr in ev.per_run)
                    notes.append(f"{'+'.join(ev.labels)} would fit each run alone but its parameter differs "
                                 f"between runs ({runs})")
    return "nearest vocabulary effect refused: " + "; ".join(dict.fromkeys(notes)) if notes else ""


def _summary(status: str, effects: Sequence[FoundEffect], diag: Diagnosis, remaining: Sequence[dict]) -> str:
    if status == "no_discrepancy":
        return "The model explains every channel to noise level: residuals are white and at the noise RMS."
    parts = []
    if effects:
        parts.append("Found: " + ", ".join(f"{e.name} on {e.channel} ({_fmt_params(e.parameters)})" for e in effects) + ".")
    if status == "explained":
        parts.append("With them every channel is explained to noise level.")
    else:
        for r in remaining:
            parts.append(f"A gap remains on {r['channel']} (worst band {r['band_hz']} Hz, "
                         f"full/low drive error ratio {r['drive_level_ratio']:.2g}, worst stretch {r['stretch'][0]} "
                         f"{r['stretch'][1]:.2f}-{r['stretch'][2]:.2f} s) that no vocabulary effect removes: {r['note']}.")
    return " ".join(parts)


def _fmt_params(params: Mapping) -> str:
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items())


# ----------------------------------------------------------------------------------- Bode


def bode_points(run: Run, sim: Mapping[str, np.ndarray], window_s: float = 0.025,
                track: Optional[tuple[np.ndarray, np.ndarray]] = None) -> dict:
    """Amplitude and phase (relative to the drive) of measured and simulated channels per window.

    Tiled windows of `window_s`; in each, every signal is fitted as a sine of the drive's
    instantaneous phase (plus a constant). Returns {"frequency_hz": (k,), channel: {"measured":
    complex (k,), "model": complex (k,)}} with phasors per volt of drive.
    """
    phase, freq = track if track is not None else frequency_track_from_drive(run.drive_v, run.fs_hz)
    win = max(8, int(round(window_s * run.fs_hz)))
    k = run.n // win
    out: dict = {"frequency_hz": np.full(k, np.nan)}
    for c in CHANNELS:
        out[c] = {"measured": np.full(k, np.nan + 0j), "model": np.full(k, np.nan + 0j)}
    for j in range(k):
        sl = slice(j * win, (j + 1) * win)
        ph = phase[sl]
        base = np.column_stack([np.cos(ph), np.sin(ph), np.ones(win)])
        dcoef, *_ = np.linalg.lstsq(base, run.drive_v[sl], rcond=None)
        d = complex(dcoef[0], -dcoef[1])
        if abs(d) < 1e-9:
            continue
        out["frequency_hz"][j] = float(np.median(freq[sl]))
        for c in CHANNELS:
            for src, x in (("measured", run.channel(c)[sl]), ("model", sim[c][sl])):
                ok = np.isfinite(x)
                if ok.sum() < 8:
                    continue
                coef, *_ = np.linalg.lstsq(base[ok], x[ok], rcond=None)
                out[c][src][j] = complex(coef[0], -coef[1]) / d
    return out
