"""An effect candidate judged by rules R1-R6: per-run fits, held-out prediction, BIC,
consistency (the candidate's evidence, `CandidateEvidence`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from flaair_analysis.evidence import (
    distance_from_null,
    excess_of_rss,
    gap_drop,
    passes_drop,
    passes_z,
)
from flaair_model.effects import SENSOR_CHANNELS
from flaair_model.model import Model, with_effects
from flaair_model.settings import DiscrepancySettings

from .diagnosis import drive_tracks
from .fitting import FitResult, Fold, ResidualProblem, fit_specs, make_folds, models_for
from .runs import MotionCache, Run, simulate_runs
from .vocabulary import UPSTREAM_TRUTH, EffectSpec

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
    consistency_p : p-value of the per-run scatter test per effect (NaN: fewer than 2 runs identify
        it).
    heldout_nrmse_before, heldout_nrmse_after : channel NRMSE on held-out runs without / with it.
    heldout_drop : 1 - after / before.
    heldout_gap_drop : the same for the model error above noise (R1): 1 - sqrt(max(RSS_after - n, 0)
        / max(RSS_before - n, 0)) in noise-weighted units.
    delta_bic_heldout : held-out BIC change (negative favours the effect).
    delta_bic_fit : in-sample BIC change on all runs.
    rules : {rule: passed}.
    accepted : all rules passed.
    same_on_both : (the effect already found on the other sensor) R5: the two chains' values agree,
        so one value acts on both; False: each chain keeps its own; None: not such a candidate.
    """

    labels: tuple[Any, ...]
    channel: str
    values: tuple[Any, ...]
    se: tuple[Any, ...]
    z: tuple[Any, ...]
    per_run: tuple[Any, ...]
    consistency_p: tuple[Any, ...]
    heldout_nrmse_before: float
    heldout_nrmse_after: float
    heldout_drop: float
    heldout_gap_drop: float
    delta_bic_heldout: float
    delta_bic_fit: float
    rules: dict[str, Any]
    accepted: bool
    same_on_both: bool | None = None
    heldout_models: tuple[Any, ...] = ()  # fold k's prediction: fitted on the other folds

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready evidence."""
        return {
            "candidate": "+".join(self.labels),
            "judged_on": self.channel,
            "values": list(self.values),
            "standard_errors": list(self.se),
            "z_from_null": list(self.z),
            "per_run": [[{"run": n, "value": v, "se": s} for n, v, s in pr] for pr in self.per_run],
            "consistency_p": list(self.consistency_p),
            "heldout_nrmse_before": self.heldout_nrmse_before,
            "heldout_nrmse_after": self.heldout_nrmse_after,
            "heldout_drop": self.heldout_drop,
            "heldout_gap_drop": self.heldout_gap_drop,
            "delta_bic_heldout": self.delta_bic_heldout,
            "delta_bic_fit": self.delta_bic_fit,
            "rules": dict(self.rules),
            "accepted": self.accepted,
            "same_on_both_sensors": self.same_on_both,
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
    parameters: dict[str, Any]
    evidence: dict[str, Any]
    explains: tuple[Any, ...]


def bic(rss_list: Sequence[float], n_list: Sequence[int], k: int) -> float:
    """BIC of per-fold residual sums of squares `rss_list` (of `n_list` samples) with `k`
    parameters.
    """
    n_tot = sum(n_list)
    val = sum(
        n * math.log(max(r, 1e-300) / n) for r, n in zip(rss_list, n_list, strict=True) if n > 0
    )
    return val + k * math.log(max(n_tot, 2))


def rss_gap_drop(rss_before: float, rss_after: float, n: int) -> float:
    """R1's drop (`evidence.gap_drop`) of one channel's `n` noise-weighted residuals, whose sum of
    squares goes from `rss_before` to `rss_after`.
    """
    return gap_drop(excess_of_rss(rss_before, n), excess_of_rss(rss_after, n))


def _consistency(
    est: Sequence[tuple[float, float]], size: float, settings: DiscrepancySettings
) -> float:
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


class AnalysisContext:
    """Data shared by the candidate evaluations of one analysis."""

    def __init__(
        self,
        runs: Sequence[Run],
        noise: Mapping[str, float],
        settings: DiscrepancySettings,
        tracks: Sequence[tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> None:
        self.runs = tuple(runs)
        self.noise = dict(noise)
        self.settings = settings
        self.folds = make_folds(self.runs)
        self.tracks = list(tracks) if tracks is not None else drive_tracks(self.runs)
        self.motion = MotionCache()

    def problem(
        self, channel: str, folds: Sequence[Fold], truth_referenced: bool, weight_model: Model
    ) -> ResidualProblem:
        """Residual problem of `channel` on `folds`."""
        truth_sigma = self.noise[UPSTREAM_TRUTH[channel]] if channel in SENSOR_CHANNELS else 0.0
        return ResidualProblem(
            self.runs,
            folds,
            channel,
            self.noise[channel],
            truth_referenced,
            self.settings.decimate,
            truth_sigma,
            weight_model,
            self.motion,
        )


def _reach_deg(ctx: AnalysisContext, model: Model) -> float:
    sims = simulate_runs([model], ctx.runs)[0]
    return max(float(np.max(s["stroke_deg"])) for s in sims)


def _phys_se(spec: EffectSpec, u: float, se_u: float) -> float:
    if not math.isfinite(se_u):
        return math.inf
    return spec.from_fit(u) * se_u if spec.log else se_u * spec.unit


def _null_fit_value(spec: EffectSpec) -> float:
    if math.isfinite(spec.null) and (not spec.log or spec.null > 0):
        return spec.to_fit(spec.null)
    if math.isinf(spec.null):
        return spec.to_fit(spec.upper)
    return spec.to_fit(spec.lower)


def same_on_both(
    spec: EffectSpec,
    v_old: float,
    se_old: float,
    v_new: float,
    se_new: float,
    settings: DiscrepancySettings,
) -> float | None:
    """R5: one sensor effect's values on the two chains agree within 3 combined standard errors plus
    `consistency_rel_tol` of its size: their inverse-variance mean, else None (one value per chain).
    """
    tol = 3.0 * math.hypot(se_old, se_new) + settings.consistency_rel_tol * spec.effect_size(v_old)
    if not abs(v_new - v_old) <= tol:
        return None
    w_old = 1 / se_old**2 if 0 < se_old < math.inf else 0.0
    w_new = 1 / se_new**2 if 0 < se_new < math.inf else 0.0
    return (w_old * v_old + w_new * v_new) / (w_old + w_new) if w_old + w_new > 0 else v_new


def _pooled_fit(
    per_fold: Sequence[FitResult],
    x0: np.ndarray,
    specs: Sequence[EffectSpec],
    all_prob: ResidualProblem,
    base: Model,
) -> FitResult:
    """The all-run estimate: inverse-variance pooling of the per-run fits (equivalent to one fit
    on all runs for independent runs); if no run identifies the effect, the best run's value.
    """
    p = len(specs)
    identified = [pf for pf in per_fold if np.all(np.isfinite(pf.se)) and np.all(pf.se > 0)]
    if identified:
        x_all = np.array(
            [_pooled([(pf.x[j], pf.se[j]) for pf in identified], x0[j]) for j in range(p)]
        )
        se_all = np.array(
            [1.0 / math.sqrt(sum(1.0 / pf.se[j] ** 2 for pf in identified)) for j in range(p)]
        )
    else:
        x_all = min(per_fold, key=lambda pf: pf.rss / max(pf.n, 1)).x
        se_all = np.full(p, math.inf)
    res_all = all_prob.residuals(models_for(base, specs, x_all[None, :]))[0]
    with np.errstate(over="ignore"):  # a fit that drove the model wild costs inf
        rss_per_fold = tuple(float(np.dot(r, r)) for r in res_all)
    return FitResult(
        x=x_all,
        se=se_all,
        rss=sum(rss_per_fold),
        n=sum(r.size for r in res_all),
        rss_per_fold=rss_per_fold,
    )


def _heldout_models(
    per_fold: Sequence[FitResult], null_x: np.ndarray, specs: Sequence[EffectSpec], base: Model
) -> list[Model]:
    """Each fold's model: the pooled estimates of the other folds."""
    out = []
    for k in range(len(per_fold)):
        others = [per_fold[i] for i in range(len(per_fold)) if i != k]
        x_ho = [
            _pooled([(pf.x[j], pf.se[j]) for pf in others], null_x[j]) for j in range(len(specs))
        ]
        out.append(models_for(base, specs, np.array([x_ho]))[0])
    return out


