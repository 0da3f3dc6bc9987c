"""The discrepancy workflow on a table: plant first, then what a table can show, judged on held-out
drive levels. Pure (numpy, scipy, the plant core through `steady_state`).

1. The plant is fitted on every level (`fit.identify_table`); the gap of each response column is
   measured on held-out levels: each level predicted by the plant fitted on the other levels.
2. Candidates a table can show: the vocabulary effects that act on the wing's motion (searched on
   a truth channel and separable from the plant), then the library's terms on the stroke and
   pitch dynamics and on the drive (no shape parameter, not a vocabulary effect under another
   name). Effects that act on sensor signals are not searched: a table has no sensor voltage
   and no time axis.
3. Per side (stroke, then pitch) with a gap: every candidate is fitted alone on the fitted plant
   (a grid start, one batch), the best `shortlist` jointly with the plant parameters they trade
   off against, and judged on held-out levels. One is kept when the side's held-out error above
   noise drops by more than `min_heldout_drop` and its parameter is `min_z` standard errors from
   doing nothing (the rules every kind of evidence is judged by, `evidence.judging`); the lowest
   held-out error wins. Vocabulary effects are judged first; the terms are judged too where no
   effect passes or where the best effect that passes still leaves the side a held-out gap (a
   column above `gap_ratio` x noise), and then every candidate that passes competes (a
   structural damping takes most of a dry friction's gap, not all of it).
Statuses: `no_discrepancy` (the fitted plant predicts held-out levels to the reading noise),
`explained`, `unexplained`. A one-level table is fitted, not searched (nothing to hold out).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from flaair_analysis.discrepancy.vocabulary import TERM_PREFIX, EffectSpec, param_spec
from flaair_analysis.evidence import (
    distance_from_null,
    drop_failure,
    excess_above_noise,
    gap_drop,
    passes_drop,
    passes_z,
    z_failure,
)
from flaair_model.effects import EFFECTS
from flaair_model.model import Model
from flaair_model.settings import TableSettings
from flaair_model.terms import MAX_DYNAMICS_TERMS, TERM_KINDS, DiscoveredTerm, TermSignals

from .fit import (
    PITCH_KEYS,
    STROKE_KEYS,
    FreeParam,
    TableFit,
    fit_table,
    identify_table,
    plant_params,
    with_values,
)
from .joint import JointFit, table_identification
from .reader import Table
from .steady_state import steady_response
from .table_evidence import TableEvidence, normalised_residuals, stack_cells

__all__ = [
    "NOT_SEARCHED",
    "Candidate",
    "Judged",
    "TableDiscrepancy",
    "analyse_table",
    "candidates",
    "heldout_predictions",
]

_TRUTH = ("stroke_deg", "pitch_deg")
_TERM_SITES = ("stroke_dynamics", "drive", "pitch_dynamics")
_SKIPPED_KINDS = {"constant": "a constant torque moves the mean, not the amplitude"}
NOT_SEARCHED: dict[str, str] = {
    e.name: (
        "acts on the sensor signal, not on the wing's motion: a table read from video has no "
        "sensor voltage and no time axis"
        if not set(e.searched_on) & set(_TRUTH)
        else f"not separable from the plant: {e.note}"
    )
    for e in EFFECTS
    if not (set(e.searched_on) & set(_TRUTH)) or not e.separable
}


@dataclass(frozen=True)
class Candidate:
    """An effect or a term as the table search fits it."""

    name: str  # effect name, or `kind@site` of a term
    is_term: bool
    side: str  # "stroke" or "pitch": the columns it is judged on
    params: tuple[FreeParam, ...]
    null: tuple[float, ...]
    grid: tuple[float, ...]  # starts of the first parameter
    trades_off: tuple[str, ...]


@dataclass
class Judged:
    """A candidate's outcome: its fit on every level, its held-out error and the rules."""

    candidate: Candidate
    fit: TableFit
    heldout_error: float
    drop: float
    z: float
    failed: list[str] = field(default_factory=list)
    heldout_ratio: dict[str, float | None] = field(default_factory=dict)  # column -> noise ratio


@dataclass
class TableDiscrepancy:
    """What `analyse_table` found (documents in `report`)."""

    status: str
    model_in: Model
    identified: Model
    model_out: Model
    identification: JointFit
    accepted: list[Judged]
    tried: list[Judged]
    gaps: dict[str, dict[str, float | None]]  # stage -> column -> NRMSE on held-out levels
    noise_ratio: dict[str, dict[str, float | None]]  # stage -> column -> RMS(residual / noise)
    predictions: dict[str, dict[str, np.ndarray]]  # stage -> column -> (P,) held-out prediction
    notes: list[str]
    searched: bool


def _side_cols(table: Table, side: str) -> list[str]:
    return [c for c in table.responses if c.startswith(side)]


