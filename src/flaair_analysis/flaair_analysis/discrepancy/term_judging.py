"""A discovered term judged by what it contributes, not by what the plant fitted along with it
does.

A term is fitted jointly with the plant parameters it trades off against (`fitted_along`). Its
held-out error is then compared (R1, R2) with the best of: the model before the step, and the
same parameters fitted again *without* the term, in the same box, from the same start, on the
same window (`refit_without`). So the freedom the plant has with the term, the baseline has too:
a plant that closes the gap alone (a parameter beyond the identification's box reached in the
joint fit) gives the term no credit.

R0: the term's own contribution to the judged channel (the model with it against the same model
without it) must be above what the gap test can see: RMS above sqrt(gap_noise_ratio**2 - 1)
noise RMS (0.32 at 1.05). A smaller change cannot be what closes a gap, whatever the plant did.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from flaair_analysis.evidence import passes_drop
from flaair_model.model import Model
from flaair_model.settings import DiscrepancySettings

from .effect_judging import AnalysisContext, CandidateEvidence, bic, rss_gap_drop
from .fitting import Fold, fit_specs, models_for
from .vocabulary import EffectSpec

__all__ = ["CONTRIBUTION_RULE", "contribution_rms", "judged_against", "refit_without"]

CONTRIBUTION_RULE = "R0_term_contribution"


def refit_without(
    ctx: AnalysisContext,
    current: Model,
    along: Sequence[EffectSpec],
    window: Sequence[Fold],
    channel: str,
    truth_ref: bool,
    x0: np.ndarray,
    settings: DiscrepancySettings,
    step_scale: float,
) -> Model:
    """`along` (the plant parameters or sensor effects a term is fitted with) fitted again on
    `current` without the term: the same box, start, window, evaluations and steps as the joint
    fit.
    """
    problem = ctx.problem(channel, window, truth_ref, current)
    fit = fit_specs(current, along, problem, x0, settings, grid=False, step_scale=step_scale)
    return models_for(current, along, fit.x[None, :])[0]


def contribution_rms(
    ctx: AnalysisContext, model: Model, base: Model, channel: str, truth_ref: bool
) -> float:
    """RMS of what the term changes on `channel` (`model` against `base`, the same model without
    it), in units of the channel's noise RMS.
    """
    problem = ctx.problem(channel, ctx.folds, truth_ref, base)
    with_term, without = problem.residuals([model, base])
    with np.errstate(over="ignore"):  # a term that drives the model wild changes it by inf
        ss = sum(float(np.sum((a - b) ** 2)) for a, b in zip(with_term, without, strict=True))
    n = sum(problem.n_per_fold())
    return math.sqrt(ss / n) if n else 0.0


def judged_against(
    ctx: AnalysisContext,
    ev: CandidateEvidence,
    model: Model,
    base: Model,
    baselines: Sequence[Model],
    channel: str,
    truth_ref: bool,
    n_params: int,
) -> CandidateEvidence:
    """`ev` (the term on `base`, `model` with it) judged again: R1 and R2 against the best of
    `baselines` (the model before the step, the plant refitted without the term), R0 on the
    term's own contribution (module docstring). Only ever stricter than `ev`'s own rules.
    """
    st = ctx.settings
    problem = ctx.problem(channel, ctx.folds, truth_ref, base)
    ss, n_f = problem.signal_ss(), problem.n_per_fold()
    rss_base = [[float(np.dot(r, r)) for r in res] for res in problem.residuals(list(baselines))]
    best = min(rss_base, key=sum)
    rss_ho = []
    for k, f in enumerate(ctx.folds):
        r = ctx.problem(channel, [f], truth_ref, base).residuals([ev.heldout_models[k]])[0][0]
        with np.errstate(over="ignore"):  # a held-out model that ran away: an infinite error
            rss_ho.append(float(np.dot(r, r)))
    drop = rss_gap_drop(sum(best), sum(rss_ho), sum(n_f))
    dbic = bic(rss_ho, n_f, n_params) - bic(best, n_f, 0)
    share = contribution_rms(ctx, model, base, channel, truth_ref)
    rules = dict(ev.rules) | {
        "R1_heldout_gap_drop": passes_drop(drop, st.rules),
        "R2_delta_bic": bool(ev.rules["R2_delta_bic"] and dbic < st.max_delta_bic),
        CONTRIBUTION_RULE: bool(share > math.sqrt(max(st.gap_noise_ratio**2 - 1.0, 0.0))),
    }
    return replace(
        ev,
        rules=rules,
        accepted=all(rules.values()),
        heldout_gap_drop=drop,
        heldout_nrmse_before=math.sqrt(sum(best) / ss) if ss > 0 else math.nan,
        delta_bic_heldout=max(ev.delta_bic_heldout, dbic),
    )
