"""Grey-box identification of the plant from measured runs (pure: numpy, scipy, numba).

Every laminate-fabricated robot differs from the nominal model by a few per cent, so its own
mechanical parameters are fitted before any missing physics is looked for:

    stroke: natural frequency f, aerodynamic damping Gamma, actuator gain G_a
    pitch:  natural frequency f_p, hinge damping c_p, couplings J_c (inertial), D_p (aerodynamic)

(`vocabulary.PLANT_PARAMETERS`). The inertias are the scale of each equation and stay at their
model values (only the ratios to them are observable from motion); the sensor constants
(Table 1, charge amplifiers, transmission ratio) are fabrication-known and stay fixed.

1. Frequency-domain start (`frequency_domain_start`): the transfer functions drive -> stroke and
   stroke -> pitch in tiled windows of the sweeps (`characterization.tiled_transfer`), and the
   linear least-squares solution of the describing-function equations

       (K - I w^2) Phi + j w (8/(3 pi)) w A Gamma Phi = G_a                         (per volt)
       (k_h - I_p w^2) Psi + j w c_p Psi = J_c w^2 Phi - j w (8/(3 pi)) w A D_p Phi

   with A the window's stroke amplitude (the quadratic damping's equivalent viscous term).
2. Time-domain fit (`identify_plant`): `scipy.optimize.least_squares` (trust-region reflective)
   on the noise-weighted residuals of the ground-truth angles of every run, parameters in log
   space, together with each run's initial angle and rate (started from the measured initial
   state, `runs.initial_mechanical_state`), Jacobian by finite differences (all columns of a run
   in one `simulate_batch_from` call).
   Upstream first: the stroke parameters on stroke_deg, then the pitch parameters on pitch_deg
   (an unmodelled pitch effect cannot bend the stroke fit).
3. Standard errors and correlations from the Jacobian at the optimum (s^2 (J^T J)^-1, within
   each stage; NaN across the stages); pairs
   with |correlation| above `INSEPARABLE_CORRELATION` and parameters whose relative standard
   error exceeds `UNDETERMINED_REL_SE` are reported as what the data cannot separate.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, cast

import numpy as np
from scipy import optimize

from flaair_analysis.evidence import Evidence, EvidenceFit, fit_evidence
from flaair_model.effects import TRUTH_CHANNELS
from flaair_model.model import Model
from flaair_sensors.core.characterization import tiled_transfer

from .run_evidence import STATE_STEP_RAD, RunEvidence
from .runs import Run
from .vocabulary import PLANT_PARAMETERS

__all__ = [
    "INSEPARABLE_CORRELATION",
    "UNDETERMINED_REL_SE",
    "PlantFit",
    "Stage",
    "StagedFit",
    "fit_initial_states",
    "fit_stages",
    "frequency_domain_start",
    "identify_plant",
    "inseparable_notes",
]

# |correlation| above which two parameters are reported as not separated
INSEPARABLE_CORRELATION = 0.95
# relative standard error above which a parameter is reported as undetermined
UNDETERMINED_REL_SE = 0.10
FIT_RANGE = 0.5  # each parameter is fitted within x(1 -+ FIT_RANGE) of its start (log space)
MAX_NFEV = 30  # least-squares iterations (each: one simulation of every run with every column)
FD_STEP = 1e-4  # finite-difference step in log space
# least-squares iterations of an initial-state fit (nearly linear: a few suffice)
STATE_MAX_NFEV = 8
DECIMATE = 4  # keep every k-th truth sample in the fit (noise stays white)
# Truth channel of plant parameters that are not fitted by default (the inertias scale their
# equation: fitted along with its damping and gain they are reported as inseparable).
_OTHER_CHANNELS = {"stroke_inertia_kg_m2": "stroke_deg", "pitch_inertia_kg_m2": "pitch_deg"}
_DESCRIBING = 8.0 / (3.0 * math.pi)  # |x'| x' ~ (8 / 3 pi) w A x' for a sine of amplitude A


@dataclass(frozen=True)
class PlantFit:
    """The plant parameters fitted to this robot.

    Attributes
    ----------
    model : the input model with the fitted plant parameters.
    keys : fitted parameter names (model.yaml `plant:` keys).
    values, nominal, start, stderr : {key: value} fitted, in the input model, from the frequency
        domain, and the fitted value's standard error.
    correlation : (p, p) correlation matrix of the estimates (order of `keys`).
    inseparable : sentences naming the combinations the data cannot separate.
    cost_before, cost_after : noise-weighted sum of squares of the truth residuals (nominal start
        and fitted), and n, the number of residuals.
    runs : the runs with their initial states fitted along with the plant.
    """

    model: Model
    keys: tuple[Any, ...]
    values: dict[str, Any]
    nominal: dict[str, Any]
    start: dict[str, Any]
    stderr: dict[str, Any]
    correlation: np.ndarray
    inseparable: tuple[Any, ...]
    cost_before: float
    cost_after: float
    n: int
    runs: tuple[Any, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: per parameter value, nominal, start, stderr; correlations; inseparable."""
        return {
            "parameters": {
                k: {
                    "value": self.values[k],
                    "nominal": self.nominal[k],
                    "start": self.start[k],
                    "stderr": self.stderr[k],
                    "relative_change": self.values[k] / self.nominal[k] - 1.0,
                }
                for k in self.keys
            },
            "correlation": {
                "order": list(self.keys),
                "matrix": [[_finite(x) for x in row] for row in self.correlation],
            },
            "inseparable": list(self.inseparable),
            "chi2_per_sample_before": self.cost_before / max(self.n, 1),
            "chi2_per_sample_after": self.cost_after / max(self.n, 1),
        }


