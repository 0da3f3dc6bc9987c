"""The discovery step's candidates: every library term that may close a channel's gap, each
fitted alone on the current plant for a first ranking (`candidates`), and what a term is fitted
jointly with (`fitted_along`: its equation's plant parameters, or the sensor chain's effects).

The coefficient's search range is `COEFFICIENT_RANGE` times the size of the signal the term adds
to (spring torque, drive or sensor deviation) over the RMS of its feature along the current
model's motion. `discovery` judges the shortlist.

Besides the table's rows, a site may take any form composed from the primitives (a dynamics
site) or the signals (the drive, a sensor), `flaair_model.terms.composed_kinds`, named by its
expression. They are ranked cheaply: the residual's sensitivity to each (at a dynamics site, the
plant's response to the form's torque along the current motion, linearised about it, in batches
of `LINEAR_BATCH`: `runs.torque_changes`; at the drive, one simulation at a small coefficient,
in batches of `RANK_BATCH`; at a sensor site, where a term adds to the chain's output, its
feature along the current model, exactly) and one linearized least-squares step give the
residual it would leave; only the
best `discovery_composed_fits` per site are then fitted through the simulator like a row. A
composed form that is numerically degenerate on the runs (zero or constant along the motion) is
skipped and counted (`Candidates.degenerate`), never fitted.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from flaair_model.effects import SENSOR_CHANNELS
from flaair_model.model import Model
from flaair_model.terms import (
    DYNAMICS_SITES,
    MAX_DYNAMICS_TERMS,
    DiscoveredTerm,
    TermKind,
    TermSignals,
    composed_kinds,
    kinds_for,
    monomial,
    primitive_values,
)
from flaair_model.validation import ModelError

from .effect_judging import AnalysisContext
from .fitting import ResidualProblem, fit_specs, models_for, spec_value, with_terms
from .identification import FIT_RANGE
from .runs import simulate_runs, torque_changes
from .vocabulary import (
    PLANT_PARAMETERS,
    SENSOR_SIDE,
    EffectSpec,
    candidate_groups,
    plant_spec,
    term_specs,
)

__all__ = [
    "COEFFICIENT_RANGE",
    "DEGENERATE_REL_STD",
    "LINEAR_BATCH",
    "PLANT_STEP",
    "PROBE_FRACTION",
    "RANK_BATCH",
    "SITES_FOR_GAP",
    "Candidates",
    "candidates",
    "fitted_along",
    "is_degenerate",
    "one_column_rss",
    "plant_box_spec",
]

SITES_FOR_GAP: dict[str, tuple[str, ...]] = {
    "stroke_deg": ("stroke_dynamics", "drive"),
    "pitch_deg": ("pitch_dynamics",),
    "stroke_sensor_v": ("stroke_sensor_v",),
    "pitch_sensor_v": ("pitch_sensor_v",),
}
# A coefficient may reach this many times the size of its feature's whole share of the channel.
COEFFICIENT_RANGE = 3.0
# A composed form's sensitivity is probed with a torque this fraction of the spring torque.
PROBE_FRACTION = 0.01
# Fit-space step of a plant parameter's probe in the composed forms' ranking.
PLANT_STEP = 1e-3
# A composed feature whose standard deviation is below this fraction of its RMS is constant.
DEGENERATE_REL_STD = 1e-6
# Composed forms ranked per batch of simulations (a run set of each held in memory at once).
RANK_BATCH = 96
# Dynamics forms whose linearised responses are computed at once (an (n, batch) torque array per
# run held in memory).
LINEAR_BATCH = 256


@dataclass(frozen=True)
class Candidates:
    """A step's candidates, best fit first: (rss, kind, site, specs, x) each; the composed forms
    ranked (each with its linearized rss, best first), the degenerate ones skipped, and how long
    the ranking took.
    """

    fitted: list[tuple[Any, ...]]
    composed_ranked: tuple[tuple[str, str, float], ...]
    degenerate: tuple[tuple[str, str], ...]
    rank_s: float = 0.0  # wall time of ranking the composed forms, every site of the step


def _motion(ctx: AnalysisContext, model: Model) -> list[dict[str, Any]]:
    """Simulated channels per run, with the velocities (rad/s), the sensor deviations and the
    `TermSignals` a drive or sensor form reads.
    """
    sims = simulate_runs([model], ctx.runs)[0]
    vref = model.sensors.reference_voltage_v
    out = []
    for run, sim in zip(ctx.runs, sims, strict=True):
        phi, psi = np.radians(sim["stroke_deg"]), np.radians(sim["pitch_deg"])
        signals = TermSignals.of_block(
            run.fs_hz,
            run.drive_v,
            phi=phi,
            psi=psi,
            stroke_sensor_v=sim["stroke_sensor_v"] - vref,
            pitch_sensor_v=sim["pitch_sensor_v"] - vref,
        )
        dphi, dpsi = np.gradient(phi) * run.fs_hz, np.gradient(psi) * run.fs_hz
        out.append(
            {
                "phi": phi,
                "dphi": dphi,
                "psi": psi,
                "dpsi": dpsi,
                "signals": signals,
                "primitives": _primitives(phi, dphi, psi, dpsi, signals),
                # the states at each sample period's midpoint, the drive and time held: what
                # the kernel integrates a form's torque at, to second order
                "midpoint": _primitives(
                    _midpoint(phi), _midpoint(dphi), _midpoint(psi), _midpoint(dpsi), signals
                ),
            }
        )
    return out


def _midpoint(x: np.ndarray) -> np.ndarray:
    """`x` halfway to the next sample (the last sample held)."""
    return np.append(0.5 * (x[:-1] + x[1:]), x[-1:])


def _primitives(
    phi: np.ndarray, dphi: np.ndarray, psi: np.ndarray, dpsi: np.ndarray, signals: TermSignals
) -> tuple[np.ndarray, ...]:
    """The `PRIMITIVES` along a motion (the drive, its rate and the time from `signals`)."""
    return primitive_values(phi, dphi, psi, dpsi, signals.drive_v, signals.t, signals.ddrive_v)


def _primitives_of(m: dict[str, Any]) -> tuple[np.ndarray, ...]:
    """A run's `PRIMITIVES` along its motion: computed once by `_motion`, else from its states."""
    if "primitives" in m:
        return tuple(m["primitives"])
    return _primitives(m["phi"], m["dphi"], m["psi"], m["dpsi"], m["signals"])


