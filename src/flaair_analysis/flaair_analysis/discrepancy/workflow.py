"""The whole workflow: identify the plant, compare, localise, name, refit, decide the status."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from flaair_model.effects import SENSOR_CHANNELS
from flaair_model.model import Model, effect_params
from flaair_model.settings import DiscrepancySettings
from flaair_model.validation import ModelError
from flaair_sim.core.plant import simulate

from .diagnosis import Diagnosis, diagnose, drive_tracks, noise_estimates, nrmse_by_channel
from .discovery import DiscoveryOutcome, discover
from .effect_judging import AnalysisContext, FoundEffect
from .fitting import Fold, fold_nrmse
from .identification import FIT_RANGE, PlantFit, identify_plant
from .runs import DiscrepancyInputError, Run, check_runs, simulate_runs
from .search import (
    CHANNEL_ORDER,
    ChannelSearch,
    channel_has_gap,
    find_effects,
    polish,
    strip_effects,
)
from .vocabulary import (
    ENTRIES,
    NOT_SEPARABLE,
    PLANT_PARAMETERS,
    SENSOR_SIDE,
    UPSTREAM_TRUTH,
    candidate_groups,
)


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
    plant_fit : the identification of this robot's plant (`identification.PlantFit`; None when
        DiscrepancySettings.identify is off).
    plant_parameters : {key: {value, nominal, stderr}} of the fitted plant parameters in model_out
        (stderr from the identification, before the joint fits with effects).
    not_separable : [{effect, reason}] vocabulary effects whose signature a plant-parameter change
        reproduces: not searched for, and not claimed.
    approximate : effects fitted on a channel that keeps a gap: in `model_out`, not named (they
        reduce the gap without explaining it).
    discovered : library terms the discovery step added (`discovery.Discovered`).
    discovery_tried : the discovery's candidates per step ({channel, candidates}).
    """

    status: str
    effects: tuple[Any, ...]
    model_in: Model
    model_out: Model
    gap_before: dict[str, Any]
    gap_after: dict[str, Any]
    gap_in_sample_after: dict[str, Any]
    noise: dict[str, Any]
    diagnosis_before: Diagnosis
    diagnosis_after: Diagnosis
    searches: tuple[Any, ...]
    remaining: tuple[Any, ...]
    sims_before: tuple[Any, ...]
    sims_after: tuple[Any, ...]
    summary: str
    run_names: tuple[Any, ...] = ()
    plant_fit: PlantFit | None = None
    plant_parameters: dict[str, Any] = field(default_factory=dict[str, Any])
    not_separable: tuple[Any, ...] = ()
    approximate: tuple[Any, ...] = ()
    discovered: tuple[Any, ...] = ()
    discovery_tried: tuple[Any, ...] = ()


# ------------------------------------------------------------------------- held-out gap after


def _refit_on(
    ctx: AnalysisContext, effects: Sequence[FoundEffect], model_out: Model, folds: Sequence[Fold]
) -> Model:
    """Re-fit the found effects' parameters on `folds`, channel by channel (upstream first)."""
    current = model_out
    for channel in CHANNEL_ORDER:
        side = SENSOR_SIDE.get(channel)
        # an effect is re-fitted where it was found; one with its own value per sensor chain on each
        names = [
            f.name
            for f in effects
            if f.channel.split("+")[0] == channel
            or (
                side is not None
                and channel in f.channel.split("+")
                and getattr(current.effect_on(f.name, side), "channel", None) == side
            )
        ]
        specs: list[Any] = []
        for g in candidate_groups(channel, current if ctx.settings.identify else None):
            if g[0].name in names:
                specs += [
                    s
                    for s in g
                    if not (s.is_plant and any(t.is_plant and t.key == s.key for t in specs))
                ]
        if specs:
            current = polish(
                ctx, strip_effects(current, specs), specs, current, channel, False, folds
            )
    return current