def inseparable_notes(
    keys: Sequence[str], rel_se: Sequence[float] | np.ndarray, corr: np.ndarray, by: str
) -> list[str]:
    """What the data cannot separate, one sentence each: the pairs whose |correlation| is above
    `INSEPARABLE_CORRELATION`, the parameters whose relative standard error (`rel_se`, in the
    order of `keys`) is above `UNDETERMINED_REL_SE`; `by` names the data ("these runs").
    """
    notes = []
    for i in range(len(keys)):
        for j in range(i + 1, len(keys)):
            if abs(corr[i, j]) > INSEPARABLE_CORRELATION:
                notes.append(
                    f"{keys[i]} and {keys[j]} (correlation {corr[i, j]:+.3f}): {by} fix only "
                    "a combination of the two"
                )
    for i, k in enumerate(keys):
        if not rel_se[i] < UNDETERMINED_REL_SE:
            notes.append(f"{k}: relative standard error {rel_se[i]:.0%}, not determined by {by}")
    return notes


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _window_amplitude(x: np.ndarray, win: int, k: int) -> np.ndarray:
    blocks = x[: k * win].reshape(k, win)
    with np.errstate(invalid="ignore"):
        return cast(np.ndarray, math.sqrt(2.0) * np.nanstd(blocks, axis=1))