def _term_scale(term: DiscoveredTerm, model: Model, table: Table) -> float:
    """The coefficient giving the term the size of the side's spring torque (or of the drive)."""
    pl = model.plant
    fn = pl.stroke_natural_frequency_hz
    w = 2.0 * math.pi * fn
    amp = np.nanmax(table.responses.get("stroke_pp_deg", np.array([60.0]))) / 2.0
    phi, psi = math.radians(amp), math.radians(40.0)
    vmax = float(np.max(table.drive_amplitude_v))
    if term.is_dynamics:
        x = np.array([phi]), np.array([w * phi]), np.array([psi]), np.array([w * psi])
        feature = abs(float(term.monomial_value(*x, vmax)[0]))
        if term.acts_on == "stroke_dynamics":
            torque = pl.stroke_stiffness_nm_per_rad * phi
        else:
            torque = pl.hinge_stiffness_nm_per_rad * psi
        return torque / max(feature, 1e-300)
    t = np.arange(400) / (400 * fn)
    v = vmax * np.sin(w * t)
    sig = TermSignals(400 * fn, v, vmax * w * np.cos(w * t), t)
    return vmax / max(float(np.max(np.abs(term.feature(sig)))), 1e-300)


def candidates(table: Table, model: Model) -> list[Candidate]:
    """The vocabulary effects and library terms a table can show, for the sides it measures."""
    sides = [s for s in ("stroke", "pitch") if _side_cols(table, s)]
    out = []
    for e in EFFECTS:
        if e.name in NOT_SEARCHED or model.effect(e.name) is not None:
            continue
        side = "stroke" if "stroke_deg" in e.searched_on else "pitch"
        if side not in sides:
            continue
        fps = e.fit[:2]  # collision: limit and contact stiffness (its damping stays)
        channel = f"{side}_deg"
        params = tuple(
            FreeParam(param_spec(e.name, p, channel, i == 0), p.grid[0] if p.grid else p.null)
            for i, p in enumerate(fps)
        )
        out.append(
            Candidate(
                e.name,
                False,
                side,
                params,
                tuple(p.null for p in fps),
                tuple(fps[0].grid),
                tuple(e.trades_off),
            )
        )
    present = {(t.kind, t.acts_on) for t in model.discovered}
    full = sum(t.is_dynamics for t in model.discovered) >= MAX_DYNAMICS_TERMS  # kernel slots
    for row in TERM_KINDS:
        for site in _TERM_SITES:
            if (row.name, site) in present or (full and site != "drive"):
                continue
            side = "pitch" if site == "pitch_dynamics" else "stroke"
            if (
                site not in row.sites
                or row.shape
                or "t" in row.form.replace("*", " ").split()
                or row.name in _SKIPPED_KINDS
                or site in row.same_as
                or side not in sides
            ):
                continue
            scale = _term_scale(DiscoveredTerm(row.name, site, 1.0), model, table)
            spec = EffectSpec(
                f"{TERM_PREFIX}{row.name}@{site}", "coefficient", f"{side}_deg", 0.0,
                -3.0 * scale, 3.0 * scale, (), 1e-3 * scale,
            )  # fmt: skip
            trades = STROKE_KEYS if side == "stroke" else PITCH_KEYS
            out.append(
                Candidate(
                    f"{row.name}@{site}",
                    True,
                    side,
                    (FreeParam(spec, 0.0),),
                    (0.0,),
                    tuple(scale * g for g in (-1.0, -0.3, -0.1, 0.1, 0.3, 1.0)),
                    trades,
                )
            )
    return out


def _predict(table: Table, model: Model, s: TableSettings) -> dict[str, np.ndarray]:
    r = steady_response([model], table.frequency_hz, table.drive_amplitude_v, table.drive_bias_v, s)
    return {c: r[c][0] for c in table.responses}


def heldout_predictions(
    table: Table,
    model: Model,
    params: Sequence[FreeParam],
    s: TableSettings,
    columns: Sequence[str],
) -> dict[str, np.ndarray]:
    """Each level predicted by `params` fitted (from `model`) on the other levels."""
    out = {c: np.full(table.n_points, np.nan) for c in table.responses}
    for _, rest, level, held in TableEvidence(table, s, columns).level_splits():
        fit = fit_table(rest.table, model, params, s, columns)
        pred = _predict(level.table, fit.model, s)
        for c in out:
            out[c][held] = pred[c]
    return out


def _at(params: Sequence[FreeParam], model_values: dict[str, float], r: float) -> list[FreeParam]:
    """`params` restarted at the values of a fit (plant ones within x/÷ r)."""
    out = []
    for p in params:
        v = model_values.get(p.key, p.start)
        if p.spec.is_plant:
            out.append(p.bounded(v, v / r, v * r))
        else:
            out.append(replace(p, start=v))
    return out


