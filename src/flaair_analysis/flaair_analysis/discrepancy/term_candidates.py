"""The discovery step's candidates: every library term that may close a channel's gap, each
fitted alone on the current plant for a first ranking (`candidates`), and what a term is fitted
jointly with (`fitted_along`: its equation's plant parameters, or the sensor chain's effects).

The coefficient's search range is `COEFFICIENT_RANGE` times the size of the signal the term adds
to (spring torque, drive or sensor deviation) over the RMS of its feature along the current
model's motion. `discovery` judges the shortlist.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from flaair_model.model import Model, ModelError
from flaair_model.terms import (
    DYNAMICS_SITES,
    MAX_DYNAMICS_TERMS,
    DiscoveredTerm,
    TermKind,
    TermSignals,
    kinds_for,
)

from .evidence import AnalysisContext
from .fitting import fit_specs
from .runs import simulate_runs
from .vocabulary import (
    PLANT_PARAMETERS,
    SENSOR_CHANNELS,
    SENSOR_SIDE,
    EffectSpec,
    candidate_groups,
    plant_spec,
    term_specs,
)

__all__ = ["COEFFICIENT_RANGE", "SITES_FOR_GAP", "candidates", "fitted_along"]

SITES_FOR_GAP: dict[str, tuple[str, ...]] = {
    "stroke_deg": ("stroke_dynamics", "drive"),
    "pitch_deg": ("pitch_dynamics",),
    "stroke_sensor_v": ("stroke_sensor_v",),
    "pitch_sensor_v": ("pitch_sensor_v",),
}
# A coefficient may reach this many times the size of its feature's whole share of the channel.
COEFFICIENT_RANGE = 3.0


def _motion(ctx: AnalysisContext, model: Model) -> list[dict[str, np.ndarray]]:
    """Simulated channels per run, with the velocities (rad/s) and the sensor deviations."""
    sims = simulate_runs([model], ctx.runs)[0]
    vref = model.sensors.reference_voltage_v
    out = []
    for run, sim in zip(ctx.runs, sims, strict=True):
        phi, psi = np.radians(sim["stroke_deg"]), np.radians(sim["pitch_deg"])
        out.append(
            {
                "phi": phi,
                "dphi": np.gradient(phi) * run.fs_hz,
                "psi": psi,
                "dpsi": np.gradient(psi) * run.fs_hz,
                "stroke_sensor_v": sim["stroke_sensor_v"] - vref,
                "pitch_sensor_v": sim["pitch_sensor_v"] - vref,
            }
        )
    return out


def _feature_rms(
    kind: TermKind, site: str, ctx: AnalysisContext, motion: list[dict[str, Any]]
) -> float:
    """RMS of the term's feature over the runs, along the current model's motion."""
    total, count = 0.0, 0
    shape = tuple((s.key, s.grid[-1]) for s in kind.shape)
    term = DiscoveredTerm(kind.name, site, 1.0, shape)
    for run, m in zip(ctx.runs, motion, strict=True):
        if site in DYNAMICS_SITES:
            f = term.monomial_value(m["phi"], m["dphi"], m["psi"], m["dpsi"])
        else:
            f = term.feature(
                TermSignals.of_block(
                    run.fs_hz,
                    run.drive_v,
                    phi=m["phi"],
                    psi=m["psi"],
                    stroke_sensor_v=m["stroke_sensor_v"],
                    pitch_sensor_v=m["pitch_sensor_v"],
                )
            )
        total += float(np.dot(f, f))
        count += f.size
    return math.sqrt(total / max(count, 1))


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
    return rms(site)


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


def fitted_along(site: str, model: Model, channel: str, identify: bool) -> list[EffectSpec]:
    """What a term at `site` is fitted jointly with: the plant parameters of its equation (a
    drive term: the stroke's), or the sensor chain's vocabulary effects.
    """
    if site in SENSOR_CHANNELS:
        return _sensor_effect_specs(site, model)
    if not identify or site not in ("stroke_dynamics", "pitch_dynamics", "drive"):
        return []
    truth = "pitch_deg" if site == "pitch_dynamics" else "stroke_deg"
    return [plant_spec(k, model, channel) for k, c in PLANT_PARAMETERS.items() if c == truth]


def candidates(
    ctx: AnalysisContext, current: Model, channel: str, truth_ref: bool
) -> list[tuple[Any, ...]]:
    """(rss, kind, site, specs, x) of every library term that may close `channel`'s gap."""
    motion = _motion(ctx, current)
    problem = ctx.problem(channel, ctx.folds, truth_ref, current)
    out = []
    n_dynamics = sum(t.is_dynamics for t in current.discovered)
    placed = {(t.kind, t.acts_on) for t in current.discovered}
    for site in SITES_FOR_GAP[channel]:
        for kind in kinds_for(site):
            if (kind.name, site) in placed or (
                site in DYNAMICS_SITES and n_dynamics >= MAX_DYNAMICS_TERMS
            ):
                continue
            rms = _feature_rms(kind, site, ctx, motion)
            if not (math.isfinite(rms) and rms > 0):
                continue
            scale = COEFFICIENT_RANGE * _share_rms(site, ctx, current, motion) / rms
            starts = [{s.key: g} for s in kind.shape for g in s.grid] or [{}]
            for start in starts:  # the term alone on the current plant: a quick ranking
                specs = term_specs(kind, site, channel, scale, start)
                x0 = np.array([s.to_fit(s.null) for s in specs])
                try:
                    fit = fit_specs(current, specs, problem, x0, ctx.settings)
                except (ModelError, ValueError):  # a start that leaves the term's own range
                    continue
                out.append((fit.rss, kind, site, specs, fit.x))
    out.sort(key=lambda c: c[0])
    best: dict[tuple[str, str], tuple[Any, ...]] = {}
    for c in out:  # one entry per term (its best shape start)
        best.setdefault((c[1].name, c[2]), c)
    return list(best.values())