def frequency_domain_start(
    runs: Sequence[Run], model: Model, window_s: float = 0.025
) -> dict[str, Any]:
    """Plant parameters from the runs' transfer functions (module docstring, step 1).

    A parameter the linear solution leaves non-positive (or no usable window) keeps its model value.
    """
    pl = model.plant
    rows_s, rhs_s, rows_p, rhs_p = [], [], [], []
    for run in runs:
        phi = np.radians(run.stroke_deg)
        psi = np.radians(run.pitch_deg)
        freq, tf = tiled_transfer({"phi": phi, "psi": psi}, run.drive_v, run.fs_hz, window_s)
        win = max(8, round(window_s * run.fs_hz))
        amp = _window_amplitude(phi, win, freq.size)
        ok = (
            np.isfinite(freq)
            & np.isfinite(tf["phi"])
            & np.isfinite(tf["psi"])
            & (freq > 10.0)
            & (amp > 0)
        )
        w = 2.0 * math.pi * freq[ok]
        f_phi, f_psi, a = tf["phi"][ok], tf["psi"][ok], amp[ok]
        # stroke: K Phi + Gamma (j w^2 c A Phi) - G_a = I w^2 Phi
        cols = np.column_stack([f_phi, 1j * w * w * _DESCRIBING * a * f_phi, -np.ones_like(f_phi)])
        rows_s.append(cols)
        rhs_s.append(pl.stroke_inertia_kg_m2 * w * w * f_phi)
        # pitch: k_h Psi + c_p j w Psi - J_c w^2 Phi + D_p j w^2 c A Phi = I_p w^2 Psi
        cols = np.column_stack(
            [f_psi, 1j * w * f_psi, -w * w * f_phi, 1j * w * w * _DESCRIBING * a * f_phi]
        )
        rows_p.append(cols)
        rhs_p.append(pl.pitch_inertia_kg_m2 * w * w * f_psi)
    start = {k: float(getattr(pl, k)) for k in PLANT_PARAMETERS}

    def solve(rows: list[Any], rhs: list[Any]) -> np.ndarray | None:
        a = np.concatenate(rows) if rows else np.zeros((0, 1))
        b = np.concatenate(rhs) if rhs else np.zeros(0)
        if a.shape[0] < 2 * a.shape[1]:
            return None
        scale = np.maximum(np.abs(a).max(axis=0), 1e-300)
        a_ri = np.vstack([a.real, a.imag]) / scale
        sol, *_ = np.linalg.lstsq(a_ri, np.concatenate([b.real, b.imag]), rcond=None)
        return cast(np.ndarray | None, sol / scale)

    s = solve(rows_s, rhs_s)
    if s is not None:
        k, gamma, ga = s
        if k > 0:
            start["stroke_natural_frequency_hz"] = math.sqrt(k / pl.stroke_inertia_kg_m2) / (
                2.0 * math.pi
            )
        if gamma > 0:
            start["aero_damping_nm_s2"] = float(gamma)
        if ga > 0:
            start["actuator_gain_nm_per_v"] = float(ga)
    p = solve(rows_p, rhs_p)
    if p is not None:
        kh, cp, jc, dp = p
        if kh > 0:
            start["pitch_natural_frequency_hz"] = math.sqrt(kh / pl.pitch_inertia_kg_m2) / (
                2.0 * math.pi
            )
        for key, v in (
            ("hinge_damping_nm_s_per_rad", cp),
            ("inertial_coupling_kg_m2", jc),
            ("aero_coupling_nm_s2", dp),
        ):
            if v > 0:
                start[key] = float(v)
    # a start far outside the fit range is a failed estimate (e.g. effects the plant lacks)
    for key, v in start.items():
        nominal = float(getattr(pl, key))
        if not (nominal / (1.0 + FIT_RANGE) < v < nominal * (1.0 + FIT_RANGE)):
            start[key] = nominal
    return start


def with_plant(model: Model, values: Mapping[str, float]) -> Model:
    """`model` with plant parameters replaced."""
    return replace(model, plant=replace(model.plant, **{k: float(v) for k, v in values.items()}))


def _plant_setter(model: Model, keys: Sequence[str]) -> Callable[[np.ndarray], Model]:
    """Fit space (log values of `keys`) to `model` with them."""
    return lambda u: with_plant(model, dict(zip(keys, np.exp(u), strict=True)))


@dataclass(frozen=True)
class Stage:
    """One stage of the plant's staged fit: its keys, the evidence that sees its side, the
    starts tried and the fit range (log space).
    """

    keys: tuple[str, ...]
    pieces: tuple[Evidence, ...]
    starts: tuple[np.ndarray, ...]
    lower: np.ndarray
    upper: np.ndarray
    max_nfev: int
    birge_refit: float | None = None
    tol: float = 1e-10
    to_model: Callable[[np.ndarray], Model] | None = None  # default: log values of the keys
    steps: np.ndarray | None = None  # default: FD_STEP for every key


@dataclass(frozen=True)
class StagedFit:
    """The outcome of `fit_stages`: the model and runs after every stage, the fitted values, the
    log-space standard deviations and the correlation within each stage (order of the keys;
    NaN across stages), and each stage with its fit.
    """

    model: Model
    runs: tuple[Run, ...]
    values: dict[str, float]
    sd: np.ndarray
    correlation: np.ndarray
    stages: tuple[tuple[str, Stage, EvidenceFit], ...]