def _scores(
    table: Table, pred: dict[str, np.ndarray], s: TableSettings
) -> tuple[dict[str, float | None], dict[str, float | None]]:
    """Per column: NRMSE and RMS of the noise-weighted residuals, over the measured cells."""
    res = normalised_residuals(table, {c: v[None, :] for c, v in pred.items()}, s, list(pred))
    nrmse, ratio = {}, {}
    for c, r in res.items():
        ok = np.isfinite(r[0])
        meas = table.responses[c][ok]
        diff = (pred[c][ok] - meas + 180.0) % 360.0 - 180.0 if "phase" in c else pred[c][ok] - meas
        nrmse[c] = (
            float(np.sqrt(np.mean(diff**2)) / np.sqrt(np.mean(meas**2))) if ok.any() else None
        )
        ratio[c] = float(np.sqrt(np.mean(r[0][ok] ** 2))) if ok.any() else None
    return nrmse, ratio


def _excess(ratio: dict[str, float | None], cols: Sequence[str]) -> float:
    """The side's error above noise (`evidence.excess_above_noise` of its columns)."""
    return excess_above_noise(v * v for c in cols if (v := ratio.get(c)) is not None)


def _grid_best(
    table: Table, model: Model, cand: Candidate, s: TableSettings, cols: Sequence[str]
) -> FreeParam:
    """The candidate's first parameter started at the best of its grid (one batch)."""
    starts = [replace(cand.params[0], start=g) for g in cand.grid] or [cand.params[0]]
    models = [
        with_values(model, params, {p.key: p.start for p in params})
        for params in ((p0, *cand.params[1:]) for p0 in starts)
    ]
    resp = steady_response(
        models, table.frequency_hz, table.drive_amplitude_v, table.drive_bias_v, s
    )
    cost = (stack_cells(table, normalised_residuals(table, resp, s, cols)) ** 2).sum(axis=1)
    return starts[int(np.argmin(cost))]


def _rank(table: Table, model: Model, cand: Candidate, s: TableSettings) -> tuple[float, Candidate]:
    """The side's cost with the candidate fitted alone on the fitted plant (grid start), and the
    candidate started where that fit ended.
    """
    cols = _side_cols(table, cand.side)
    first = _grid_best(table, model, cand, s, cols)
    params = (first, *cand.params[1:])
    try:
        fit = fit_table(table, model, params, replace(s, max_nfev=s.heldout_max_nfev), cols)
    except (ValueError, np.linalg.LinAlgError):  # the candidate drives the model unstable
        return math.inf, cand
    moved = tuple(replace(p, start=fit.values[p.key]) for p in params)
    return fit.chi2, replace(cand, params=moved)


def _judge(table: Table, model: Model, cand: Candidate, s: TableSettings, before: float) -> Judged:
    cols = _side_cols(table, cand.side)
    params = [*cand.params, *plant_params(model, cand.trades_off, {}, 1.5)]
    fit = fit_table(table, model, params, s, cols)
    # fitted without the effect, the plant may have run far to mimic it (a hinge stiffening's
    # pitch fit at 1.9 x the robot's pitch frequency, the couplings at 4 x): a plant parameter
    # ending on the narrow box's edge is freed over the fit's whole range, from where it ended
    # (a wide box from the start sends a collision's joint fit to another minimum)
    if any(
        p.spec.is_plant and not (p.lower * 1.01 < fit.values[p.key] < p.upper / 1.01)
        for p in params
    ):
        wide = [
            replace(p, start=fit.values[p.key])
            for p in [*cand.params, *plant_params(model, cand.trades_off, {}, s.fit_range)]
        ]
        refit = fit_table(table, model, wide, s, cols)
        if refit.chi2 < fit.chi2:
            params, fit = wide, refit
    quick = replace(s, max_nfev=s.heldout_max_nfev)
    held = heldout_predictions(table, model, _at(params, fit.values, 1.5), quick, cols)
    _, ratio = _scores(table, held, s)
    err = _excess(ratio, cols)
    drop = gap_drop(before, err)
    key = cand.params[0].key
    v, se, null = fit.values[key], fit.stderr[key], cand.null[0]
    reach = math.inf
    if math.isinf(null):  # a stop: its limit must lie below the stroke the model reaches
        reach = 90.0
        if "stroke_pp_deg" in table.responses:
            reach = float(np.nanmax(_predict(table, fit.model, s)["stroke_pp_deg"])) / 2.0
    z = distance_from_null(v, se, null, reach)
    failed = []
    if not passes_drop(drop, s.rules):
        failed.append(drop_failure(drop, s.rules))
    if not passes_z(z, s.rules):
        failed.append(z_failure(z, s.rules))
    return Judged(cand, fit, err, drop, z, failed, {c: ratio.get(c) for c in cols})