def _feature_values(
    kind: TermKind, site: str, motion: list[dict[str, Any]], shape: tuple[Any, ...] = ()
) -> list[np.ndarray]:
    """The term's feature on each run along `motion` (a dynamics term: the states, the
    commanded drive, its rate and time; a drive or sensor term: the run's `TermSignals`).
    """
    term = DiscoveredTerm(kind.name, site, 1.0, shape)
    if site in DYNAMICS_SITES and not term.is_filtered:
        return [monomial(_primitives_of(m), term.monomial) for m in motion]
    return [term.feature(m["signals"]) for m in motion]  # a low-pass: of the signal it reads


def _feature_rms(kind: TermKind, site: str, motion: list[dict[str, Any]]) -> float:
    """RMS of the term's feature over the runs, along the current model's motion."""
    shape = tuple((s.key, s.grid[-1]) for s in kind.shape)
    f = _feature_values(kind, site, motion, shape)
    return math.sqrt(sum(float(np.dot(x, x)) for x in f) / max(sum(x.size for x in f), 1))


def _composed_rms(
    kind: TermKind, site: str, motion: list[dict[str, Any]], shape: tuple[Any, ...] = ()
) -> tuple[float, bool]:
    """A composed form's RMS over the runs along `motion` (at `shape`, a low-pass's corner), and
    whether it is degenerate there.
    """
    f = np.concatenate(_feature_values(kind, site, motion, shape))
    rms, std = float(np.sqrt(np.mean(f * f))), float(np.std(f))
    return rms, not (math.isfinite(rms) and rms > 0 and std > DEGENERATE_REL_STD * rms)


def is_degenerate(kind: TermKind, site: str, motion: list[dict[str, Any]]) -> bool:
    """The feature is zero, not finite or constant along `motion` (per run: phi, dphi, psi, dpsi
    in rad and rad/s; for a drive or sensor form, the run's `TermSignals` as ``signals``): it
    cannot be told from the constant or from nothing.
    """
    return _composed_rms(kind, site, motion)[1]