def _heldout_nrmse(
    ctx: AnalysisContext, effects: Sequence[FoundEffect], model_out: Model
) -> dict[str, Any]:
    """Per-channel NRMSE of held-out predictions: each fold predicted by a re-fit on the others."""
    per_fold = [
        _refit_on(ctx, effects, model_out, [g for i, g in enumerate(ctx.folds) if i != k])
        if effects
        else model_out
        for k in range(len(ctx.folds))
    ]
    return fold_nrmse(ctx.runs, ctx.folds, per_fold)


# ------------------------------------------------------------------------------- the workflow


def analyse(
    runs: Sequence[Run],
    model: Model,
    settings: DiscrepancySettings,
    progress: Callable[[str], None] | None = None,
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
    runs = _checked(runs, model)
    sims_before, noise, tracks, diag_before, gap_before = _compared(runs, model, settings, progress)
    plant_fit, base, sims_fit, diag_fit = None, model, sims_before, diag_before
    if settings.identify:
        plant_fit, sims_fit, diag_fit = _identified(runs, model, noise, settings, tracks, progress)
        base = plant_fit.model
        runs = plant_fit.runs  # with their initial states fitted along with the plant
    common: dict[str, Any] = dict(
        model_in=model,
        gap_before=gap_before,
        noise=noise,
        diagnosis_before=diag_before,
        sims_before=tuple(sims_before),
        run_names=tuple(r.name for r in runs),
        plant_fit=plant_fit,
        not_separable=_not_separable(settings),
    )
    if not diag_fit.gaps:
        return _no_discrepancy(model, base, plant_fit, runs, sims_fit, diag_fit, common)
    effects: Sequence[FoundEffect]
    model_out, effects, searches, runs = find_effects(
        runs,
        base,
        noise,
        settings,
        progress,
        tracks,
        nominal={k: float(getattr(model.plant, k)) for k in PLANT_PARAMETERS},
    )
    ctx = AnalysisContext(runs, noise, settings, tracks)
    diag_after, remaining = _where_left(ctx, model_out, searches)
    discovery = None
    if remaining and settings.discover:
        found_ctx = (
            ctx if plant_fit is None else AnalysisContext(plant_fit.runs, noise, settings, tracks)
        )
        discovery = _discovery(found_ctx, model, model_out, effects, remaining, plant_fit, progress)
        if discovery.discovered or discovery.named:
            model_out, runs, ctx = discovery.model, discovery.runs, found_ctx
            effects = _effects_after(discovery, effects, model_out)
            diag_after, remaining = _where_left(ctx, model_out, searches)
    discovered = discovery.discovered if discovery is not None else ()
    sims_after, gap_after, in_sample = _gap_after(
        ctx, runs, effects, bool(discovered), model_out, sims_fit, progress
    )
    status = _status(remaining, bool(effects or discovered))
    effects, approximate = _established(effects, remaining)
    return DiscrepancyResult(
        status=status,
        effects=tuple(effects),
        model_out=model_out,
        gap_after=gap_after,
        gap_in_sample_after=in_sample,
        diagnosis_after=diag_after,
        searches=searches,
        remaining=remaining,
        sims_after=tuple(sims_after),
        summary=_summary(
            status,
            effects,
            diag_after,
            remaining,
            _plant_parameters(model, model_out, plant_fit),
            tuple(e.name for e in approximate),
            discovered,
        ),
        plant_parameters=_plant_parameters(model, model_out, plant_fit),
        approximate=approximate,
        discovered=tuple(discovered),
        discovery_tried=discovery.tried if discovery is not None else (),
        **common,
    )


def _not_separable(settings: DiscrepancySettings) -> tuple[dict[str, str], ...]:
    """The effects a change of the fitted plant mimics (not searched), and why."""
    if not settings.identify:
        return ()
    return tuple({"effect": n, "reason": ENTRIES[n].note} for n in NOT_SEPARABLE)


def _established(
    effects: Sequence[FoundEffect], remaining: Sequence[dict[str, Any]]
) -> tuple[tuple[FoundEffect, ...], tuple[FoundEffect, ...]]:
    """The effects named, and those fitted only approximately: found on a channel that keeps a
    gap, they reduce it without explaining it (physics outside the vocabulary may be what they
    stand in for), so they stay in the model but are not named.
    """
    gaps = {r["channel"] for r in remaining}
    # an effect found on both chains at once carries "stroke_sensor_v+pitch_sensor_v"
    approximate = tuple(e for e in effects if gaps & set(e.channel.split("+")))
    return tuple(e for e in effects if e not in approximate), approximate


def _status(remaining: Sequence[Any], found: bool) -> str:
    """Unexplained while a gap is left; else explained when something was found."""
    if remaining:
        return "unexplained"
    return "explained" if found else "no_discrepancy"


def _compared(
    runs: Sequence[Run],
    model: Model,
    settings: DiscrepancySettings,
    progress: Callable[[str], None] | None,
) -> tuple[list[Any], dict[str, float], list[tuple[Any, Any]], Diagnosis, dict[str, float]]:
    """The input model compared with the runs.

    Returns
    -------
    tuple
        (its simulated channels per run, the noise RMS per channel, the drive tracks, its
        diagnosis, its NRMSE per channel).
    """
    if progress:
        progress("compare")
    sims_before = simulate_runs([model], runs)[0]
    noise = noise_estimates(runs, sims_before, model)
    tracks = drive_tracks(runs)
    diag_before = diagnose(runs, sims_before, model, noise, settings, tracks=tracks)
    gap_before = nrmse_by_channel(runs, sims_before)
    return sims_before, noise, tracks, diag_before, gap_before


def _gap_after(
    ctx: AnalysisContext,
    runs: Sequence[Run],
    effects: Sequence[FoundEffect],
    any_discovered: bool,
    model_out: Model,
    sims_fit: Sequence[Any],
    progress: Callable[[str], None] | None,
) -> tuple[list[Any], dict[str, Any], dict[str, float]]:
    """The gap `model_out` leaves: held-out when something was found (the fitted plant's
    otherwise, nothing being re-fitted).

    Returns
    -------
    tuple
        (its simulated channels per run, the NRMSE per channel held out, in sample).
    """
    if progress:
        progress("held-out gap")
    sims_after = simulate_runs([model_out], runs)[0]
    gap_after = (
        _heldout_nrmse(ctx, effects, model_out)
        if effects or any_discovered
        else nrmse_by_channel(runs, sims_fit)
    )
    in_sample = nrmse_by_channel(runs, sims_after)
    return sims_after, gap_after, in_sample


def _identified(
    runs: Sequence[Run],
    model: Model,
    noise: Mapping[str, float],
    settings: DiscrepancySettings,
    tracks: Sequence[tuple[Any, Any]],
    progress: Callable[[str], None] | None,
) -> tuple[PlantFit, list[Any], Diagnosis]:
    """The robot's own plant fitted (`identify_plant`), its simulation and its diagnosis."""
    if progress:
        progress("identify plant")
    plant_fit = identify_plant(runs, model, noise)
    sims_fit = simulate_runs([plant_fit.model], plant_fit.runs)[0]
    diag_fit = diagnose(plant_fit.runs, sims_fit, plant_fit.model, noise, settings, tracks=tracks)
    return plant_fit, sims_fit, diag_fit


def _checked(runs: Sequence[Run], model: Model) -> tuple[Run, ...]:
    """The runs checked (`check_runs`), and the model simulatable at their rate."""
    runs = check_runs(runs)
    for r in runs:
        try:
            simulate(r.drive_v[:8], r.fs_hz, model)
        except ModelError as exc:
            raise DiscrepancyInputError(
                f"model cannot be simulated at {r.fs_hz:g} Hz: {exc}"
            ) from None
    return runs


def _no_discrepancy(
    model: Model,
    base: Model,
    plant_fit: PlantFit | None,
    runs: Sequence[Run],
    sims_fit: Sequence[Any],
    diag_fit: Diagnosis,
    common: dict[str, Any],
) -> DiscrepancyResult:
    """The result when the fitted plant leaves no gap: the plant is all that changed."""
    gap_fit = nrmse_by_channel(runs, sims_fit)
    plant = _plant_parameters(model, base, plant_fit)
    return DiscrepancyResult(
        status="no_discrepancy",
        effects=(),
        model_out=base,
        gap_after=gap_fit,
        gap_in_sample_after=dict(gap_fit),
        diagnosis_after=diag_fit,
        searches=(),
        remaining=(),
        sims_after=tuple(sims_fit),
        summary=_summary("no_discrepancy", (), diag_fit, (), plant),
        plant_parameters=plant,
        **common,
    )


def _discovery(
    ctx: AnalysisContext,
    model: Model,
    model_out: Model,
    effects: Sequence[FoundEffect],
    remaining: Sequence[dict[str, Any]],
    plant_fit: PlantFit | None,
    progress: Callable[[str], None] | None,
) -> DiscoveryOutcome:
    """The term library searched on the channels the vocabulary left a gap on."""
    gaps = {r["channel"] for r in remaining}
    return discover(
        ctx,
        model_out,
        sorted(gaps),
        progress,
        [e for e in effects if gaps & set(e.explains)],
        plant_fit.model.plant if plant_fit is not None else None,
        nominal={k: float(getattr(model.plant, k)) for k in PLANT_PARAMETERS},
    )


def _effects_after(
    discovery: DiscoveryOutcome, effects: Sequence[FoundEffect], model_out: Model
) -> list[FoundEffect]:
    """The effects after the discovery: those it replaced out, those it named in, each at the
    value the model holds (the discovery re-fits effects along with its terms).
    """
    kept = [e for e in effects if e not in discovery.replaced] + list(discovery.named)
    return [
        replace(e, parameters=effect_params(on))
        if (on := model_out.effect(e.name)) is not None
        else e
        for e in kept
    ]


def _where_left(
    ctx: AnalysisContext, model_out: Model, searches: Sequence[ChannelSearch]
) -> tuple[Diagnosis, tuple[Any, ...]]:
    """The diagnosis of `model_out` and where gaps remain."""
    sims = simulate_runs([model_out], ctx.runs)[0]
    diag = diagnose(ctx.runs, sims, model_out, ctx.noise, ctx.settings, tracks=ctx.tracks)
    sensor_ok = {
        c: not channel_has_gap(ctx, model_out, c, True)
        for c in SENSOR_CHANNELS
        if any(s.channel == c and s.truth_referenced for s in searches)
    }
    return diag, _remaining(diag, searches, sensor_ok)


def _plant_parameters(model_in: Model, model_out: Model, fit: PlantFit | None) -> dict[str, Any]:
    """{key: {value, nominal, stderr}} of the fitted
    plant parameters ({} without identification).
    """
    if fit is None:
        return {}
    return {
        k: {
            "value": float(getattr(model_out.plant, k)),
            "nominal": float(getattr(model_in.plant, k)),
            "stderr": fit.stderr.get(k, math.nan),
        }
        for k in PLANT_PARAMETERS
    }


def _remaining(
    diag: Diagnosis, searches: Sequence[ChannelSearch], sensor_ok: Mapping[str, bool]
) -> tuple[Any, ...]:
    """Where gaps remain; sensor_ok: sensor channel explained when driven by the measured angle."""
    skipped = {s.channel: s.skipped for s in searches}
    out = []
    for c in diag.gaps:
        g = diag.channels[c]
        note = g.interpretation
        if skipped.get(c, "").startswith("downstream"):
            note = "possibly propagated from the unexplained stroke_deg gap; " + note
        if c in sensor_ok:
            note = (
                "the sensor itself is explained when driven by the measured angle: this gap is "
                "the "
                f"{UPSTREAM_TRUTH[c]} gap propagated; "
                if sensor_ok[c]
                else "a sensor gap beyond the propagated physics error (judged against the "
                "measured angle); "
            ) + note
        near = _near_misses(searches, c)
        if near:
            note = note + "; " + near
        out.append(
            {
                "channel": c,
                "band_hz": g.worst_band_hz,
                "drive_level_ratio": g.level_ratio,
                "level_nrmse": g.level_nrmse,
                "stretch": list(g.worst_stretch),
                "model_error_nrmse": g.model_error_nrmse,
                "note": note,
            }
        )
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
                    runs = "; ".join(
                        ", ".join(f"{n} {v:.4g}" for n, v, _ in pr) for pr in ev.per_run
                    )
                    notes.append(
                        f"{'+'.join(ev.labels)} would fit each run alone but its "
                        f"parameter differs between runs ({runs})"
                    )
    return "nearest vocabulary effect refused: " + "; ".join(dict.fromkeys(notes)) if notes else ""


def _summary(
    status: str,
    effects: Sequence[FoundEffect],
    diag: Diagnosis,
    remaining: Sequence[dict[str, Any]],
    plant: Mapping[str, dict[str, Any]] | None = None,
    approximate: Sequence[str] = (),
    discovered: Sequence[Any] = (),
) -> str:
    parts = []
    if plant:
        change = {k: p["value"] / p["nominal"] - 1.0 for k, p in plant.items()}
        moved = sorted(change, key=lambda k: -abs(change[k]))[:3]
        parts.append(
            "This robot's plant was fitted first (largest changes from the model: "
            + ", ".join(f"{k} {change[k]:+.1%}" for k in moved)
            + ")."
        )
        edge = [
            k
            for k, p in plant.items()
            if abs(math.log(p["value"] / p["nominal"])) >= 0.999 * math.log1p(FIT_RANGE)
        ]
        if edge:
            parts.append(
                f"At the edge of the plant fit's range (x{1 + FIT_RANGE:g} of the model): "
                f"{', '.join(edge)}; this robot may lie beyond it."
            )
    if status == "no_discrepancy":
        parts.append(
            "With its own plant parameters the model explains every channel to noise "
            "level: residuals are white and at the noise RMS; no physics is missing."
        )
        return " ".join(parts)
    if effects:
        parts.append(
            "Found: "
            + ", ".join(
                f"{e.name} on {e.channel} ({format_parameters(e.parameters)})" for e in effects
            )
            + "."
        )
    if discovered:
        parts.append(
            "Outside the vocabulary, discovered from the term library (a hypothesis "
            "for the lab to test, not a named effect): "
            + ", ".join(f"{d.term.expression} on {d.term.acts_on}" for d in discovered)
            + "."
        )
    if status == "explained":
        parts.append("With them every channel is explained to noise level.")
    else:
        if approximate:
            parts.append(
                "Fitted but not named, as they only reduce the gap on the channel they were "
                f"found on: {', '.join(approximate)}."
            )
        for r in remaining:
            parts.append(
                f"A gap remains on {r['channel']} (worst band {r['band_hz']} Hz, full/low "
                f"drive error ratio {r['drive_level_ratio']:.2g}, worst stretch "
                f"{r['stretch'][0]} {r['stretch'][1]:.2f}-{r['stretch'][2]:.2f} s) that "
                f"no vocabulary effect removes: {r['note']}."
            )
    return " ".join(parts)


def format_parameters(params: Mapping[str, Any]) -> str:
    """'delay_s=0.00015, channel=stroke'; one value per
    sensor chain: 'stroke: delay_s=0.00015; pitch: ...'.
    """
    if params and all(isinstance(v, Mapping) for v in params.values()):
        return "; ".join(f"{side}: {format_parameters(p)}" for side, p in params.items())
    return ", ".join(
        f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items()
    )