def analyse_table(table: Table, model: Model, s: TableSettings) -> TableDiscrepancy:
    """Fit the plant, search what a table can show, judge on held-out levels (module docstring)."""
    before_pred = _predict(table, model, s)
    identified, fits, start, notes = identify_table(table, model, s)
    ident = table_identification(table, model, s, identified, fits, start, notes)
    gaps: dict[str, dict[str, float | None]] = {}
    ratios: dict[str, dict[str, float | None]] = {}
    preds: dict[str, dict[str, np.ndarray]] = {"before": before_pred}
    gaps["gap_before"], ratios["gap_before"] = _scores(table, before_pred, s)
    if table.levels_v.size < 2:
        notes.append(
            "one drive level: no level could be held out; the plant is fitted and judged in "
            "sample, and the effects search did not run (it needs two or more levels)"
        )
        fit_pred = _predict(table, identified, s)
        _, in_sample = _scores(table, fit_pred, s)
        status = (
            "no_discrepancy"
            if all(v is None or v <= s.gap_ratio for v in in_sample.values())
            else "unexplained"
        )
        preds["identified"] = preds["final"] = fit_pred
        none = {c: None for c in table.responses}
        gaps["gap_identified"] = gaps["gap_after"] = dict(none)
        ratios["gap_identified"] = ratios["gap_after"] = dict(none)
        return TableDiscrepancy(
            status, model, identified, identified, ident, [], [], gaps, ratios, preds, notes, False
        )
    plant_free = [
        *plant_params(identified, STROKE_KEYS if _side_cols(table, "stroke") else (), {}, 1.5),
        *plant_params(identified, PITCH_KEYS if _side_cols(table, "pitch") else (), {}, 1.5),
    ]
    quick = replace(s, max_nfev=s.heldout_max_nfev)
    held = heldout_predictions(table, identified, plant_free, quick, list(table.responses))
    preds["identified"] = held
    gaps["gap_identified"], ratios["gap_identified"] = _scores(table, held, s)
    current, current_ratio, current_pred = identified, ratios["gap_identified"], held
    accepted: list[Judged] = []
    tried: list[Judged] = []
    for side in ("stroke", "pitch"):
        cols = _side_cols(table, side)
        for _ in range(s.max_effects_per_side):
            if not cols or all((current_ratio[c] or 0.0) <= s.gap_ratio for c in cols):
                break
            before = _excess(current_ratio, cols)
            pool = [c for c in candidates(table, current) if c.side == side]
            passed: list[Judged] = []
            for group in (False, True):  # vocabulary effects first, then terms
                if passed and not _leaves_gap(min(passed, key=_error), s):
                    break
                ranked = sorted(
                    (_rank(table, current, c, s) for c in pool if c.is_term == group),
                    key=lambda rc: rc[0],
                )
                judged = [
                    _judge(table, current, c, s, before)
                    for cost, c in ranked[: s.shortlist]
                    if math.isfinite(cost)
                ]
                tried.extend(judged)
                passed += [j for j in judged if not j.failed]
            if not passed:
                break
            best = min(passed, key=_error)
            accepted.append(best)
            current = best.fit.model
            if side == "stroke" and _side_cols(table, "pitch"):
                current = fit_table(
                    table,
                    current,
                    plant_params(current, PITCH_KEYS, {}, 1.5),
                    s,
                    _side_cols(table, "pitch"),
                ).model
            free = plant_free + [p for j in accepted for p in j.candidate.params]
            current_pred = heldout_predictions(
                table,
                current,
                _at(free, _values_of(current, accepted), 1.5),
                s,
                list(table.responses),
            )
            _, current_ratio = _scores(table, current_pred, s)
    preds["final"] = current_pred
    gaps["gap_after"], ratios["gap_after"] = _scores(table, current_pred, s)

    def has_gap(r: dict[str, float | None]) -> bool:
        return any((v or 0.0) > s.gap_ratio for v in r.values())

    if not has_gap(ratios["gap_identified"]):
        status = "no_discrepancy"
    elif accepted and not has_gap(ratios["gap_after"]):
        status = "explained"
    else:
        status = "unexplained"
    return TableDiscrepancy(
        status, model, identified, current, ident, accepted, tried, gaps, ratios, preds, notes, True
    )


def _error(j: Judged) -> float:
    return j.heldout_error


def _leaves_gap(j: Judged, s: TableSettings) -> bool:
    """Whether the side keeps a gap on held-out levels with the candidate in the model."""
    return any((v or 0.0) > s.gap_ratio for v in j.heldout_ratio.values())


def _values_of(model: Model, accepted: Sequence[Judged]) -> dict[str, float]:
    out: dict[str, float] = {
        f"plant.{k}": getattr(model.plant, k) for k in STROKE_KEYS + PITCH_KEYS
    }
    for j in accepted:
        for p in j.candidate.params:
            out[p.key] = j.fit.values[p.key]
    return out