def _per_parameter(
    ctx: AnalysisContext,
    base: Model,
    specs: Sequence[EffectSpec],
    fit_all: FitResult,
    values: Sequence[float],
    se_phys: Sequence[float],
    per_fold: Sequence[FitResult],
) -> tuple[list[float], list[float], list[Any], list[int], list[bool]]:
    """Per parameter: z from its null value (a stop: from the stroke the model reaches), the
    consistency p of the per-run estimates, the estimates, how many runs identify it, and
    whether it ended inside its bounds.
    """
    z: list[float] = []
    cons: list[float] = []
    per_run: list[Any] = []
    n_ident: list[int] = []
    inside: list[bool] = []
    reach = None
    for j, s in enumerate(specs):
        lo, hi = s.to_fit(s.lower), s.to_fit(s.upper)
        near = 1e-3 * (hi - lo)
        at_lo = fit_all.x[j] - lo < near and s.lower != s.null
        at_hi = hi - fit_all.x[j] < near and s.upper != s.null
        inside.append(not (at_lo or at_hi))
        v, e = values[j], se_phys[j]
        if math.isinf(s.null) and reach is None:
            reach = _reach_deg(ctx, base)
        z.append(distance_from_null(v, e, s.null, math.inf if reach is None else reach))
        est = [(s.from_fit(pf.x[j]), _phys_se(s, pf.x[j], pf.se[j])) for pf in per_fold]
        per_run.append(tuple((f.name, ev, es) for f, (ev, es) in zip(ctx.folds, est, strict=True)))
        cons.append(_consistency(est, s.effect_size(v), ctx.settings))
        n_ident.append(sum(1 for _, es in est if 0 < es < math.inf))
    return z, cons, per_run, n_ident, inside


