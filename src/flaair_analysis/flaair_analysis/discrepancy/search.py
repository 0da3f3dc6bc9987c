"""Greedy, channel-by-channel search for the missing effects."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, cast

import numpy as np

from flaair_model.effects import SENSOR_CHANNELS, TRUTH_CHANNELS
from flaair_model.model import (
    Model,
    with_effect_on,
    with_effects,
    without_effect_on,
)
from flaair_model.settings import DiscrepancySettings

from .diagnosis import channel_residual, gap_test
from .effect_judging import (
    AnalysisContext,
    CandidateEvidence,
    FoundEffect,
    evaluate,
    evaluate_shared,
    same_on_both,
)
from .fitting import Fold, apply_values, fit_specs, spec_value
from .found import merge_sensor_channels
from .identification import fit_initial_states, identify_plant
from .runs import MotionCache, Run, sensor_gain_v_per_deg, simulate_runs
from .vocabulary import (
    EFFECT_CHANNELS,
    PLANT_PARAMETERS,
    UPSTREAM_TRUTH,
    EffectSpec,
    candidate_groups,
    candidate_specs,
    plant_spec,
)

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
    steps: tuple[Any, ...]


CHANNEL_ORDER = ("stroke_deg", "pitch_deg", "stroke_sensor_v", "pitch_sensor_v")


def channel_has_gap(ctx: AnalysisContext, model: Model, channel: str, truth_ref: bool) -> bool:
    """The gap test of one channel (noise ratio and whiteness only)."""
    sims = simulate_runs([model], ctx.runs)[0]
    res = [
        channel_residual(run, sim, channel, model, truth_referenced=truth_ref)
        for run, sim in zip(ctx.runs, sims, strict=True)
    ]
    sigma = ctx.noise[channel]
    if truth_ref:
        g = sensor_gain_v_per_deg(model, channel)
        sigma = math.sqrt(sigma**2 + (g * ctx.noise[UPSTREAM_TRUTH[channel]]) ** 2)
    return gap_test(res, sigma, ctx.settings)[0]


def _other_side(side: str | None) -> str:
    return "pitch" if side == "stroke" else "stroke"


def _offer(
    model_in: Model,
    current: Model,
    spec: EffectSpec,
    found_here: Sequence[EffectSpec],
    reopen: Sequence[str] = (),
) -> str | None:
    """'new', 'merge' (the other sensor has the effect: fit this chain's own value, then merge to
    'both' or keep one value per chain, rule R5) or None (not offered). `reopen`: effects taken
    over from the other sensor at its value (shared test) whose own value on this chain is fitted.
    """
    if model_in.effect(spec.name) is not None:
        return None
    if any(s.name == spec.name for s in found_here) and spec.name not in reopen:
        return None
    if spec.channel_param is None:
        return "new" if current.effect(spec.name) is None else None
    here = current.effect_on(spec.name, spec.channel_param)
    if current.effect_on(spec.name, _other_side(spec.channel_param)) is None:
        return "new" if here is None else None
    return "merge" if here is None or spec.name in reopen else None


def _other_chain(
    model: Model, spec: EffectSpec, found: Sequence[FoundEffect]
) -> tuple[float, float]:
    """(value, standard error) of sensor effect `spec`
    on the other chain (found on the other sensor).
    """
    prev = next((f for f in found if f.name == spec.name), None)
    se_prev = (
        (prev.evidence.get("standard_errors") or [math.inf])[0] if prev is not None else math.inf
    )
    other = model.effect_on(spec.name, _other_side(spec.channel_param))
    return float(getattr(other, spec.key)), float(se_prev)


def _own(model: Model, spec: EffectSpec) -> bool:
    """`spec` is fitted on its own channel: a plant parameter, an effect without a sensor chain, or
    a sensor effect whose value on this chain is its own (not one value shared by both chains).
    """
    if spec.is_plant or spec.channel_param is None:
        return True
    e = model.effect_on(spec.name, spec.channel_param)
    return e is not None and getattr(e, "channel", None) == spec.channel_param


def polish(
    ctx: AnalysisContext,
    base: Model,
    specs: Sequence[EffectSpec],
    current: Model,
    channel: str,
    truth_ref: bool,
    folds: Sequence[Fold] | None = None,
) -> Model:
    """Joint least-squares re-fit of `specs` (effects of one channel and the plant parameters
    fitted along with them), from their values in `current`; `base` lacks those effects.
    """
    folds = ctx.folds if folds is None else folds
    x0 = np.array([s.to_fit(spec_value(current, s)) for s in specs])
    prob = ctx.problem(channel, folds, truth_ref, base)
    fit = fit_specs(base, specs, prob, x0, ctx.settings, grid=False)
    channels = {s.name: None if _own(current, s) else "both" for s in specs if not s.is_plant}
    return apply_values(
        base, specs, [s.from_fit(u) for s, u in zip(specs, fit.x, strict=True)], channels
    )


def _groups(ctx: AnalysisContext, channel: str, model: Model) -> tuple[tuple[EffectSpec, ...], ...]:
    """Candidate parameter sets on `channel`: with the plant parameters they trade off against
    (and without the effects a plant change mimics) once the plant is fitted.
    """
    return candidate_groups(channel, model if ctx.settings.identify else None)


def _use_runs(ctx: AnalysisContext, runs: Sequence[Run]) -> None:
    """Continue the search with `runs` (new initial states): simulations cached so far are stale."""
    ctx.runs = tuple(runs)
    ctx.motion = MotionCache()


def _join(a: Sequence[EffectSpec], b: Sequence[EffectSpec]) -> list[EffectSpec]:
    """Specs of a and b, each plant parameter once."""
    keys = {s.key for s in a if s.is_plant}
    return list(a) + [s for s in b if not (s.is_plant and s.key in keys)]


@dataclass
class _ChannelState:
    model: Model
    specs: list[Any]
    evidence: dict[str, Any]  # effect name -> CandidateEvidence that added it
    last: CandidateEvidence | None = None
    reopen: tuple[
        Any, ...
    ] = ()  # effects taken over from the other sensor at its value (shared test)


def _greedy(
    ctx: AnalysisContext,
    model_in: Model,
    state: _ChannelState,
    channel: str,
    truth_ref: bool,
    found: Sequence[FoundEffect],
    steps: list[Any],
    max_steps: int,
) -> tuple[_ChannelState, bool, list[Any]]:
    """Forward selection on one channel; returns (state, has_gap, first-step single evaluations)."""
    has_gap = channel_has_gap(ctx, state.model, channel, truth_ref)
    first = []
    for step in range(max_steps):
        if not has_gap:
            break
        offers = [
            (g, _offer(model_in, state.model, g[0], state.specs, state.reopen))
            for g in _groups(ctx, channel, state.model)
        ]
        offers = [(g, kind) for g, kind in offers if kind is not None]
        if not offers:
            break
        evals = []
        for group, kind in offers:
            s = group[0]
            merge = None
            base = state.model
            if kind == "merge":
                merge = _other_chain(state.model, s, found)
                base = strip_effects(state.model, [s])
            ev, m = evaluate(ctx, base, list(group), channel, truth_ref, merge_with=merge)
            if kind == "merge":  # one value on both chains when they agree (R5), else one per chain
                m = (
                    with_effects(state.model, {s.name: s.params(ev.values[0], channel="both")})
                    if ev.same_on_both
                    else with_effect_on(
                        state.model, s.name, cast(str, s.channel_param), {s.key: ev.values[0]}
                    )
                )
            ev = _check_upstream_truth(ctx, ev, m, channel, s)
            evals.append((ev, m, tuple(group), kind))
        if step == 0:
            first = evals
        steps.append(tuple(e[0] for e in evals))
        passing = [e for e in evals if e[0].accepted]
        if not passing:
            break
        ev, m, chosen, _ = min(passing, key=lambda e: e[0].delta_bic_heldout)
        reopen = tuple(n for n in state.reopen if n not in {s.name for s in chosen})
        state = _ChannelState(
            m,
            _join(
                [s for s in state.specs if s.name not in state.reopen or s.name in reopen], chosen
            ),
            {**state.evidence, **{s.name: ev for s in chosen}},
            ev,
            reopen,
        )
        own = [s for s in state.specs if _own(state.model, s)]
        # Re-fit this channel's own effects whenever anything joined them, a shared (merged)
        # effect included: an efficiency fitted before a delay was found is biased by cos(w tau).
        # Likewise whenever parameters were fitted along (plant, shape): their per-run estimates
        # are correlated, so the pooled values are not the joint optimum on all runs.
        if own and (
            len({s.name for s in state.specs if not s.is_plant}) >= 2
            or any(not s.tested for s in own)
        ):
            state.model = polish(
                ctx, strip_effects(state.model, own), own, state.model, channel, truth_ref
            )
        has_gap = _refit_states_and_polish(ctx, state, channel, truth_ref)
    return state, has_gap, first


def _refit_states_and_polish(
    ctx: AnalysisContext, state: _ChannelState, channel: str, truth_ref: bool
) -> bool:
    """After an effect joined `state` (modified in place): the runs' initial states fitted again
    (on a truth channel), then, while a gap is left, further joint re-fits of this channel's own
    parameters (`_polish_rounds`) and the states once more. Returns whether a gap is left.
    """
    _refit_states(ctx, state.model, channel)
    has_gap = channel_has_gap(ctx, state.model, channel, truth_ref)
    own = [s for s in state.specs if _own(state.model, s)]
    if not has_gap or not own:
        return has_gap
    model = _polish_rounds(ctx, state.model, own, channel, truth_ref)
    if model is state.model:
        return has_gap
    state.model = model
    _refit_states(ctx, state.model, channel)
    return channel_has_gap(ctx, state.model, channel, truth_ref)


def _refit_states(ctx: AnalysisContext, model: Model, channel: str) -> None:
    """On a truth channel: the runs' initial states fitted again with `model` (they were fitted
    with the plant alone, or with the effects as they were).
    """
    if channel in TRUTH_CHANNELS and ctx.settings.identify:
        _use_runs(
            ctx,
            identify_plant(ctx.runs, model, ctx.noise, keys=(), state_channels=TRUTH_CHANNELS).runs,
        )


def _polish_rounds(
    ctx: AnalysisContext, model: Model, specs: Sequence[EffectSpec], channel: str, truth_ref: bool
) -> Model:
    """Joint re-fits of `specs` from `model` while a gap is left and each still lowers the cost
    by `polish_min_gain`, at most `max_polish_rounds` times (`DiscrepancySettings`; `model` itself
    if none lowers it).

    A joint fit of many parameters (collision's three with structural damping and the stroke
    plant) may stop short of its optimum within one least-squares call (`max_nfev`).
    """
    cost = _channel_cost(ctx, model, specs, channel, truth_ref)
    for _ in range(ctx.settings.max_polish_rounds):
        trial = polish(ctx, strip_effects(model, specs), specs, model, channel, truth_ref)
        trial_cost = _channel_cost(ctx, trial, specs, channel, truth_ref)
        if not trial_cost < cost:
            break
        gain = 1.0 - trial_cost / cost
        model, cost = trial, trial_cost
        if gain < ctx.settings.polish_min_gain or not channel_has_gap(
            ctx, model, channel, truth_ref
        ):
            break
    return model


def _channel_cost(
    ctx: AnalysisContext, model: Model, specs: Sequence[EffectSpec], channel: str, truth_ref: bool
) -> float:
    """Weighted residual sum of squares of `model` on `channel` (the fit's own cost)."""
    problem = ctx.problem(channel, ctx.folds, truth_ref, strip_effects(model, specs))
    return sum(float(np.dot(r, r)) for r in problem.residuals([model])[0])


def _check_upstream_truth(
    ctx: AnalysisContext, ev: CandidateEvidence, model: Model, channel: str, spec: EffectSpec
) -> CandidateEvidence:
    """R6: a stroke-physics effect judged on pitch_deg must leave stroke_deg without a gap."""
    if channel != "pitch_deg" or "stroke_deg" not in EFFECT_CHANNELS[spec.name] or not ev.accepted:
        return ev
    ok = not channel_has_gap(ctx, model, "stroke_deg", False)
    rules = {**ev.rules, "R6_stroke_truth_intact": ok}
    return replace(ev, rules=rules, accepted=all(rules.values()))


def _states_on_sensor(
    ctx: AnalysisContext, model: Model, channel: str, sensors_done: Sequence[str]
) -> bool:
    """Fit the runs' initial states on the truth and on the sensors modelled so far (`sensors_done`,
    `channel`); keep them (True) only if that leaves
    `channel` without a gap and no gap anywhere else.

    A video-rate truth leaves the initial state loose; the transient of a wrong state shows on the
    far more precise sensor at the start of a run. No effect of the vocabulary acts only there.
    """
    channels = TRUTH_CHANNELS + tuple(dict.fromkeys([*sensors_done, channel]))
    runs, before, after = fit_initial_states(ctx.runs, model, ctx.noise, channels)
    if not after < before:
        return False
    trial = AnalysisContext(runs, ctx.noise, ctx.settings, ctx.tracks)
    if any(channel_has_gap(trial, model, c, False) for c in channels):
        return False
    _use_runs(ctx, runs)
    return True


def _search_channel(
    ctx: AnalysisContext,
    model_in: Model,
    start: Model,
    channel: str,
    truth_ref: bool,
    found: Sequence[FoundEffect],
    sensors_done: Sequence[str] = (),
) -> tuple[_ChannelState, bool, list[Any]]:
    """Shared-sensor test, greedy forward selection, then pair backtracking if a gap is left; on a
    sensor, a gap left is then tried against the runs' initial states fitted on the sensor, and
    last against the upstream plant refitted on it.
    """
    st = ctx.settings
    steps: list[Any] = []
    state = _ChannelState(start, [], {})
    if channel in SENSOR_CHANNELS:
        shared = [s for s in candidate_specs(channel) if _offer(model_in, start, s, []) == "merge"]
        tries = ([shared] if shared else []) + ([[s] for s in shared] if len(shared) > 1 else [])
        for group in tries:
            ev, m = evaluate_shared(ctx, start, group, channel, truth_ref)
            steps.append((ev,))
            if ev.accepted:
                state = _ChannelState(
                    m, list(group), {s.name: ev for s in group}, ev, tuple(s.name for s in group)
                )
                break
    base_state = _ChannelState(
        state.model, list(state.specs), dict(state.evidence), state.last, state.reopen
    )
    state, has_gap, first = _greedy(
        ctx, model_in, state, channel, truth_ref, found, steps, st.max_effects_per_channel
    )
    if has_gap and st.pair_fallback:
        singles = [e for e in first if e[3] in ("new", "merge")]
        best = None
        for i in range(len(singles)):
            for j in range(i + 1, len(singles)):
                a, b = singles[i], singles[j]
                specs = _join(a[2], b[2])
                starts = {
                    (s.name, s.key): v
                    for s, v in zip(
                        list(b[2]) + list(a[2]), list(b[0].values) + list(a[0].values), strict=True
                    )
                }
                x_start = np.array([s.to_fit(starts[(s.name, s.key)]) for s in specs])
                ev, m = evaluate(ctx, base_state.model, specs, channel, truth_ref, x_start)
                for s in (a[2][0], b[2][0]):
                    ev = _check_upstream_truth(ctx, ev, m, channel, s)
                for s, kind in ((a[2][0], a[3]), (b[2][0], b[3])):
                    # the other chain's effect: one value on both when they agree (R5)
                    if kind == "merge":
                        k = specs.index(s)
                        merged = same_on_both(
                            s, *_other_chain(base_state.model, s, found), ev.values[k], ev.se[k], st
                        )
                        if merged is not None:
                            m = with_effects(m, {s.name: s.params(merged, channel="both")})
                steps.append((ev,))
                if ev.accepted and (
                    best is None or ev.delta_bic_heldout < best[0].delta_bic_heldout
                ):
                    best = (ev, m, specs)
        greedy_after = (
            state.last.heldout_nrmse_after
            if state.last is not None and state.specs != base_state.specs
            else math.inf
        )
        if best is not None and best[0].heldout_nrmse_after < greedy_after:
            ev, m, specs = best
            pair_state = _ChannelState(
                m,
                _join(base_state.specs, specs),
                {**base_state.evidence, **{s.name: ev for s in specs}},
                ev,
                base_state.reopen,
            )
            _refit_states_and_polish(ctx, pair_state, channel, truth_ref)
            state, has_gap, _ = _greedy(
                ctx,
                model_in,
                pair_state,
                channel,
                truth_ref,
                found,
                steps,
                max(st.max_effects_per_channel - 2, 0),
            )
    if has_gap and channel in SENSOR_CHANNELS and st.identify and not truth_ref and state.specs:
        has_gap = not _states_on_sensor(ctx, state.model, channel, sensors_done)
    if has_gap and channel in SENSOR_CHANNELS and st.identify and not truth_ref:
        state, has_gap = _refine_plant_on_sensor(ctx, state, channel)
    return state, has_gap, steps


def _refine_plant_on_sensor(
    ctx: AnalysisContext, state: _ChannelState, channel: str
) -> tuple[_ChannelState, bool]:
    """The sensor resolves the motion far better than a video truth: a gap left on a sensor channel
    may be the fitted plant's own imprecision. Re-fit the upstream plant parameters on the sensor,
    jointly with the effects found on this sensor alone; keep them only if that closes the gap and
    the truth stays at noise.
    """
    truth = UPSTREAM_TRUTH[channel]
    own = [
        s for s in state.specs if not s.is_plant and s.judged_on == channel and _own(state.model, s)
    ]
    specs = own + [
        plant_spec(k, state.model, channel, rel_range=0.1)
        for k, c in PLANT_PARAMETERS.items()
        if c == truth
    ]
    refined = polish(ctx, strip_effects(state.model, own), specs, state.model, channel, False)
    if channel_has_gap(ctx, refined, channel, False) or channel_has_gap(ctx, refined, truth, False):
        return state, True
    return _ChannelState(refined, state.specs, state.evidence, state.last, state.reopen), False


def find_effects(
    runs: Sequence[Run],
    model: Model,
    noise: Mapping[str, float],
    settings: DiscrepancySettings,
    progress: Callable[[str], None] | None = None,
    tracks: Sequence[tuple[np.ndarray, np.ndarray]] | None = None,
    nominal: Mapping[str, float] | None = None,
) -> tuple[Model, tuple[FoundEffect, ...], tuple[ChannelSearch, ...], tuple[Run, ...]]:
    """Greedy, channel-by-channel search for the missing effects (rules in the module docstring).

    nominal: {plant key: value} the plant identification's fit range is centred on (the input
    model's; default `model`'s): the pitch parameters identified again after a stroke effect was
    found may have been bent far by its absence.

    Returns
    -------
    (model_out, found effects, per-channel search records, the runs with their initial states as
    last fitted)
    """
    ctx = AnalysisContext(runs, noise, settings, tracks)
    current = model
    found: list[FoundEffect] = []
    searches = []
    unexplained_truth: set[str] = set()
    # sensor channels modelled to noise level (they pin the initial states)
    sensors_done: list[str] = []
    for channel in CHANNEL_ORDER:
        if progress:
            progress(channel)
        if channel == "pitch_deg" and "stroke_deg" in unexplained_truth:
            if channel_has_gap(ctx, current, channel, False):
                unexplained_truth.add(channel)
            searches.append(
                ChannelSearch(channel, False, "downstream of an unexplained stroke_deg gap", ())
            )
            continue
        truth_ref = channel in SENSOR_CHANNELS and UPSTREAM_TRUTH[channel] in unexplained_truth
        if not channel_has_gap(ctx, current, channel, truth_ref):
            searches.append(ChannelSearch(channel, truth_ref, "no gap", ()))
            sensors_done += [channel] if channel in SENSOR_CHANNELS and not truth_ref else []
            continue
        if (
            channel in SENSOR_CHANNELS
            and not truth_ref
            and settings.identify
            and _states_on_sensor(ctx, current, channel, sensors_done)
        ):
            searches.append(
                ChannelSearch(
                    channel,
                    truth_ref,
                    "no gap once the runs' initial "
                    "states are fitted on this sensor "
                    "too (a video-rate truth leaves them "
                    "loose)",
                    (),
                )
            )
            sensors_done.append(channel)
            continue
        state, has_gap, steps = _search_channel(
            ctx, model, current, channel, truth_ref, found, sensors_done
        )
        current = state.model
        for s in state.specs:
            if not s.tested:
                continue
            ev = state.evidence.get(s.name)
            found.append(
                FoundEffect(
                    name=s.name,
                    channel=channel,
                    parameters={},
                    evidence=ev.as_dict() if ev is not None else {},
                    explains=EFFECT_CHANNELS[s.name],
                )
            )
        if has_gap and channel in TRUTH_CHANNELS:
            unexplained_truth.add(channel)
        if not has_gap and channel in SENSOR_CHANNELS and not truth_ref:
            sensors_done.append(channel)
        if channel == "stroke_deg" and state.specs and settings.identify and not has_gap:
            # the pitch parameters were identified under the old stroke motion: identify them again
            fit = identify_plant(
                ctx.runs,
                current,
                noise,
                keys=[k for k, c in PLANT_PARAMETERS.items() if c == "pitch_deg"],
                centre=nominal,
            )
            current = fit.model
            _use_runs(ctx, fit.runs)
        searches.append(ChannelSearch(channel, truth_ref, "", tuple(steps)))
    return current, tuple(merge_sensor_channels(found, current)), tuple(searches), ctx.runs


def strip_effects(model: Model, specs: Sequence[EffectSpec]) -> Model:
    """`model` without the specs' effects: a sensor effect removed from the spec's chain only (and
    whole when it is one value shared by both chains).
    """
    for s in specs:
        if s.is_plant or model.effect(s.name) is None:
            continue
        if s.channel_param is not None and _own(model, s):
            model = without_effect_on(model, s.name, s.channel_param)
        elif s.channel_param is None or model.effect_on(s.name, s.channel_param) is not None:
            model = replace(model, effects=tuple((n, e) for n, e in model.effects if n != s.name))
    return model