def fit_stages(
    model: Model,
    runs: Sequence[Run],
    keys: Sequence[str],
    stage_of: Callable[[str, tuple[str, ...], Model, list[Run]], Stage | None],
) -> StagedFit:
    """The plant fitted upstream first: the stroke keys on what sees the stroke, then, with them
    fixed, the pitch keys on what sees the pitch (an unmodelled pitch effect cannot bend the
    stroke fit). `stage_of(channel, keys, model, runs)` gives each stage (None: skipped) from
    the model and runs as the earlier stages left them; a run set among its pieces has its
    initial states carried on.
    """
    keys = tuple(keys)
    values: dict[str, float] = {}
    sd = np.full(len(keys), np.nan)
    corr = np.full((len(keys), len(keys)), np.nan)
    current, runs, done = model, list(runs), []
    for channel in TRUTH_CHANNELS:
        side_keys = tuple(k for k in keys if {**PLANT_PARAMETERS, **_OTHER_CHANNELS}[k] == channel)
        stage = stage_of(channel, side_keys, current, runs)
        if stage is None:
            continue
        to_model = stage.to_model or _plant_setter(current, side_keys)
        fit = fit_evidence(
            list(stage.pieces),
            to_model,
            list(stage.starts),
            stage.lower,
            stage.upper,
            np.full(len(side_keys), FD_STEP) if stage.steps is None else stage.steps,
            max_nfev=stage.max_nfev,
            tol=stage.tol,
            birge_refit=stage.birge_refit,
        )
        current = to_model(fit.x)
        out = {k: float(getattr(current.plant, k)) for k in side_keys}
        for piece, nuisance in zip(stage.pieces, fit.nuisance, strict=True):
            if isinstance(piece, RunEvidence) and piece.side is not None:
                runs = piece.runs_at(nuisance)
        values.update(out)
        idx = [keys.index(k) for k in side_keys]
        e = np.sqrt(np.abs(np.diag(fit.covariance)))
        sd[idx] = e
        with np.errstate(invalid="ignore", divide="ignore"):
            corr[np.ix_(idx, idx)] = fit.covariance / np.outer(e, e)
        done.append((channel, stage, fit))
    return StagedFit(current, tuple(runs), values, sd, corr, tuple(done))


def identify_plant(
    runs: Sequence[Run],
    model: Model,
    noise: Mapping[str, float],
    keys: Sequence[str] = tuple(PLANT_PARAMETERS),
    max_nfev: int = MAX_NFEV,
    decimate: int = DECIMATE,
    state_channels: Sequence[str] = (),
    centre: Mapping[str, float] | None = None,
) -> PlantFit:
    """Fit this robot's plant parameters to the truth angles of its runs (module docstring).

    Upstream first: the stroke parameters on stroke_deg, then, with them fixed, the pitch
    parameters on pitch_deg (so that an unmodelled pitch effect cannot bend the stroke fit).

    Parameters
    ----------
    runs
        Checked runs (`runs.check_runs`), each with its measured initial state.
    model
        Model to start from (its effects are kept as they are).
    noise
        Noise RMS per channel (degrees for the truth channels), the residual weights.
    keys
        Plant parameters to fit.
    max_nfev, decimate
        Least-squares iterations per stage; keep every k-th sample.
    state_channels
        Truth channels whose initial states are fitted even where no plant parameter is (after an
        effect joined the model, the states fitted with the old plant are re-fitted).
    centre
        {key: value} the fit range (x(1 -+ FIT_RANGE)) is centred on; default: `model`'s values. A
        re-identification (after an effect joined the model) keeps the range of the first one: a
        parameter bent by the missing effect must be able to come back.
    """
    keys = tuple(keys)
    nominal = {k: float(getattr(model.plant, k)) for k in keys}
    start = {k: float(getattr(model.plant, k)) for k in keys}
    if keys:
        start.update({k: v for k, v in frequency_domain_start(runs, model).items() if k in keys})

    def stage_of(
        channel: str, stage: tuple[str, ...], current: Model, now: list[Run]
    ) -> Stage | None:
        if not stage and channel not in state_channels:
            return None
        side = "stroke" if channel == "stroke_deg" else "pitch"
        omega = 2.0 * math.pi * float(getattr(current.plant, f"{side}_natural_frequency_hz"))
        u_nominal = np.log([float(getattr(current.plant, k)) for k in stage])
        u_centre = np.log([float(centre[k]) for k in stage]) if centre is not None else u_nominal
        # the better of the model's and the frequency-domain values starts the fit
        return Stage(
            stage,
            (RunEvidence(now, noise, decimate, (channel,), side, omega),),
            (u_nominal, np.log([start[k] for k in stage])),
            u_centre - math.log1p(FIT_RANGE),
            u_centre + math.log1p(FIT_RANGE),
            max_nfev,
        )

    staged = fit_stages(model, runs, keys, stage_of)
    values, sd, corr = staged.values, staged.sd, staged.correlation
    fits = [fit for _, _, fit in staged.stages]
    cost_before = sum(fit.start_costs[0] for fit in fits)
    cost_after = sum(fit.cost for fit in fits)
    n = sum(fit.n[0] for fit in fits)
    current, runs = staged.model, list(staged.runs)
    stderr = {k: float(values[k] * sd[i]) for i, k in enumerate(keys)}  # log-space SE x value
    inseparable = inseparable_notes(keys, sd, corr, "these runs")
    return PlantFit(
        model=current,
        keys=keys,
        values=values,
        nominal=nominal,
        start=start,
        stderr=stderr,
        correlation=corr,
        inseparable=tuple(inseparable),
        cost_before=cost_before,
        cost_after=cost_after,
        n=n,
        runs=tuple(runs),
    )