def _rank_composed(
    ctx: AnalysisContext,
    current: Model,
    site: str,
    problem: ResidualProblem,
    motion: list[dict[str, Any]],
) -> tuple[list[tuple[float, TermKind, float]], list[str]]:
    """Every composed form at `site` ranked by one linearized least-squares step, jointly with
    the plant parameters it is fitted along with (`fitted_along`: a form the plant can mimic
    closes little): [(rss after the step, kind, coefficient scale)] best first, and the
    degenerate forms.
    """
    share = _share_rms(site, ctx, current, motion)
    variants, scales, degenerate = [], [], []
    for kind in composed_kinds(site):
        kept = 0
        for shape in _shapes(kind):
            rms, degenerate_here = _composed_rms(kind, site, motion, shape)
            if not degenerate_here:
                variants.append((kind, shape))
                scales.append(share / rms)
                kept += 1
        if not kept:
            degenerate.append(kind.name)
    if not variants:
        return [], degenerate
    plant = fitted_along(site, current, problem.channel, ctx.settings.identify)
    plant = [p for p in plant if p.is_plant]
    x0 = np.array([[p.to_fit(spec_value(current, p)) for p in plant]])
    plant_probes = [
        models_for(current, plant, x0 + PLANT_STEP * np.eye(len(plant))[i])[0]
        for i in range(len(plant))
    ]
    base = problem.residuals([current, *plant_probes])
    r0 = np.concatenate(base[0])
    along = [np.concatenate(r) - r0 for r in base[1:]]
    best: dict[str, tuple[float, TermKind, float]] = {}
    r0_ss = float(np.dot(r0, r0))
    # the step's matrix [change, *along]: the plant's columns written once, each form's change
    # into the first column (the same matrix, not rebuilt per form)
    a = np.column_stack([r0, *along]) if along else None
    for (k, _shape), sc, change in _changes(site, problem, current, variants, scales, r0, motion):
        if a is not None:
            a[:, 0] = change
            step = np.linalg.lstsq(a, -r0, rcond=None)[0]
            left = r0 + a @ step
            rss = float(np.dot(left, left))
        else:  # one column: the least-squares step in closed form, on the unit column
            rss = one_column_rss(change, r0, r0_ss)
        if k.name not in best or rss < best[k.name][0]:  # a low-pass: its best corner
            best[k.name] = (rss, k, COEFFICIENT_RANGE * sc)
    return sorted(best.values(), key=lambda c: c[0]), degenerate


def one_column_rss(column: np.ndarray, r0: np.ndarray, r0_ss: float) -> float:
    """The rss `r0` leaves after one least-squares step along `column` (r0_ss where the column
    is zero or not finite). The column is scaled to its largest sample first: a form whose RMS
    is tiny has a huge probe scale, whose square would overflow.
    """
    size = float(np.max(np.abs(column)))
    if not (math.isfinite(size) and size > 0.0):
        return r0_ss
    unit = column / size
    return r0_ss - float(np.dot(unit, r0)) ** 2 / float(np.dot(unit, unit))


def _shapes(kind: TermKind) -> list[tuple[tuple[str, float], ...]]:
    """The shape values a composed form is ranked at: none, or each of its grid's corners."""
    return [((s.key, g),) for s in kind.shape for g in s.grid] or [()]