def evaluate(
    ctx: AnalysisContext,
    base: Model,
    specs: Sequence[EffectSpec],
    channel: str,
    truth_referenced: bool,
    x_start: np.ndarray | None = None,
    merge_with: tuple[float, float] | None = None,
    step_scale: float = 1.0,
) -> tuple[CandidateEvidence, Model]:
    """Fit `specs` on top of `base` per fold and on all folds, judge on held-out folds (R1-R4).

    step_scale: of the fits' finite-difference steps (`fitting.fit_specs`).

    merge_with: (value, se) of the same effect already found on the other sensor channel; the
    two become one value on channel 'both' (their weighted mean) when they agree (rule R5),
    else each chain keeps its own (`CandidateEvidence.same_on_both`).
    """
    st = ctx.settings
    specs = list(specs)
    p = len(specs)
    null_x = np.array([_null_fit_value(s) for s in specs])
    x0 = null_x if x_start is None else np.asarray(x_start, float)
    folds = ctx.folds
    per_fold = [
        fit_specs(
            base,
            specs,
            ctx.problem(channel, [f], truth_referenced, base),
            x0,
            st,
            grid=(x_start is None),
            step_scale=step_scale,
        )
        for f in folds
    ]
    all_prob = ctx.problem(channel, folds, truth_referenced, base)
    fit_all = _pooled_fit(per_fold, x0, specs, all_prob, base)
    values = [s.from_fit(u) for s, u in zip(specs, fit_all.x, strict=True)]
    se_phys = [_phys_se(s, u, e) for s, u, e in zip(specs, fit_all.x, fit_all.se, strict=True)]
    res_null = all_prob.residuals([base])[0]
    rss_null = [float(np.dot(r, r)) for r in res_null]
    n_f = all_prob.n_per_fold()
    models_ho = _heldout_models(per_fold, null_x, specs, base)
    rss_ho = []
    for k, f in enumerate(folds):
        r = ctx.problem(channel, [f], truth_referenced, base).residuals([models_ho[k]])[0][0]
        with np.errstate(over="ignore"):  # a held-out model that ran away: an infinite error
            rss_ho.append(float(np.dot(r, r)))
    ss = all_prob.signal_ss()
    before = math.sqrt(sum(rss_null) / ss) if ss > 0 else math.nan
    after = math.sqrt(sum(rss_ho) / ss) if ss > 0 else math.nan
    drop = 1.0 - after / before if before > 0 else 0.0
    drop_above_noise = rss_gap_drop(sum(rss_null), sum(rss_ho), sum(n_f))
    dbic_ho = bic(rss_ho, n_f, p) - bic(rss_null, n_f, 0)
    dbic_fit = bic(list(fit_all.rss_per_fold), n_f, p) - bic(rss_null, n_f, 0)
    z, cons, per_run, n_ident, inside = _per_parameter(
        ctx, base, specs, fit_all, values, se_phys, per_fold
    )
    # shape and plant parameters are fitted along
    tested = [j for j, s in enumerate(specs) if s.tested]
    rules = {
        "R1_heldout_gap_drop": passes_drop(drop_above_noise, st.rules),
        "R2_delta_bic": bool(dbic_ho < st.max_delta_bic),
        "R3_significance": bool(all(passes_z(z[j], st.rules) and inside[j] for j in tested)),
        "R4_consistency": bool(
            all(n_ident[j] >= 2 for j in tested)
            and all(cons[j] >= st.consistency_alpha for j in tested if math.isfinite(cons[j]))
        ),
    }
    model = models_for(base, specs, fit_all.x[None, :])[0]
    same = None
    if merge_with is not None:
        merged = same_on_both(specs[0], *merge_with, values[0], se_phys[0], st)
        same = merged is not None
        if merged is not None:
            values = [merged]
            model = with_effects(base, {specs[0].name: specs[0].params(merged, channel="both")})
    ev = CandidateEvidence(
        labels=tuple(s.label for s in specs),
        channel=channel,
        values=tuple(values),
        se=tuple(se_phys),
        z=tuple(z),
        per_run=tuple(per_run),
        consistency_p=tuple(cons),
        heldout_nrmse_before=before,
        heldout_nrmse_after=after,
        heldout_drop=drop,
        heldout_gap_drop=drop_above_noise,
        delta_bic_heldout=dbic_ho,
        delta_bic_fit=dbic_fit,
        rules=rules,
        accepted=all(rules.values()),
        same_on_both=same,
        heldout_models=tuple(models_ho),
    )
    return ev, model


