"""Least-squares fitting of effect (and plant) parameters on folds of the runs."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, cast

import numpy as np
from numba import njit
from scipy import optimize

from flaair_model.effects import SENSOR_CHANNELS
from flaair_model.model import Model, effect_params, with_effect_on, with_effects
from flaair_model.settings import DiscrepancySettings
from flaair_model.terms import DiscoveredTerm, TermSignals
from flaair_model.validation import ModelError
from flaair_sim.core.plant import sensor_chain

from .runs import (
    MotionCache,
    Run,
    measured_motion,
    mechanics_model,
    sensor_gain_v_per_deg,
    sensor_voltage,
    simulate_motion,
    simulate_runs,
)
from .vocabulary import CHANNELS, SENSOR_SIDE, UPSTREAM_TRUTH, EffectSpec

# ------------------------------------------------------------------------------------ fitting


@dataclass(frozen=True, eq=False)
class Fold:
    """A run and the sample range judged in it (whole run, or half of a lone run)."""

    run: int
    start: int
    stop: int
    name: str


def fold_nrmse(
    runs: Sequence[Run], folds: Sequence[Fold], per_fold: Sequence[Model]
) -> dict[str, Any]:
    """NRMSE per channel of fold k predicted by per_fold[k], pooled over the folds (fold means
    removed, missing truth skipped).
    """
    rss = {c: 0.0 for c in CHANNELS}
    ss = {c: 0.0 for c in CHANNELS}
    for f, model in zip(folds, per_fold, strict=True):
        run = runs[f.run]
        sim = simulate_runs([model], [run])[0][0]
        for c in CHANNELS:
            r = (run.channel(c) - sim[c])[f.start : f.stop]
            x = run.channel(c)[f.start : f.stop]
            ok = np.isfinite(r)
            r, x = r[ok] - r[ok].mean(), x[ok] - x[ok].mean()
            rss[c] += float(np.dot(r, r))
            ss[c] += float(np.dot(x, x))
    return {c: math.sqrt(rss[c] / ss[c]) if ss[c] > 0 else math.nan for c in CHANNELS}


def make_folds(runs: Sequence[Run]) -> tuple[Fold, ...]:
    if len(runs) >= 2:
        return tuple(Fold(i, 0, r.n, r.name) for i, r in enumerate(runs))
    r = runs[0]
    h = r.n // 2
    return (Fold(0, 0, h, f"{r.name}[first half]"), Fold(0, h, r.n, f"{r.name}[second half]"))


@njit(cache=True)
def _fold_angle_changes(
    out: np.ndarray, change: np.ndarray, idx: np.ndarray, first: int, weight: float
) -> None:
    """Rows ``first ..`` of `out` (samples, m): each column of ``change[idx]`` (rad) in degrees,
    less its mean over the fold, negated and divided by `weight`; in one pass over the samples
    with numpy's arithmetic (the degrees' product, each column's sum in sample order), so the
    bits are those of the array expression it replaces (tests/test_angle_columns.py).
    """
    k, m = idx.size, change.shape[1]
    to_deg = 180.0 / math.pi
    total = np.zeros(m)
    for t in range(k):
        row = change[idx[t]]
        for j in range(m):
            total[j] += row[j] * to_deg
    mean = total / k
    for t in range(k):
        row = change[idx[t]]
        for j in range(m):
            out[first + t, j] = -(row[j] * to_deg - mean[j]) / weight


class ResidualProblem:
    """Weighted residuals of one channel, for a family of models, on a set of folds.

    The weight (noise RMS; truth-referenced: sqrt(noise_V^2 + (g noise_deg)^2) with the gain g
    of `weight_model`) is fixed per problem so that costs of different models compare.
    """

    def __init__(
        self,
        runs: Sequence[Run],
        folds: Sequence[Fold],
        channel: str,
        sigma: float,
        truth_referenced: bool,
        decimate: int,
        truth_sigma: float = 0.0,
        weight_model: Model | None = None,
        motion: MotionCache | None = None,
    ) -> None:
        self.runs = runs
        self.motion = motion if motion is not None else MotionCache()
        self._measured: dict[tuple[Model, int], Any] = {}
        self.folds = list(folds)
        self.channel = channel
        self.truth_referenced = truth_referenced and channel in SENSOR_CHANNELS
        self.weight = sigma
        if self.truth_referenced:
            g = sensor_gain_v_per_deg(cast(Model, weight_model), channel)  # given with a truth ref
            self.weight = math.sqrt(sigma**2 + (g * truth_sigma) ** 2)
        self.run_ids = sorted({f.run for f in self.folds})
        self.idx = []
        for f in self.folds:
            sl = np.arange(f.start, f.stop, decimate)
            ok = np.isfinite(runs[f.run].channel(channel)[sl])
            if self.truth_referenced:
                ok &= np.isfinite(runs[f.run].channel(UPSTREAM_TRUTH[channel])[sl])
            self.idx.append(sl[ok])

    def n_per_fold(self) -> list[int]:
        """Residual samples per fold."""
        return [int(i.size) for i in self.idx]

    def signal_ss(self) -> float:
        """Weighted sum of squares of the measured channel about its fold means."""
        total = 0.0
        for f, idx in zip(self.folds, self.idx, strict=True):
            x = self.runs[f.run].channel(self.channel)[idx]
            total += float(np.sum(((x - x.mean()) / self.weight) ** 2))
        return total

    def term_signals(self, model: Model) -> dict[int, TermSignals]:
        """{run id: the signals a term at this sensor channel reads along `model`}: its motion
        (with the judged angle measured, where truth-referenced) and both chains' outputs before
        any sensor term, as `residuals` gives them to the sensor chain.
        """
        side = SENSOR_SIDE[self.channel]
        mech = mechanics_model(model)
        chain = replace(
            model, discovered=tuple(t for t in model.discovered if t.acts_on not in SENSOR_CHANNELS)
        )
        motion = self.motion.get([model], self.runs, self.run_ids)
        vref = model.sensors.reference_voltage_v
        out = {}
        for j in self.run_ids:
            run = self.runs[j]
            stroke, pitch = motion[(mech, j)]
            if self.truth_referenced:
                stroke, pitch = measured_motion(run, stroke, pitch, side)
            vs, vp = sensor_chain(chain, run.fs_hz, stroke, pitch, run.drive_v)
            out[j] = TermSignals.of_block(
                run.fs_hz,
                run.drive_v,
                phi=stroke,
                psi=pitch,
                stroke_sensor_v=vs - vref,
                pitch_sensor_v=vp - vref,
            )
        return out

    def output_columns(self, features: Mapping[int, np.ndarray]) -> np.ndarray:
        """The weighted residual's change per unit of a term added to this sensor channel's
        output, with feature {run id: per sample}: one column, the folds' samples stacked as
        `residuals` stacks them.
        """
        cols = []
        for f, idx in zip(self.folds, self.idx, strict=True):
            x = features[f.run][idx]
            cols.append(-(x - x.mean()) / self.weight)
        return np.concatenate(cols)

    def angle_columns(self, changes: Mapping[int, np.ndarray]) -> np.ndarray:
        """The weighted residual's change of a truth channel, one row per column of
        ``changes[run]`` ((n, m): the judged angle's change in rad at each sample): the folds'
        samples stacked as `residuals` stacks them.
        """
        m = next(iter(changes.values())).shape[1]
        if m < 2 or any(idx.size < 2 for idx in self.idx):
            # one column: numpy sums a fold's samples pairwise (they are contiguous), and the
            # ranking's ties are decided in the last bits; a fold of under two samples: numpy's
            # concatenation then picks another memory layout
            cols = []
            for f, idx in zip(self.folds, self.idx, strict=True):
                x = np.degrees(changes[f.run][idx].T)
                cols.append(-(x - x.mean(axis=1, keepdims=True)) / self.weight)
            return np.concatenate(cols, axis=1)
        # (samples, m) in memory, returned as its (m, samples) view: the layout numpy's
        # concatenation of the transposed folds had
        out = np.empty((sum(idx.size for idx in self.idx), m))
        first = 0
        for f, idx in zip(self.folds, self.idx, strict=True):
            _fold_angle_changes(out, changes[f.run], idx, first, float(self.weight))
            first += idx.size
        return out.T

    def residuals(self, models: Sequence[Model]) -> list[list[np.ndarray]]:
        """``res[i][k]``: weighted residual of model i on fold k (fold mean removed)."""
        models = list(models)
        motion = (
            self.motion.get(models, self.runs, self.run_ids)
            if self.channel in SENSOR_CHANNELS
            else None
        )
        # truth channels: the motion of every model on every run (degrees only where judged)
        sims = (
            {}
            if motion is not None
            else {j: simulate_motion(models, self.runs[j]) for j in self.run_ids}
        )
        angle = "stroke_rad" if self.channel == "stroke_deg" else "pitch_rad"
        out = []
        side = SENSOR_SIDE.get(self.channel, "")  # a sensor channel's (motion is for them)
        for i, m in enumerate(models):
            row = []
            mech = mechanics_model(m) if motion is not None else m  # m: unused without motion
            for f, idx in zip(self.folds, self.idx, strict=True):
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
                    r = run.channel(self.channel)[idx] - np.degrees(
                        getattr(sims[f.run], angle)[i, idx]
                    )
                if not np.all(np.isfinite(r)):
                    r = np.where(np.isfinite(r), r, 1e6 * self.weight)
                row.append((r - r.mean()) / self.weight)
            out.append(row)
        return out


def apply_values(
    base: Model,
    specs: Sequence[EffectSpec],
    values: Sequence[float],
    channels: Mapping[str, str | None] | None = None,
) -> Model:
    """`base` with the specs' parameters at physical `values`: plant parameters replaced, effects
    added (the parameters of one effect merged into one entry; an effect already in `base` keeps
    the parameters not fitted), library terms set. A sensor effect is set on its spec's chain
    only (the other chain keeps its own value); channels: effect -> 'both' sets it on both
    chains. The one way a fit's parameters (`EffectSpec`: plant, effect, term) reach a model.
    """
    plant = {}
    effects: dict[str, Any] = {}
    terms: dict[str, Any] = {}
    for s, v in zip(specs, values, strict=True):
        if s.is_plant:
            plant[s.key] = float(v)
            continue
        (terms if s.is_term else effects).setdefault(s.name, {}).update(s.params(v))
    model = replace(base, plant=replace(base.plant, **plant)) if plant else base
    if terms:
        places = {s.name: s.term_place for s in specs if s.is_term}
        model = with_terms(
            model,
            [
                DiscoveredTerm(*places[name], p.pop("coefficient"), tuple(p.items()))
                for name, p in terms.items()
            ],
        )
    for s in specs:
        if s.is_plant or s.is_term or s.name not in effects:
            continue
        params = effects.pop(s.name)
        if s.channel_param is None and (old := model.effect(s.name)) is not None:
            params = {**effect_params(old), **params}
        if s.channel_param is None or (channels or {}).get(s.name) == "both":
            model = with_effects(
                model, {s.name: {**params, **({"channel": "both"} if s.channel_param else {})}}
            )
        else:
            model = with_effect_on(
                model, s.name, s.channel_param, {k: v for k, v in params.items() if k != "channel"}
            )
    return model


def with_terms(model: Model, terms: Sequence[DiscoveredTerm]) -> Model:
    """`model` with `terms` added (each replacing a term of the same kind on the same site)."""
    places = {(t.kind, t.acts_on) for t in terms}
    kept = tuple(t for t in model.discovered if (t.kind, t.acts_on) not in places)
    return replace(model, discovered=kept + tuple(terms))


def models_for(base: Model, specs: Sequence[EffectSpec], xs: np.ndarray) -> list[Model]:
    """Models with the parameters of `specs` at the fit-space rows `xs`."""
    return [
        apply_values(base, specs, [s.from_fit(u) for s, u in zip(specs, x, strict=True)])
        for x in np.atleast_2d(xs)
    ]


def spec_value(model: Model, spec: EffectSpec) -> float:
    """Current physical value of `spec`'s parameter in `model` (plant field or effect parameter;
    a sensor effect's value on the spec's chain).
    """
    if spec.is_plant:
        return float(getattr(model.plant, spec.key))
    if spec.is_term:
        term = next(t for t in model.discovered if (t.kind, t.acts_on) == spec.term_place)
        return term.coefficient if spec.key == "coefficient" else dict(term.shape)[spec.key]
    if spec.channel_param is not None:
        return float(getattr(model.effect_on(spec.name, spec.channel_param), spec.key))
    return float(getattr(model.effect(spec.name), spec.key))


@dataclass(frozen=True)
class FitResult:
    x: np.ndarray  # fit-space optimum
    se: np.ndarray  # fit-space standard errors (inf: not identifiable)
    rss: float  # weighted RSS
    n: int
    rss_per_fold: tuple[Any, ...]


def fit_specs(
    base: Model,
    specs: Sequence[EffectSpec],
    problem: ResidualProblem,
    x0: np.ndarray,
    settings: DiscrepancySettings,
    grid: bool = True,
    step_scale: float = 1.0,
) -> FitResult:
    """Least-squares fit of the specs' parameters on `problem` (grid start, then TRF).

    step_scale multiplies the specs' finite-difference steps of the Jacobian (not the trust
    region's scaling): a model whose simulated motion is not smooth in its parameters (a term
    with sign(): each zero crossing that passes an integration stage moves the motion by a jump)
    has a cost that is rough at the specs' own steps, and a fit stalls where it starts.
    """
    specs = list(specs)
    lo = np.array([s.to_fit(s.lower) for s in specs])
    hi = np.array([s.to_fit(s.upper) for s in specs])
    steps = np.array([s.step for s in specs]) * step_scale
    x0 = np.clip(np.asarray(x0, float), lo, hi)
    if grid and specs[0].grid:
        s = specs[0]
        xs = np.array(
            [[s.to_fit(v), *x0[1:]] for v in s.grid if s.lower <= v <= s.upper] + [list(x0)]
        )
        res = problem.residuals(models_for(base, specs, xs))
        with np.errstate(over="ignore"):  # a start that drives the model wild costs inf
            costs = [sum(float(np.dot(r, r)) for r in row) for row in res]
        x0 = xs[int(np.argmin(costs))]

    cache: dict[tuple[Any, ...], Any] = {}

    def stack(rows: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(rows) if rows else np.zeros(0)

    def fun(x: np.ndarray) -> np.ndarray:
        # the exact point: a key rounded to 1e-15 served one point's residuals for another
        # wherever a fit-space value is that small (a hinge drag's 1e-12 N m s^2 in its own units)
        key = tuple(np.asarray(x, float).tolist())
        if key not in cache:
            cache.clear()
            cache[key] = stack(problem.residuals(models_for(base, specs, x[None, :]))[0])
        return cast(np.ndarray, cache[key])

    def jac(x: np.ndarray) -> np.ndarray:
        f0 = fun(x)
        h = np.where(x + steps <= hi, steps, -steps)
        xs = np.repeat(x[None, :], len(specs), axis=0) + np.diag(h)
        rows = problem.residuals(models_for(base, specs, xs))
        return np.column_stack([(stack(rows[i]) - f0) / h[i] for i in range(len(specs))])

    x_scale = np.maximum(np.abs(steps) / step_scale * 100.0, 1e-12)
    try:
        # a trial step that drives the model wild costs inf, and the solver rejects it (its
        # arithmetic on that inf is what numpy would call invalid)
        with np.errstate(over="ignore", invalid="ignore"):
            sol = optimize.least_squares(
                fun,
                x0,
                jac=jac,
                bounds=(lo, hi),
                method="trf",
                x_scale=x_scale,
                max_nfev=settings.max_nfev,
                xtol=1e-6,
                ftol=1e-9,
                gtol=1e-9,
            )
        x = sol.x
    except (ValueError, ModelError):
        x = x0
    f = fun(x)
    J = jac(x)
    n = f.size
    p = len(specs)
    with np.errstate(over="ignore", invalid="ignore"):  # a fit that ran away: inf, never a number
        rss = float(np.dot(f, f))
        jtj = J.T @ J
        col = np.sqrt(np.sum(J * J, axis=0))
    s2 = rss / max(n - p, 1)
    se = np.full(p, math.inf)
    try:
        if np.all(np.isfinite(jtj)) and np.linalg.matrix_rank(jtj) == p:
            cov = np.linalg.inv(jtj) * s2
            d = np.diag(cov)
            se = np.where(d > 0, np.sqrt(np.abs(d)), math.inf)
    except np.linalg.LinAlgError:
        pass
    # a parameter whose column barely moves the residual is not identifiable here
    se = np.where(col * np.abs(steps) < 1e-9 * math.sqrt(max(rss, 1e-300)), math.inf, se)
    sizes = problem.n_per_fold()
    per_fold, k = [], 0
    for m in sizes:
        per_fold.append(float(np.dot(f[k : k + m], f[k : k + m])))
        k += m
    return FitResult(
        x=np.asarray(x, float), se=np.asarray(se, float), rss=rss, n=n, rss_per_fold=tuple(per_fold)
    )
