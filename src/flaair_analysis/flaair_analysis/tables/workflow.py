"""The discrepancy workflow on a table: plant first, then what a table can show, judged on held-out
drive levels. Pure (numpy, scipy, the plant core through `steady_state`).

1. The plant is fitted on every level (`fit.identify_table`); the gap of each response column is
   measured on held-out levels: each level predicted by the plant fitted on the other levels.
2. Candidates a table can show: the vocabulary effects that act on the wing's motion (searched on
   a truth channel and separable from the plant), then the library's terms on the stroke and
   pitch dynamics and on the drive (no shape parameter, not a vocabulary effect under another
   name). Effects that act on sensor signals are not searched: a table has no sensor voltage
   and no time axis.
3. The search over evidence (`discrepancy.evidence_search.search_sides`), the table's columns of
   each side its evidence and its drive levels the held-out splits.
   Per side (stroke, then pitch) with a gap: every candidate is fitted alone on the fitted plant
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from flaair_analysis.discrepancy.evidence_search import (
    Candidate,
    FreeParam,
    HeldOut,
    Judged,
    SearchOutcome,
    Side,
    heldout,
    plant_params,
    search_sides,
)
from flaair_analysis.discrepancy.vocabulary import TERM_PREFIX, EffectSpec, param_spec
from flaair_model.effects import EFFECTS
from flaair_model.model import Model
from flaair_model.settings import TableSettings
from flaair_model.terms import MAX_DYNAMICS_TERMS, TERM_KINDS, DiscoveredTerm, TermSignals

from .fit import PITCH_KEYS, STROKE_KEYS, identify_table
from .joint import JointFit, table_identification
from .reader import Table
from .steady_state import steady_response
from .table_evidence import TableEvidence, normalised_residuals

__all__ = [
    "NOT_SEARCHED",
    "TableDiscrepancy",
    "analyse_table",
    "candidates",
    "heldout_predictions",
    "search_table",
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
    pieces = [TableEvidence(table, s, columns)]
    return _predictions(table, heldout(pieces, model, params, s.max_nfev), s)


def _predictions(table: Table, held: HeldOut, s: TableSettings) -> dict[str, np.ndarray]:
    """Every column at each held-out level, predicted by the model fitted on the others."""
    out = {c: np.full(table.n_points, np.nan) for c in table.responses}
    for split, fit in held.fits:
        pred = _predict(table.subset(split.where), fit.model, s)
        for c in out:
            out[c][split.where] = pred[c]
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


_Scores = dict[str, dict[str, float | None]]  # stage -> column -> value


def _one_level(
    table: Table, model: Model, identified: Model, ident: JointFit, s: TableSettings,
    gaps: _Scores, ratios: _Scores, preds: dict[str, dict[str, np.ndarray]], notes: list[str],
) -> TableDiscrepancy:  # fmt: skip
    """A one-level table: fitted and judged in sample, not searched."""
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


def _reach_deg(table: Table, s: TableSettings) -> Callable[[Model], float]:
    """The largest stroke amplitude a model reaches on the table (90 deg without a stroke
    column): how far a stop's limit may lie.
    """

    def reach(model: Model) -> float:
        if "stroke_pp_deg" not in table.responses:
            return 90.0
        return float(np.nanmax(_predict(table, model, s)["stroke_pp_deg"])) / 2.0

    return reach


def search_table(table: Table, model: Model, s: TableSettings) -> tuple[HeldOut, SearchOutcome]:
    """The search over the table's evidence (`evidence_search.search_sides`) from `model`'s plant
    as it is: `model` judged on held-out levels (each predicted by its plant refitted on the
    others), and what the search found. Needs two or more drive levels.
    """
    stroke, pitch = _side_cols(table, "stroke"), _side_cols(table, "pitch")
    plant_free = [
        *plant_params(model, STROKE_KEYS if stroke else (), {}, 1.5),
        *plant_params(model, PITCH_KEYS if pitch else (), {}, 1.5),
    ]
    whole = [TableEvidence(table, s, list(table.responses))]
    held = heldout(whole, model, plant_free, s.heldout_max_nfev)
    sides = [
        Side(name, (TableEvidence(table, s, cols),) if cols else (), keys)
        for name, cols, keys in (("stroke", stroke, STROKE_KEYS), ("pitch", pitch, PITCH_KEYS))
    ]
    found = search_sides(
        sides,
        whole,
        model,
        plant_free,
        held,
        lambda m, side: [c for c in candidates(table, m) if c.side == side],
        s,
        _reach_deg(table, s),
    )
    return held, found


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
        return _one_level(table, model, identified, ident, s, gaps, ratios, preds, notes)
    held, found = search_table(table, identified, s)
    preds["identified"] = _predictions(table, held, s)
    gaps["gap_identified"], ratios["gap_identified"] = _scores(table, preds["identified"], s)
    preds["final"] = _predictions(table, found.final, s)
    gaps["gap_after"], ratios["gap_after"] = _scores(table, preds["final"], s)

    def has_gap(r: dict[str, float | None]) -> bool:
        return any((v or 0.0) > s.gap_ratio for v in r.values())

    accepted, tried = list(found.accepted), list(found.tried)
    if not has_gap(ratios["gap_identified"]):
        status = "no_discrepancy"
    elif accepted and not has_gap(ratios["gap_after"]):
        status = "explained"
    else:
        status = "unexplained"
    return TableDiscrepancy(
        status, model, identified, found.model, ident, accepted, tried, gaps, ratios, preds, notes,
        True,
    )  # fmt: skip