def evaluate_shared(
    ctx: AnalysisContext, current: Model, specs: Sequence[EffectSpec], channel: str, truth_ref: bool
) -> tuple[CandidateEvidence, Model]:
    """Zero-parameter test: the other sensor's effects `specs`, at their values, on both sensors."""
    st = ctx.settings
    values = tuple(
        float(
            getattr(
                current.effect_on(s.name, "pitch" if s.channel_param == "stroke" else "stroke"),
                s.key,
            )
        )
        for s in specs
    )
    model = with_effects(
        current, {s.name: s.params(v, channel="both") for s, v in zip(specs, values, strict=True)}
    )
    prob = ctx.problem(channel, ctx.folds, truth_ref, current)
    res_old, res_new = prob.residuals([current, model])
    rss_old = [float(np.dot(r, r)) for r in res_old]
    rss_new = [float(np.dot(r, r)) for r in res_new]
    n_f = prob.n_per_fold()
    ss = prob.signal_ss()
    before, after = math.sqrt(sum(rss_old) / ss), math.sqrt(sum(rss_new) / ss)
    drop = 1.0 - after / before if before > 0 else 0.0
    drop_above_noise = rss_gap_drop(sum(rss_old), sum(rss_new), sum(n_f))
    dbic = bic(rss_new, n_f, 0) - bic(rss_old, n_f, 0)
    rules = {
        "R1_heldout_gap_drop": passes_drop(drop_above_noise, st.rules),
        "R2_delta_bic": bool(dbic < st.max_delta_bic),
    }
    ev = CandidateEvidence(
        labels=tuple(f"{s.name}[both]" for s in specs),
        channel=channel,
        values=values,
        se=tuple(math.nan for _ in specs),
        z=tuple(math.nan for _ in specs),
        per_run=tuple(() for _ in specs),
        consistency_p=tuple(math.nan for _ in specs),
        heldout_nrmse_before=before,
        heldout_nrmse_after=after,
        heldout_drop=drop,
        heldout_gap_drop=drop_above_noise,
        delta_bic_heldout=dbic,
        delta_bic_fit=dbic,
        rules=rules,
        accepted=all(rules.values()),
    )
    return ev, model