def _state_residuals_and_jacobian(
    resid: RunEvidence, model: Model, scale: np.ndarray, step: float = STATE_STEP_RAD
) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    """The residual and the Jacobian of one run's initial state u in fit space (state = u * scale),
    both from one batch simulation (forward differences of `step`); the last point's pair is kept.
    """
    cache: dict[tuple[Any, ...], tuple[np.ndarray, np.ndarray]] = {}

    def fun_and_jac(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = tuple(np.round(u, 14))
        if key not in cache:
            cache.clear()
            us = np.vstack([u, u[None, :] + step * np.eye(4)])
            rows = resid.rows_from([model] * 5, [us * scale])
            cache[key] = (rows[0], ((rows[1:] - rows[0]) / step).T)
        return cache[key]

    return (lambda u: fun_and_jac(u)[0]), (lambda u: fun_and_jac(u)[1])


def fit_initial_states(
    runs: Sequence[Run],
    model: Model,
    noise: Mapping[str, float],
    channels: Sequence[str],
    max_nfev: int = STATE_MAX_NFEV,
    decimate: int = DECIMATE,
    step_scale: float = 1.0,
) -> tuple[tuple[Run, ...], float, float]:
    """Each run's initial state [phi, phi', psi, psi'] fitted on `channels` with `model` fixed.

    A sensor resolves the motion far better than a video-rate truth: once the sensor chain is
    modelled, its channel pins the state the truth leaves loose (a transient the truth cannot see
    is a gap on the sensor). Least squares per run (Gauss-Newton, trust-region reflective) on the
    noise-weighted residuals of `channels`, from the run's current state; rates scaled by the
    natural frequencies. Returns (runs with the fitted states, cost before, cost after).
    step_scale multiplies the finite-difference step (`STATE_STEP_RAD`): with a sign() term in
    the model the motion jumps as the start moves a zero crossing across an integration stage,
    and at the plain step the Jacobian is noise (a friction's start transient was left at 4.6x
    the sensor's noise; at 30x the step, at noise).
    """
    w = (
        2.0
        * math.pi
        * np.array(
            [
                model.plant.stroke_natural_frequency_hz,
                model.plant.stroke_natural_frequency_hz,
                model.plant.pitch_natural_frequency_hz,
                model.plant.pitch_natural_frequency_hz,
            ]
        )
    )
    scale = np.where(np.arange(4) % 2 == 1, w, 1.0)  # state = u * scale: (x, x'/omega) in fit space
    out, before, after = [], 0.0, 0.0
    for run in runs:
        resid = RunEvidence([run], noise, decimate, channels)
        x_run = np.zeros(4) if run.mechanical0 is None else np.asarray(run.mechanical0, float)
        residual, jacobian = _state_residuals_and_jacobian(
            resid, model, scale, STATE_STEP_RAD * step_scale
        )
        u0 = x_run / scale
        f0 = residual(u0)
        sol = optimize.least_squares(
            residual,
            u0,
            jac=jacobian,
            method="trf",
            max_nfev=max_nfev,
            x_scale=1.0,
            xtol=1e-8,
            ftol=1e-8,
            gtol=1e-10,
        )
        f1 = residual(sol.x)
        c0, c1 = float(np.dot(f0, f0)), float(np.dot(f1, f1))
        keep = c1 < c0
        out.append(replace(run, mechanical0=sol.x * scale) if keep else run)
        before += c0
        after += min(c0, c1)
    return tuple(out), before, after