def _changes(
    site: str,
    problem: ResidualProblem,
    current: Model,
    variants: list[tuple[TermKind, tuple[tuple[str, float], ...]]],
    scales: list[float],
    r0: np.ndarray,
    motion: list[dict[str, Any]],
) -> Iterator[tuple[tuple[TermKind, tuple[tuple[str, float], ...]], float, np.ndarray]]:
    """((kind, shape), scale, the weighted residual's change) per composed form at
    `PROBE_FRACTION` of its scale: at a sensor site, where a term adds to the output after the
    chain, from its feature along `current` (exact: the output is linear in it); at a dynamics
    site from the plant's linearised response to its torque (`_linear_changes`); at the drive
    simulated, in batches.
    """
    if site in SENSOR_CHANNELS:
        signals = problem.term_signals(current)
        for (k, shape), sc in zip(variants, scales, strict=True):
            term = DiscoveredTerm(k.name, site, 1.0, shape)
            column = problem.output_columns({j: term.feature(s) for j, s in signals.items()})
            yield (k, shape), sc, PROBE_FRACTION * sc * column
        return
    if site in DYNAMICS_SITES:
        yield from _linear_changes(site, problem, current, variants, scales, motion)
        return
    for start in range(0, len(variants), RANK_BATCH):  # a batch's simulations held at once
        chunk = slice(start, start + RANK_BATCH)
        probes = [
            with_terms(current, [DiscoveredTerm(k.name, site, PROBE_FRACTION * sc, shape)])
            for (k, shape), sc in zip(variants[chunk], scales[chunk], strict=True)
        ]
        res = problem.residuals(probes)
        for v, sc, r in zip(variants[chunk], scales[chunk], res, strict=True):
            yield v, sc, np.concatenate(r) - r0


def _linear_changes(
    site: str,
    problem: ResidualProblem,
    current: Model,
    variants: list[tuple[TermKind, tuple[tuple[str, float], ...]]],
    scales: list[float],
    motion: list[dict[str, Any]],
) -> Iterator[tuple[tuple[TermKind, tuple[tuple[str, float], ...]], float, np.ndarray]]:
    """`_changes` at a dynamics site: each form's torque at `PROBE_FRACTION` of its scale along
    the current motion (at each sample period's midpoint; a low-pass form's filtered value
    likewise), through the plant linearised about that motion (`runs.torque_changes`).
    """
    equation = "stroke" if site == "stroke_dynamics" else "pitch"
    angle = "stroke" if problem.channel == "stroke_deg" else "pitch"
    for start in range(0, len(variants), LINEAR_BATCH):
        chunk = slice(start, start + LINEAR_BATCH)
        changes = {}
        for j in problem.run_ids:
            m = motion[j]
            forms = list(zip(variants[chunk], scales[chunk], strict=True))
            torque = np.empty((problem.runs[j].drive_v.size, len(forms)))  # a column per form
            for col, ((k, shape), sc) in enumerate(forms):
                term = DiscoveredTerm(k.name, site, PROBE_FRACTION * sc, shape)
                if term.is_filtered:
                    f = _midpoint(term.feature(m["signals"]))
                else:
                    f = monomial(m["midpoint"], term.monomial)
                torque[:, col] = term.coefficient * f
            changes[j] = torque_changes(current, problem.runs[j], equation, torque, angle)
        yield from zip(variants[chunk], scales[chunk], problem.angle_columns(changes), strict=True)


def _share_rms(
    site: str, ctx: AnalysisContext, model: Model, motion: list[dict[str, Any]]
) -> float:
    """Size of the signal the term adds to: spring torque, drive or sensor deviation (RMS)."""

    def rms(key: str) -> float:
        x = np.concatenate([m[key] for m in motion])
        return float(np.sqrt(np.mean(x * x)))

    if site == "stroke_dynamics":
        return model.plant.stroke_stiffness_nm_per_rad * rms("phi")
    if site == "pitch_dynamics":
        return model.plant.hinge_stiffness_nm_per_rad * rms("psi")
    if site == "drive":
        d = np.concatenate([r.drive_v for r in ctx.runs])
        return float(np.sqrt(np.mean(d * d)))
    x = np.concatenate([getattr(m["signals"], site) for m in motion])
    return float(np.sqrt(np.mean(x * x)))


def _sensor_effect_specs(site: str, model: Model) -> list[EffectSpec]:
    """The parameters of the vocabulary effects already on sensor chain `site` (a term there
    trades off against them: a delay fitted without a leak has bent to mimic part of it).
    """
    side = SENSOR_SIDE[site]
    specs = []
    for group in candidate_groups(site):
        if model.effect_on(group[0].name, side) is not None and group[0].channel_param in (
            None,
            side,
        ):
            specs += [replace(s, tested=False) for s in group]
    return specs


