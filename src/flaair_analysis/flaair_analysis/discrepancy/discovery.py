"""Discovery: propose the form of a missing effect from the term library, fit it, judge it.

Run after the vocabulary search when a located gap remains (docs/DISCREPANCY.md). For each
channel with a gap, upstream first, every library term (`flaair_model.terms.TERM_KINDS`) that can
act where the channel's signal comes from is fitted through the simulator:

    stroke_deg       -> stroke_dynamics, drive        (with the stroke plant parameters)
    pitch_deg        -> pitch_dynamics                (with the pitch plant parameters)
    stroke_sensor_v  -> stroke_sensor_v
    pitch_sensor_v   -> pitch_sensor_v

The coefficient (and any shape parameter) is fitted by least squares on the runs jointly with
the fitted plant parameters it trades off against; nothing is regressed on differentiated data,
so a video-rate truth with NaN between frames is used as it is. The best `discovery_shortlist`
fits are then judged like a vocabulary effect (`evidence.evaluate`: per-run fits, each run
predicted from the others), and a term is accepted only if it passes the same rules R1-R4: the
held-out model error above noise drops by more than `min_heldout_drop`, the held-out BIC falls
by more than `-max_delta_bic`, the coefficient is `min_z` standard errors from zero, and the
runs (full and half drive, early and late) agree on it. Among accepted terms the lowest held-out
error of the channel wins; errors within `PARSIMONY` (2 %) of the best are a tie, won by the term
with fewer parameters. A winner that is a vocabulary effect under another name
(`TermKind.same_as`) is reported as that effect, fitted as the vocabulary fits it. A gap no term
closes stays. After a term on a sensor chain, the vocabulary effects named on that chain are
judged again with it in the model (`_rejudged_chain`): all are removed where the chain shows no
gap without them, else each one the rules no longer accept and without which the chain shows no
gap.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from itertools import pairwise
from typing import Any

import numpy as np

from flaair_model.effects import SENSOR_CHANNELS
from flaair_model.model import Model, PlantParams
from flaair_model.terms import (
    DiscoveredTerm,
)
from flaair_model.validation import ModelError

from .discovery_uncertainty import PARSIMONY, form_uncertainty
from .effect_judging import AnalysisContext, CandidateEvidence, FoundEffect, evaluate
from .fitting import Fold, fit_specs, fold_nrmse, models_for, spec_value
from .identification import fit_initial_states, identify_plant
from .runs import MotionCache
from .search import CHANNEL_ORDER, channel_has_gap
from .term_candidates import candidates, fitted_along
from .term_judging import judged_against, refit_without
from .vocabulary import (
    ENTRIES,
    PLANT_PARAMETERS,
    SENSOR_SIDE,
    UPSTREAM_TRUTH,
    EffectSpec,
    candidate_groups,
    term_specs,
)

__all__ = ["SAME_ERROR", "Discovered", "DiscoveryOutcome", "discover", "rank_passing"]

# Held-out errors within this fraction of each other are one number computed two ways: a composed
# form that equals a library row on these runs (the square of a film's voltage where the film is
# a pure gain on its angle). The row wins; the last bits of the arithmetic, which differ between
# processors, never decide.
SAME_ERROR = 1e-9


@dataclass(frozen=True)
class Discovered:
    """One accepted library term, with its evidence.

    Attributes
    ----------
    term : the term as the model carries it.
    channel : the measured channel whose gap it closes (judged on).
    stderr : standard error of each parameter.
    gap_before, gap_after : NRMSE per channel on held-out runs without and with it (after: its
        parameters fitted without the run they predict).
    evidence : `CandidateEvidence.as_dict` of the accepted fit.
    beaten : the other candidates of its step, best first: {term, acts_on, expression,
        accepted, delta_bic_heldout, heldout_gap_drop, bic_margin}.
    uncertainty : `discovery_uncertainty.form_uncertainty`: the next best form's held-out
        error, whether the runs tell the two apart, the experiment that would.
    """

    term: DiscoveredTerm
    channel: str
    stderr: dict[str, Any]
    gap_before: dict[str, Any]
    gap_after: dict[str, Any]
    evidence: dict[str, Any]
    beaten: tuple[Any, ...]
    uncertainty: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        """The discrepancy.json entry."""
        t = self.term
        params = {"coefficient": {"value": t.coefficient, "stderr": self.stderr["coefficient"]}}
        params |= {k: {"value": v, "stderr": self.stderr[k]} for k, v in t.shape}
        return {
            "kind": t.kind,
            "composed": t.row.composed,
            "acts_on": t.acts_on,
            "expression": t.expression,
            "feature": t.feature_expression,
            "words": t.row.words,
            "examples": t.row.examples,
            "judged_on": self.channel,
            "parameters": params,
            "gap_before": dict(self.gap_before),
            "gap_after": dict(self.gap_after),
            "candidates_beaten": list(self.beaten),
            "uncertainty": dict(self.uncertainty),
            "evidence": dict(self.evidence),
        }


@dataclass(frozen=True)
class DiscoveryOutcome:
    """The model with the accepted terms, the terms, the vocabulary effects found instead, the
    vocabulary effects the terms replaced, every candidate tried and the runs (their initial
    states fitted again with the terms).
    """

    model: Model
    discovered: tuple[Discovered, ...]
    named: tuple[FoundEffect, ...]
    replaced: tuple[FoundEffect, ...]
    tried: tuple[Any, ...]
    runs: tuple[Any, ...]


def _truth_ref(ctx: AnalysisContext, model: Model, channel: str) -> bool:
    return channel in SENSOR_CHANNELS and channel_has_gap(
        ctx, model, UPSTREAM_TRUTH[channel], False
    )


def _as_vocabulary(
    ctx: AnalysisContext, current: Model, name: str, channel: str
) -> tuple[CandidateEvidence, Model] | None:
    """The vocabulary effect `name` fitted on `channel` as the vocabulary fits it, if accepted."""
    if current.effect(name) is not None:
        return None
    for group in candidate_groups(channel, current if ctx.settings.identify else None):
        if group[0].name == name:
            ev, model = evaluate(ctx, current, group, channel, _truth_ref(ctx, current, channel))
            return (ev, model) if ev.accepted else None
    return None


def _beaten(
    winner: CandidateEvidence, judged: Sequence[tuple[Any, ...]], rest: Sequence[tuple[Any, ...]]
) -> tuple[Any, ...]:
    rows = []
    for ev, kind, site, specs in judged:
        if ev is winner:
            continue
        term = DiscoveredTerm(
            kind.name,
            site,
            ev.values[0],
            tuple((s.key, v) for s, v in zip(specs[1:], ev.values[1:], strict=True)),
        )
        rows.append(
            {
                "term": kind.name,
                "composed": kind.composed,
                "acts_on": site,
                "expression": term.expression,
                "accepted": ev.accepted,
                "heldout_nrmse_after": ev.heldout_nrmse_after,
                "heldout_gap_drop": ev.heldout_gap_drop,
                "nrmse_margin": ev.heldout_nrmse_after - winner.heldout_nrmse_after,
                "failed_rules": [k for k, v in ev.rules.items() if not v],
            }
        )
    for _rss, kind, site, _specs, _x in rest:  # not shortlisted: their fits left more residual
        rows.append(
            {
                "term": kind.name,
                "acts_on": site,
                "expression": None,
                "accepted": False,
                "heldout_nrmse_after": None,
                "heldout_gap_drop": None,
                "nrmse_margin": None,
                "failed_rules": ["not shortlisted"],
            }
        )
    return tuple(rows)


def _step(
    ctx: AnalysisContext,
    current: Model,
    channel: str,
    start_plant: PlantParams | None,
    centre: Mapping[str, float],
) -> tuple[list[tuple[Any, ...]], list[Any]]:
    """One discovery step on `channel`: the accepted candidates, best first, each (evidence,
    kind, site, specs, model); and the step's record [judged, not shortlisted, tried, the
    composed forms' ranking: {composed_ranked (forms), composed_rank_s (wall time)}]. Each
    term is judged against the plant refitted without it in the same box (`term_judging`).
    """
    truth_ref = _truth_ref(ctx, current, channel)
    found = candidates(ctx, current, channel, truth_ref)
    cands = found.fitted
    # the best rows, and each site's best composed forms (alone on the current plant a form the
    # plant mimics in part fits worse than it will with the plant; the drive's forms do not take
    # the dynamics' places): the rows' shortlist stays what it was without the composed forms
    table = [c for c in cands if not c[1].composed]
    shortlist = table[: ctx.settings.discovery_shortlist]
    for site in dict.fromkeys(c[2] for c in cands if c[1].composed):  # each site's best, in order
        here = [c for c in cands if c[1].composed and c[2] == site]
        shortlist += here[: ctx.settings.discovery_composed_fits]
    cands = shortlist + [c for c in cands if not any(c is s for s in shortlist)]
    judged = []
    st = ctx.settings
    alone: dict[tuple[str, ...], Model] = {}  # the parameters fitted along, refitted without a term
    for _rss, kind, site, specs, x in shortlist:
        # the term and the plant parameters it trades off against, fitted on all runs; then the
        # term run by run on that plant (the rules judge the term, as the identification fits
        # the plant on every run)
        plant = fitted_along(site, current, channel, st.identify, centre)
        base, baselines = current, [current]
        fit_st = replace(st, max_nfev=st.discovery_max_nfev)
        try:
            if plant:
                joint = list(specs) + plant
                start = replace(current, plant=start_plant) if start_plant is not None else current
                x_plant = np.array([s.to_fit(spec_value(start, s)) for s in plant])
                fit = fit_specs(
                    current,
                    joint,
                    ctx.problem(channel, _fit_window(ctx), truth_ref, current),
                    np.concatenate([x, x_plant]),
                    fit_st,
                    grid=False,
                    step_scale=st.discovery_fd_step,
                )
                x = fit.x[: len(specs)]
                base = models_for(current, plant, fit.x[None, len(specs) :])[0]
                key = tuple(s.label for s in plant)
                if key not in alone:
                    alone[key] = refit_without(
                        ctx,
                        current,
                        plant,
                        _fit_window(ctx),
                        channel,
                        truth_ref,
                        x_plant,
                        fit_st,
                        st.discovery_fd_step,
                    )
                baselines.append(alone[key])
            ev, model = evaluate(
                ctx, base, specs, channel, truth_ref, x_start=x, step_scale=st.discovery_fd_step
            )
            ev = judged_against(ctx, ev, model, base, baselines, channel, truth_ref, len(specs))
        except (ModelError, ValueError):  # the fit left the model's valid range: not a candidate
            continue
        judged.append((ev, kind, site, specs, model))
    ranking = {"composed_ranked": len(found.composed_ranked), "composed_rank_s": found.rank_s}
    return rank_passing(judged), [
        judged,
        cands[len(shortlist) :],
        _tried(cands, found, judged),
        ranking,
    ]


def _tried(cands: Sequence[Any], found: Any, judged: Sequence[Any]) -> list[dict[str, Any]]:
    """The step's record of every candidate: fitted (with its verdict when judged), ranked by
    one linearized step only, or skipped as degenerate.
    """
    tried: list[dict[str, Any]] = [
        {"term": k.name, "acts_on": s, "composed": k.composed, "fit_rss": r}
        for r, k, s, _sp, _x in cands
    ]
    rows = {(row["term"], row["acts_on"]): row for row in tried}
    fitted = set(rows)
    tried += [
        {"term": name, "acts_on": site, "composed": True, "linearized_rss": rss}
        for name, site, rss in found.composed_ranked
        if (name, site) not in fitted
    ]
    tried += [
        {"term": name, "acts_on": site, "composed": True, "skipped": "degenerate on the runs"}
        for name, site in found.degenerate
    ]
    for ev, kind, site, *_rest in judged:
        rows[(kind.name, site)] |= {
            "rules": dict(ev.rules),
            "heldout_nrmse_after": ev.heldout_nrmse_after,
            "heldout_gap_drop": ev.heldout_gap_drop,
            "values": list(ev.values),
            "z": list(ev.z),
            "consistency_p": list(ev.consistency_p),
        }
    return tried


def rank_passing(judged: Sequence[Any]) -> list[Any]:
    """The accepted candidates, best first.

    Each judged candidate is (evidence, its `TermKind`, site, specs, model), as a discovery step
    judges it.
    """
    # each candidate's plant is its own: rank on the held-out error, which all share; a term
    # with fewer parameters within PARSIMONY of the best error comes first (a leak through a
    # low-pass at its 5 kHz bound is the plain leak), and of equal errors (SAME_ERROR) a row
    # before a composed form
    passing = sorted((j for j in judged if j[0].accepted), key=lambda j: j[0].heldout_nrmse_after)
    if passing:
        best = passing[0][0].heldout_nrmse_after
        same = max(best * SAME_ERROR, 1e-300)
        passing.sort(
            key=lambda j: (
                j[0].heldout_nrmse_after > best * (1.0 + PARSIMONY),
                len(j[3]),
                round(j[0].heldout_nrmse_after / same),
                j[1].composed,
                j[0].heldout_nrmse_after,
            )
        )
    return passing


def _uncertainty(
    ctx: AnalysisContext, win: tuple[Any, ...], judged: Sequence[tuple[Any, ...]], channel: str
) -> dict[str, Any]:
    """The winner against the next best form of its step, and the sine that tells them apart."""
    edges = [e for e in ctx.settings.band_edges_hz if 0.0 < e < 1e8]
    return form_uncertainty(
        win,
        judged,
        channel,
        ctx.runs[0].fs_hz,
        max(float(np.max(np.abs(r.drive_v))) for r in ctx.runs),
        [0.5 * (a + b) for a, b in pairwise(edges)],
        ctx.noise[channel],
    )


def _without(model: Model, effects: Sequence[FoundEffect]) -> Model:
    names = {e.name for e in effects}
    return replace(model, effects=tuple((n, e) for n, e in model.effects if n not in names))


def _refit_pitch_plant(ctx: AnalysisContext, model: Model, centre: Mapping[str, float]) -> Model:
    """`model` with its pitch plant parameters fitted again on pitch_deg (kept if better), in
    the identification's box about `centre`.
    """
    specs = fitted_along("pitch_dynamics", model, "pitch_deg", True, centre)
    problem = ctx.problem("pitch_deg", ctx.folds, False, model)
    x0 = np.array([s.to_fit(spec_value(model, s)) for s in specs])
    fit = fit_specs(
        model,
        specs,
        problem,
        x0,
        replace(ctx.settings, max_nfev=ctx.settings.discovery_max_nfev),
        grid=False,
        step_scale=ctx.settings.discovery_fd_step,
    )
    refit = models_for(model, specs, fit.x[None, :])[0]
    before = sum(float(np.dot(r, r)) for r in problem.residuals([model])[0])
    return refit if fit.rss < before else model


def _fit_window(ctx: AnalysisContext) -> tuple[Fold, ...]:
    """`ctx.folds` without the first `discovery_skip_s` of each run."""
    skip = ctx.settings.discovery_skip_s
    return tuple(
        replace(f, start=min(f.stop, max(f.start, round(skip * ctx.runs[f.run].fs_hz))))
        for f in ctx.folds
    )


def _polish_truth(ctx: AnalysisContext, model: Model, centre: Mapping[str, float]) -> Model:
    """`discovery_polish_rounds` of: the discovered dynamics and drive terms with the plant,
    fitted again on the truth channels (without the runs' first wingbeats), then the runs'
    initial states (`ctx.runs` replaced). The accepted coefficient is the mean of per-run fits,
    the in-sample optimum lies beside it; the two fits alternate towards their joint optimum.
    """
    for _round in range(ctx.settings.discovery_polish_rounds):
        model = _polish_round(ctx, model, centre)
    return model


def _polish_round(ctx: AnalysisContext, model: Model, centre: Mapping[str, float]) -> Model:
    """One round of `_polish_truth` (the plant within the identification's box about `centre`)."""
    st = replace(ctx.settings, max_nfev=ctx.settings.discovery_max_nfev)
    for truth, sites in (
        ("stroke_deg", ("stroke_dynamics", "drive")),
        ("pitch_deg", ("pitch_dynamics",)),
    ):
        specs = _discovered_specs(model, sites, truth)
        if not specs and truth == "stroke_deg":
            continue
        specs += fitted_along(sites[0], model, truth, st.identify, centre)
        if not specs:
            continue
        problem = ctx.problem(truth, _fit_window(ctx), False, model)
        x0 = np.array([s.to_fit(spec_value(model, s)) for s in specs])
        fit = fit_specs(model, specs, problem, x0, st, grid=False, step_scale=st.discovery_fd_step)
        before = sum(float(np.dot(r, r)) for r in problem.residuals([model])[0])
        if fit.rss < before:
            model = models_for(model, specs, fit.x[None, :])[0]
    if st.identify:
        ctx.runs = identify_plant(
            ctx.runs, model, ctx.noise, keys=(), state_channels=("stroke_deg", "pitch_deg")
        ).runs
        ctx.motion = MotionCache()
        _states_on_sensors(ctx, model)
    return model


def _states_on_sensors(ctx: AnalysisContext, model: Model) -> None:
    """The runs' initial states fitted again on the truth and both sensors, kept (`ctx.runs`) if
    the cost drops and no channel is left with a gap it did not have: a video-rate truth leaves
    the states loose, and a wrong state's transient shows on the far more precise sensors.
    """
    channels = ("stroke_deg", "pitch_deg", *SENSOR_CHANNELS)
    runs, before, after = fit_initial_states(
        ctx.runs, model, ctx.noise, channels, step_scale=ctx.settings.discovery_fd_step
    )
    if not after < before:
        return
    trial = AnalysisContext(runs, ctx.noise, ctx.settings, ctx.tracks)
    if any(
        channel_has_gap(trial, model, c, False) and not channel_has_gap(ctx, model, c, False)
        for c in channels
    ):
        return
    ctx.runs, ctx.motion = trial.runs, MotionCache()


def _replacing(
    ctx: AnalysisContext,
    current: Model,
    channel: str,
    replaceable: Sequence[FoundEffect],
    start_plant: PlantParams | None,
    centre: Mapping[str, float],
) -> tuple[list[tuple[Any, ...]], list[Any], list[FoundEffect], list[dict[str, Any]]]:
    """A discovery step on `channel`, first in place of the vocabulary effects found there that
    leave its gap (the winner must then predict the held-out runs better than they did), else on
    top of them: (the passing candidates, best first; the step record; the effects replaced; what
    was tried).
    """
    # on a sensor the chain's effects are fitted along with the term instead
    here = [
        e
        for e in replaceable
        if channel not in SENSOR_CHANNELS
        and e.channel.split("+")[0] == channel
        and current.effect(e.name) is not None
    ]
    tried: list[dict[str, Any]] = []
    for base, dropped in ([(_without(current, here), here)] if here else []) + [(current, [])]:
        passing, record = _step(ctx, base, channel, start_plant, centre)
        tried.append(
            {
                "channel": channel,
                "in_place_of": [e.name for e in dropped],
                "candidates": record[2],
                "composed_degenerate_skipped": sum(
                    1 for c in record[2] if c.get("skipped") == "degenerate on the runs"
                ),
                **record[3],
            }
        )
        if dropped:
            passing = [
                w
                for w in passing
                if w[0].heldout_nrmse_after
                < min(e.evidence.get("heldout_nrmse_after", math.inf) for e in dropped)
            ]
        if passing:
            return passing, record, dropped, tried
    return [], record, [], tried


def _rejudged_chain(
    ctx: AnalysisContext,
    current: Model,
    channel: str,
    effects: Sequence[FoundEffect],
) -> tuple[Model, list[FoundEffect], list[dict[str, Any]]]:
    """The vocabulary effects found on sensor chain `channel`, judged again now that a term there
    is in the model. First all together: where the chain shows no gap with the terms alone
    (refitted without the effects), every one is removed. Else each in turn: fitted on top of the
    model without it (the terms and the chain's other effects refitted without it) by the rules
    that accepted it, and the chain's gap test run without it; one the rules no longer accept,
    without which the chain shows no gap, is removed. (The vocabulary search named them for part
    of the term's signal: a high-pass or a delay for a crosstalk between the amplifiers.)
    Returns the model, the effects removed and each re-judgement's record.
    """
    truth_ref = _truth_ref(ctx, current, channel)
    side = SENSOR_SIDE[channel]
    here = []
    for effect in effects:
        on = current.effect_on(effect.name, side)
        group = next((g for g in candidate_groups(channel) if g[0].name == effect.name), None)
        shared = getattr(on, "channel", side) != side  # one value on both chains
        if effect.channel == channel and on is not None and group is not None and not shared:
            here.append((effect, group))
    if not here:
        return current, [], []
    alone = _chain_refitted(ctx, _without(current, [e for e, _ in here]), channel, truth_ref)
    if not channel_has_gap(ctx, alone, channel, truth_ref):
        return (
            alone,
            [e for e, _ in here],
            [
                {
                    "effect": e.name,
                    "channel": channel,
                    "removed": True,
                    "why": "no gap without them",
                }
                for e, _ in here
            ],
        )
    dropped: list[FoundEffect] = []
    records: list[dict[str, Any]] = []
    for effect, group in here:
        x_effect = np.array([s.to_fit(spec_value(current, s)) for s in group])
        without = _chain_refitted(ctx, _without(current, [effect]), channel, truth_ref)
        ev, _ = evaluate(
            ctx, without, group, channel, truth_ref, x_start=x_effect,
            step_scale=ctx.settings.discovery_fd_step,
        )  # fmt: skip
        # removed only where the rules no longer want it and the chain shows no gap without it
        removed = not ev.accepted and not channel_has_gap(ctx, without, channel, truth_ref)
        records.append(
            {
                "effect": effect.name,
                "channel": channel,
                "removed": removed,
                "rules": dict(ev.rules),
                "heldout_gap_drop": ev.heldout_gap_drop,
            }
        )
        if removed:
            current = without
            dropped.append(effect)
    return current, dropped, records


def _chain_refitted(ctx: AnalysisContext, model: Model, channel: str, truth_ref: bool) -> Model:
    """`model` with the terms on sensor chain `channel` and the chain's vocabulary effects fitted
    again on the channel (the discovery's window, evaluations and steps).
    """
    st = replace(ctx.settings, max_nfev=ctx.settings.discovery_max_nfev)
    specs = _discovered_specs(model, (channel,), channel)
    specs += fitted_along(channel, model, channel, st.identify)
    if not specs:
        return model
    x0 = np.array([s.to_fit(spec_value(model, s)) for s in specs])
    return refit_without(
        ctx, model, specs, _fit_window(ctx), channel, truth_ref, x0, st, st.discovery_fd_step
    )


def _discovered_specs(model: Model, sites: Sequence[str], channel: str) -> list[EffectSpec]:
    """The fittable parameters of `model`'s discovered terms at `sites`, judged on `channel`
    (each coefficient within 3x its value).
    """
    return [
        s
        for t in model.discovered
        if t.acts_on in sites
        for s in term_specs(
            t.row, t.acts_on, channel, max(3.0 * abs(t.coefficient), 1e-30), dict(t.shape)
        )
    ]


def _winner(
    ctx: AnalysisContext,
    current: Model,
    passing: Sequence[Any],
    dropped: Sequence[FoundEffect],
    channel: str,
) -> tuple[Any, Any, str | None]:
    """The first passing candidate (a term that is a vocabulary effect must pass as that effect:
    then its fit as the effect, and the effect's name); (None, None, None) when none passes.
    """
    for candidate in passing:
        vocabulary = candidate[1].same_as.get(candidate[2])
        if vocabulary is None:
            return candidate, None, None
        named_fit = _as_vocabulary(ctx, _without(current, dropped), vocabulary, channel)
        if named_fit is not None:
            return candidate, named_fit, vocabulary
    return None, None, None


def _named_effect(vocabulary: str, channel: str, vev: CandidateEvidence) -> FoundEffect:
    """A library term found to be vocabulary effect `vocabulary`, as that effect."""
    return FoundEffect(
        vocabulary,
        channel,
        {  # the values go on to the plant parameters the effect trades off against
            p.key: float(v) for p, v in zip(ENTRIES[vocabulary].params, vev.values, strict=False)
        },
        {
            **vev.as_dict(),
            "found_by": "discovery (a library term that is this vocabulary effect)",
        },
        ENTRIES[vocabulary].acts_on,
    )


def _discovered(
    ctx: AnalysisContext,
    current: Model,
    win: Any,
    judged: Sequence[Any],
    rest: Any,
    channel: str,
    centre: Mapping[str, float],
) -> tuple[Discovered, Model]:
    """The winning term's account (its held-out gap before and after, what it beat, what it
    cannot be told from) and the model with it (the pitch plant refitted under a stroke term).
    """
    ev, kind, site, specs, new_model = win
    gap_before = fold_nrmse(ctx.runs, ctx.folds, [current] * len(ctx.folds))
    after_models = list(ev.heldout_models)
    if channel == "stroke_deg" and ctx.settings.identify:
        # the pitch plant was identified under the stroke's error: fit it again under the
        # corrected stroke (its parameters are the plant's, not the term's)
        new_model = _refit_pitch_plant(ctx, new_model, centre)
        pitch = {
            k: getattr(new_model.plant, k) for k, c in PLANT_PARAMETERS.items() if c == "pitch_deg"
        }
        after_models = [replace(m, plant=replace(m.plant, **pitch)) for m in after_models]
    gap_after = fold_nrmse(ctx.runs, ctx.folds, after_models)
    term = next(t for t in new_model.discovered if (t.kind, t.acts_on) == (kind.name, site))
    stderr = {s.key: e for s, e in zip(specs, ev.se, strict=True) if s.is_term}
    discovered = Discovered(
        term,
        channel,
        stderr,
        gap_before,
        gap_after,
        ev.as_dict(),
        _beaten(ev, [(j[0], j[1], j[2], j[3]) for j in judged], rest),
        _uncertainty(ctx, win, judged, channel),
    )
    return discovered, new_model


def discover(
    ctx: AnalysisContext,
    model: Model,
    gap_channels: Sequence[str],
    progress: Callable[[str], None] | None = None,
    replaceable: Sequence[FoundEffect] = (),
    start_plant: PlantParams | None = None,
    nominal: Mapping[str, float] | None = None,
) -> DiscoveryOutcome:
    """Search the term library for what closes the located gaps (see the module docstring).

    replaceable: vocabulary effects found where a gap is left (named, but fitting only
    approximately); a term may replace them. start_plant: where a term's joint fit starts the
    plant parameters (the identification's plant: the vocabulary search may have moved them to
    mimic what it could not name). nominal: {plant key: value} the identification's box is
    centred on (the input model's; default `model`'s): every plant fit of the discovery stays in
    that box, the freedom the plant had without a term.
    """
    centre = (
        dict(nominal)
        if nominal is not None
        else {k: float(getattr(model.plant, k)) for k in PLANT_PARAMETERS}
    )
    current = model
    found: list[Discovered] = []
    named: list[FoundEffect] = []
    replaced: list[FoundEffect] = []
    tried: list[dict[str, Any]] = []
    for channel in CHANNEL_ORDER:
        if channel not in gap_channels:
            continue
        # up to discovery_terms_per_channel terms: a second is searched with the first in place
        # (and its plant) while the channel keeps a located gap, under the same held-out rules
        for _step_no in range(ctx.settings.discovery_terms_per_channel):
            if len(found) >= ctx.settings.max_discovered_terms:
                break
            if not channel_has_gap(ctx, current, channel, _truth_ref(ctx, current, channel)):
                break
            if channel == "pitch_deg" and channel_has_gap(ctx, current, "stroke_deg", False):
                tried.append(
                    {
                        "channel": channel,
                        "skipped": "below the stroke_deg gap (possibly propagated from it)",
                        "candidates": [],
                    }
                )
                break
            if progress:
                progress(f"discover on {channel}")
            passing, (judged, rest, _tried, _ranking), dropped, step_tried = _replacing(
                ctx,
                current,
                channel,
                [e for e in replaceable if e not in replaced],
                start_plant,
                centre,
            )
            tried += step_tried
            win, named_fit, vocabulary = _winner(ctx, current, passing, dropped, channel)
            if win is None:
                break
            replaced += dropped
            current = _without(current, dropped)
            if named_fit is not None and vocabulary is not None:
                vev, current = named_fit
                named.append(_named_effect(vocabulary, channel, vev))
                break  # as before: a vocabulary effect ends the channel's search
            discovered, new_model = _discovered(ctx, current, win, judged, rest, channel, centre)
            found.append(discovered)
            # the term with the plant, then the runs' initial states, before the channel is
            # judged for a second term (the first term's fit stopped where the states were)
            current = _polish_truth(ctx, new_model, centre)
            if channel in SENSOR_CHANNELS:
                # the chain's vocabulary effects were fitted with the term's gap in the data
                current, out, records = _rejudged_chain(
                    ctx, current, channel, [e for e in replaceable if e not in replaced]
                )
                replaced += out
                if records:
                    tried[-1]["effects_rejudged"] = records
    if found:
        final = {(t.kind, t.acts_on): t for t in current.discovered}
        found = [replace(d, term=final[(d.term.kind, d.term.acts_on)]) for d in found]
    return DiscoveryOutcome(
        current, tuple(found), tuple(named), tuple(replaced), tuple(tried), ctx.runs
    )