def fitted_along(
    site: str,
    model: Model,
    channel: str,
    identify: bool,
    centre: Mapping[str, float] | None = None,
) -> list[EffectSpec]:
    """What a term at `site` is fitted jointly with: the plant parameters of its equation (a
    drive term: the stroke's), or the sensor chain's vocabulary effects.

    centre: {plant key: value} the plant identification's box is centred on; given, each plant
    parameter is fitted in that very box (x(1 -+ FIT_RANGE) in log, `identification`), the
    freedom the plant had without the term; else within x(1 -+ 0.5) of its value in `model`.
    """
    if site in SENSOR_CHANNELS:
        return _sensor_effect_specs(site, model)
    if not identify or site not in ("stroke_dynamics", "pitch_dynamics", "drive"):
        return []
    truth = "pitch_deg" if site == "pitch_dynamics" else "stroke_deg"
    keys = [k for k, c in PLANT_PARAMETERS.items() if c == truth]
    if centre is None:
        return [plant_spec(k, model, channel) for k in keys]
    return [plant_box_spec(k, model, channel, float(centre[k])) for k in keys]


def plant_box_spec(key: str, model: Model, channel: str, centre: float) -> EffectSpec:
    """Plant parameter `key` as a fittable spec starting at its value in `model`, bounded by the
    identification's box about `centre`: [centre / (1 + FIT_RANGE), centre * (1 + FIT_RANGE)].
    """
    box = 1.0 + FIT_RANGE
    return replace(plant_spec(key, model, channel), lower=centre / box, upper=centre * box)


def _fit_alone(
    ctx: AnalysisContext,
    current: Model,
    kind: TermKind,
    site: str,
    channel: str,
    scale: float,
    problem: ResidualProblem,
) -> list[tuple[Any, ...]]:
    """The term alone on the current plant, from each start of its shape grid: a quick ranking."""
    out = []
    for start in [{s.key: g} for s in kind.shape for g in s.grid] or [{}]:
        specs = term_specs(kind, site, channel, scale, start)
        x0 = np.array([s.to_fit(s.null) for s in specs])
        try:
            fit = fit_specs(
                current, specs, problem, x0, ctx.settings, step_scale=ctx.settings.discovery_fd_step
            )
        except (ModelError, ValueError):  # a start that leaves the term's own range
            continue
        out.append((fit.rss, kind, site, specs, fit.x))
    return out


def candidates(ctx: AnalysisContext, current: Model, channel: str, truth_ref: bool) -> Candidates:
    """Every library term that may close `channel`'s gap, and the best composed forms (see the
    module docstring), each fitted alone: best fit first.
    """
    motion = _motion(ctx, current)
    problem = ctx.problem(channel, ctx.folds, truth_ref, current)
    out = []
    ranked_all: list[tuple[str, str, float]] = []
    degenerate: list[tuple[str, str]] = []
    n_dynamics = sum(t.is_dynamics for t in current.discovered)
    placed = {(t.kind, t.acts_on) for t in current.discovered}
    rank_s = 0.0
    for site in SITES_FOR_GAP[channel]:
        if site in DYNAMICS_SITES and n_dynamics >= MAX_DYNAMICS_TERMS:
            continue
        for kind in kinds_for(site):
            if (kind.name, site) in placed:
                continue
            rms = _feature_rms(kind, site, motion)
            if not (math.isfinite(rms) and rms > 0):
                continue
            scale = COEFFICIENT_RANGE * _share_rms(site, ctx, current, motion) / rms
            out += _fit_alone(ctx, current, kind, site, channel, scale, problem)
        started = time.perf_counter()
        ranked, skipped = _rank_composed(ctx, current, site, problem, motion)
        rank_s += time.perf_counter() - started
        degenerate += [(name, site) for name in skipped]
        ranked = [c for c in ranked if (c[1].name, site) not in placed]
        ranked_all += [(k.name, site, rss) for rss, k, _sc in ranked]
        for _rss, kind, scale in ranked[: ctx.settings.discovery_composed_fits]:
            out += _fit_alone(ctx, current, kind, site, channel, scale, problem)
    out.sort(key=lambda c: c[0])
    best: dict[tuple[str, str], tuple[Any, ...]] = {}
    for c in out:  # one entry per term (its best shape start)
        best.setdefault((c[1].name, c[2]), c)
    return Candidates(list(best.values()), tuple(ranked_all), tuple(degenerate), rank_s)
