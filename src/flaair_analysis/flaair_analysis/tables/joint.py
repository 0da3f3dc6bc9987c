"""The plant fitted to any of runs, a table and a multisine set's line spectra of the same
robot at once (docs/TABLES.md, docs/MULTISINE.md). Pure.

One least-squares fit of the plant parameters over every set (`evidence.fit_evidence`): the
runs' residuals (the ground-truth angle minus its simulation, demeaned per run, decimated,
divided by the channel's noise RMS: as `identify` on runs), the table's (each measured cell
against the steady state, divided by its reading noise: as `identify TABLE.csv`) and the
spectra's (each line of the band against the model simulated on the logged drive, divided by
the periods' noise) stacked in one residual vector. Stages as each fit does: the stroke
parameters on stroke_deg, the table's stroke columns and the stroke video's spectrum, then the
pitch parameters on pitch_deg, the pitch columns and the pitch video's spectrum. Each run's
initial state (angle, rate) is fitted along with the plant on the runs alone (a table has no
time axis; the spectra drop the transient periods).

Weighting: the sum of the sets' chi-squares (maximum likelihood when each set's noise model is
right): a run sample and a table cell each count by their information, so the runs' thousands of
samples do not outvote the table where they say nothing (short or quiet runs leave the
resonance to the table), and the table's sixty cells decide there. A set whose residuals after
that fit are above its noise (chi-square per residual r > 1: a noise model too optimistic, or
physics the model misses) would outvote the other by its sample count alone, so each set's
block is then divided by sqrt(max(1, r)) (the Birge ratio: the set's noise taken as its actual
scatter) and the stage refitted once from there.

Agreement: after the fit, each set's residual RMS over its noise (`noise_ratio`) per channel or
column (the spectra's on the video channels it is fitted on). Above `gap_ratio` (the tables'
setting, 1.5) is a gap: with the table alone at noise it
is the two sets disagreeing (different robots, or a table read under other conditions), and a
warning names each set's gap and the stroke frequency each set alone points to.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from flaair_analysis.discrepancy.evidence_search import ParamFit, plant_params
from flaair_analysis.discrepancy.identification import (
    DECIMATE,
    Stage,
    fit_stages,
    frequency_domain_start,
    identify_plant,
    inseparable_notes,
)
from flaair_analysis.discrepancy.run_evidence import RunEvidence
from flaair_analysis.discrepancy.runs import Run
from flaair_analysis.evidence import Evidence, EvidenceFit, EvidenceSet
from flaair_analysis.multisine.spectrum_evidence import SpectrumEvidence
from flaair_model.model import Model
from flaair_model.settings import TableSettings

from .fit import PITCH_KEYS, STROKE_KEYS, identify_table
from .reader import Table
from .table_evidence import TableEvidence, table_scores

__all__ = [
    "JointFit",
    "SetAgreement",
    "identify_evidence",
    "identify_joint",
    "run_scores",
    "table_identification",
]

_SIDES = (("stroke", "stroke_deg", STROKE_KEYS), ("pitch", "pitch_deg", PITCH_KEYS))
_ALONE = "one set: its residuals in units of its noise"
_BIRGE_REFIT = 1.2  # a set's chi-square per residual above which the stage is refitted weighted


@dataclass(frozen=True)
class SetAgreement:
    """One data set's agreement with the jointly fitted model.

    Attributes
    ----------
    name : "runs" or "table".
    n : residuals (decimated samples or measured cells).
    chi2 : sum of squares of its noise-weighted residuals (unweighted by the block weight).
    noise_ratio : {channel or column: RMS of residual / noise}.
    nrmse : {channel or column: RMS residual / RMS measured}.
    weight : {stage: the block's weight in that stage's fit (1, or 1 / Birge ratio)}.
    alone : {column: noise_ratio} of the set fitted alone (the table's fit; {} for the runs).
    """

    name: str
    n: int
    chi2: float
    noise_ratio: dict[str, float]
    nrmse: dict[str, float]
    weight: dict[str, float]
    alone: dict[str, float] = field(default_factory=dict)

    def gaps(self, ratio: float) -> list[str]:
        """The channels or columns whose residual is above `ratio` x noise."""
        return [c for c, v in self.noise_ratio.items() if v > ratio]


@dataclass(frozen=True)
class JointFit:
    """The plant fitted to runs and a table together.

    Attributes
    ----------
    model : the input model with the jointly fitted plant.
    keys : fitted plant keys; values, nominal, start, stderr: {key: value}.
    table_alone, runs_start : {key: value} of the table fitted alone (the start) and of the runs'
        frequency-domain estimate (what each set alone points to).
    correlation : (p, p) within each stage (NaN across stages).
    runs : the runs with their initial states fitted along with the plant.
    agreement : {"runs": SetAgreement, "table": SetAgreement}.
    warnings : sets that disagree (one sentence each); notes: what the data cannot tell.
    nfev : the fit's evaluations (every stage).
    inseparable : the combinations the data cannot separate (`inseparable_notes`).
    weighting : how the sets' residuals are weighed, in words.
    """

    model: Model
    keys: tuple[str, ...]
    values: dict[str, float]
    nominal: dict[str, float]
    start: dict[str, float]
    stderr: dict[str, float]
    table_alone: dict[str, float]
    runs_start: dict[str, float]
    correlation: np.ndarray
    runs: tuple[Run, ...]
    agreement: dict[str, SetAgreement]
    warnings: tuple[str, ...]
    notes: tuple[str, ...]
    nfev: int
    inseparable: tuple[str, ...] = ()
    weighting: str = "sum of chi-squares; a set above its noise divided by its Birge ratio"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN and inf as None)."""

        def fin(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "parameters": {
                k: {
                    "value": self.values[k],
                    "nominal": self.nominal[k],
                    "start": self.start[k],
                    "stderr": fin(self.stderr[k]),
                    "relative_change": self.values[k] / self.nominal[k] - 1.0,
                    "table_alone": fin(self.table_alone.get(k, math.nan)),
                    "runs_frequency_domain": fin(self.runs_start.get(k, math.nan)),
                }
                for k in self.keys
            },
            "correlation": {
                "order": list(self.keys),
                "matrix": [[fin(x) for x in row] for row in self.correlation],
            },
            "data_sets": {
                name: {
                    "residuals": a.n,
                    "chi2_per_residual": a.chi2 / max(a.n, 1),
                    "noise_ratio": {c: fin(v) for c, v in a.noise_ratio.items()},
                    "nrmse": {c: fin(v) for c, v in a.nrmse.items()},
                    "weight": a.weight,
                    "noise_ratio_fitted_alone": {c: fin(v) for c, v in a.alone.items()},
                }
                for name, a in self.agreement.items()
            },
            "inseparable": list(self.inseparable),
            "agree": not self.warnings,
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "weighting": self.weighting,
        }


def _side_pieces(
    runs: list[Run],
    others: Sequence[EvidenceSet],
    model: Model,
    side: str,
    channel: str,
    noise: Mapping[str, float],
    decimate: int,
) -> list[Evidence]:
    """The evidence a side's stage is fitted on: the runs' truth channel (with each run's angle
    and rate), then each other set's piece of the side.
    """
    pieces: list[Evidence] = []
    if runs:
        omega = 2.0 * math.pi * float(getattr(model.plant, f"{side}_natural_frequency_hz"))
        pieces.append(RunEvidence(runs, noise, decimate, (channel,), side, omega))
    for other in others:
        if (piece := other.stage_piece(side, channel)) is not None:
            pieces.append(piece)
    return pieces


def _others(
    table: Table | None,
    spectra: SpectrumEvidence | None,
    s: TableSettings,
    extra: Sequence[EvidenceSet],
) -> list[EvidenceSet]:
    """The sets beside the runs: the table (every column), the spectra, then any other kind."""
    others: list[EvidenceSet] = []
    if table is not None:
        others.append(TableEvidence(table, s, list(table.responses)))
    if spectra is not None:
        others.append(spectra)
    return [*others, *extra]


def run_scores(
    runs: Sequence[Run], model: Model, noise: Mapping[str, float], decimate: int
) -> tuple[dict[str, float], dict[str, float], int, float]:
    """The runs' truth against `model` from each run's state: per channel noise ratio and NRMSE,
    residuals and chi-square (as the joint fit weighs them).
    """
    ratio, nrmse, n, chi2 = {}, {}, 0, 0.0
    for _, channel, _ in _SIDES:
        evidence = RunEvidence(runs, noise, decimate, (channel,))
        r = evidence.residuals([model], np.zeros(0))[0]
        meas = np.concatenate(
            [run.channel(channel)[i[channel]] for run, i in zip(runs, evidence.idx, strict=True)]
            or [np.zeros(0)]
        )
        if r.size == 0:
            continue
        ratio[channel] = float(np.sqrt(np.mean(r**2)))
        nrmse[channel] = ratio[channel] * evidence.sigma[channel] / max(float(np.std(meas)), 1e-300)
        n, chi2 = n + r.size, chi2 + float(r @ r)
    return ratio, nrmse, n, chi2


def identify_joint(
    runs: Sequence[Run],
    table: Table | None,
    model: Model,
    noise: Mapping[str, float],
    s: TableSettings,
    decimate: int = DECIMATE,
    spectra: SpectrumEvidence | None = None,
    extra: Sequence[EvidenceSet] = (),
) -> JointFit:
    """Fit the plant to any of `runs`, `table`, `spectra` and `extra` sets of one robot
    together.

    Parameters
    ----------
    runs
        The robot's runs (`check_runs`), ground truth present (may be empty).
    table
        The same robot's frequency-response table, or None.
    model
        Model to start from (its effects are kept; inertias and sensors stay).
    noise
        Noise RMS per run channel (`noise_estimates`), the runs' residual weights.
    s
        Table settings: reading noise, fit range, iterations, `gap_ratio` (agreement).
    decimate
        Keep every k-th run sample.
    spectra
        A multisine run set's line spectra (`multisine.spectrum_evidence`), or None.
    extra
        Any other kind of measured set (`evidence.EvidenceSet`), fitted and scored as these.
    """
    runs = list(runs)
    others = _others(table, spectra, s, extra)
    keys = STROKE_KEYS + PITCH_KEYS
    nominal = {k: float(getattr(model.plant, k)) for k in keys}
    alone, table_ratio_alone, notes = _table_fitted_alone(table, model, s, keys)
    runs_start = (
        {k: float(v) for k, v in frequency_domain_start(runs, model).items() if k in keys}
        if runs
        else {}
    )
    start = _joint_start(table, alone, runs_start, nominal, notes)

    def stage_of(
        channel: str, side_keys: tuple[str, ...], current: Model, now: list[Run]
    ) -> Stage | None:
        side = "stroke" if channel == "stroke_deg" else "pitch"
        pieces = _side_pieces(now, others, current, side, channel, noise, decimate)
        if not any(p.sites for p in pieces):
            notes.append(f"nothing measures the {side}: the {side} plant stays the model's")
            return None
        free = plant_params(current, side_keys, start, s.fit_range)
        return Stage(
            side_keys,
            tuple(pieces),
            (np.array([f.spec.to_fit(f.start) for f in free]),),
            np.array([f.spec.to_fit(f.lower) for f in free]),
            np.array([f.spec.to_fit(f.upper) for f in free]),
            s.max_nfev,
            _BIRGE_REFIT,
        )

    staged = fit_stages(model, runs, keys, stage_of)
    current, runs = staged.model, list(staged.runs)
    values = {k: staged.values.get(k, float(getattr(current.plant, k))) for k in keys}
    sd, corr = staged.sd, staged.correlation
    weights, nfev = _stage_weights(staged.stages)
    agreement = _set_agreements(runs, others, current, noise, decimate, weights, table_ratio_alone)
    warnings = _disagreement(agreement, s.gap_ratio, alone, runs_start, values)
    rel_se = [sd[i] if k in staged.values else math.nan for i, k in enumerate(keys)]
    free = [i for i, k in enumerate(keys) if k in staged.values]
    inseparable = inseparable_notes(
        [keys[i] for i in free],
        [rel_se[i] for i in free],
        corr[np.ix_(free, free)],
        "these sets" if len(agreement) > 1 else f"the {next(iter(agreement), 'data')}",
    )
    return JointFit(
        model=current,
        keys=tuple(keys),
        values=values,
        nominal=nominal,
        start={k: start[k] for k in keys},
        stderr={k: float(values[k] * sd[i]) for i, k in enumerate(keys)},
        table_alone=alone,
        runs_start=runs_start,
        correlation=corr,
        runs=tuple(runs),
        agreement=agreement,
        warnings=tuple(warnings),
        notes=tuple(notes),
        nfev=nfev,
        inseparable=tuple(inseparable),
    )


def _joint_start(
    table: Table | None,
    alone: Mapping[str, float],
    runs_start: Mapping[str, float],
    nominal: Mapping[str, float],
    notes: list[str],
) -> dict[str, float]:
    """Where the joint fit starts: the table fitted alone (itself started from its peaks), or the
    runs' estimate for a side the table does not measure (noted), or the model's values.
    """
    start = dict(alone) if alone else {k: runs_start.get(k, v) for k, v in nominal.items()}
    for side, _, side_keys in _SIDES:
        if table is not None and not any(c.startswith(side) for c in table.responses):
            start.update({k: runs_start.get(k, nominal[k]) for k in side_keys})
            notes.append(f"the table has no {side} column: the {side} plant is the runs'")
    return start


def _table_fitted_alone(
    table: Table | None, model: Model, s: TableSettings, keys: Sequence[str]
) -> tuple[dict[str, float], dict[str, float], list[str]]:
    """The table fitted alone (`identify_table`): what it points to.

    Returns
    -------
    tuple
        ({key: value} of the table's fit, {column: noise ratio} of that fit, its notes); all
        empty without a table.
    """
    notes: list[str] = []
    alone: dict[str, float] = {}
    table_ratio_alone: dict[str, float] = {}
    if table is not None:
        table_model, _, _, table_notes = identify_table(table, model, s)
        alone = {k: float(getattr(table_model.plant, k)) for k in keys}
        table_ratio_alone, _, _, _ = table_scores(table, table_model, s)
        notes.extend(table_notes)
    return alone, table_ratio_alone, notes


def _stage_weights(
    stages: Sequence[tuple[str, Stage, EvidenceFit]],
) -> tuple[dict[str, dict[str, float]], int]:
    """Each set's block weight per side in the staged fit, and the fit's evaluations.

    Returns
    -------
    tuple
        ({set name: {side: weight}}, the evaluations of every stage).
    """
    weights: dict[str, dict[str, float]] = {}
    nfev = 0
    for channel, stage, fit in stages:
        side = "stroke" if channel == "stroke_deg" else "pitch"
        for piece, w in zip(stage.pieces, fit.weights, strict=True):
            weights.setdefault(piece.name, {})[side] = w
        nfev += fit.nfev
    return weights, nfev


def _set_agreements(
    runs: Sequence[Run],
    others: Sequence[EvidenceSet],
    model: Model,
    noise: Mapping[str, float],
    decimate: int,
    weights: Mapping[str, dict[str, float]],
    table_ratio_alone: dict[str, float],
) -> dict[str, SetAgreement]:
    """Each given set's agreement with the jointly fitted `model` (each other set scored where
    it is fitted: `EvidenceSet.set_scores`).

    Returns
    -------
    dict
        {set name: SetAgreement}: "runs", then the others in their order.
    """
    agreement: dict[str, SetAgreement] = {}
    if runs:
        r_ratio, r_nrmse, r_n, r_chi2 = run_scores(runs, model, noise, decimate)
        agreement["runs"] = SetAgreement(
            "runs", r_n, r_chi2, r_ratio, r_nrmse, weights.get("runs", {})
        )
    for other in others:
        ratio, nrmse, n, chi2 = other.set_scores(model)
        alone = table_ratio_alone if other.name == "table" else {}
        agreement[other.name] = SetAgreement(
            other.name, n, chi2, ratio, nrmse, weights.get(other.name, {}), alone
        )
    return agreement


def identify_evidence(
    runs: Sequence[Run],
    table: Table | None,
    model: Model,
    noise: Mapping[str, float],
    s: TableSettings,
    decimate: int = DECIMATE,
    spectra: SpectrumEvidence | None = None,
    extra: Sequence[EvidenceSet] = (),
) -> JointFit:
    """The plant fitted on whatever evidence of one robot is given: the one identification.

    Runs alone are fitted as `identification.identify_plant` (started from the better of the
    model and the runs' frequency-domain estimate, within its fit range), a table alone as
    `fit.identify_table` (started from its peaks, within the tables' range), and any other mix
    (runs and a table, a multisine set with or without either) by `identify_joint` (started
    from the table fitted alone or the runs' estimate, each set weighed by its chi-square). Each
    is a choice of stages for `fit_stages`; the result is one `JointFit` with each set's
    agreement. Parameters as `identify_joint`.
    """
    runs = list(runs)
    if table is None and spectra is None and not extra:
        return _runs_alone(runs, model, noise, decimate)
    if not runs and spectra is None and table is not None and not extra:
        return _table_alone(table, model, s)
    return identify_joint(runs, table, model, noise, s, decimate, spectra, extra)


def _sides(keys: Sequence[str]) -> dict[str, float]:
    """A weight of 1 for each side with a fitted key (a lone set is never down-weighted)."""
    return {side: 1.0 for side, _, side_keys in _SIDES if set(side_keys) & set(keys)}


def _runs_alone(
    runs: list[Run], model: Model, noise: Mapping[str, float], decimate: int
) -> JointFit:
    fit = identify_plant(runs, model, noise, decimate=decimate)
    ratio, nrmse, n, chi2 = run_scores(fit.runs, fit.model, noise, decimate)
    return JointFit(
        model=fit.model,
        keys=tuple(fit.keys),
        values=dict(fit.values),
        nominal=dict(fit.nominal),
        start=dict(fit.start),
        stderr=dict(fit.stderr),
        table_alone={},
        runs_start=dict(fit.start),
        correlation=fit.correlation,
        runs=fit.runs,
        agreement={"runs": SetAgreement("runs", n, chi2, ratio, nrmse, _sides(fit.keys))},
        warnings=(),
        notes=(),
        nfev=0,
        inseparable=fit.inseparable,
        weighting=_ALONE,
    )


def _table_alone(table: Table, model: Model, s: TableSettings) -> JointFit:
    return table_identification(table, model, s, *identify_table(table, model, s))


def table_identification(
    table: Table,
    model: Model,
    s: TableSettings,
    fitted: Model,
    fits: Sequence[ParamFit],
    start: Mapping[str, float],
    notes: Sequence[str],
) -> JointFit:
    """A table's own identification (`fit.identify_table`'s outputs, from `model`) as the one
    identification result: each stage's parameters, the correlation within each stage, the
    table's agreement, its misfit warnings.
    """
    keys = tuple(p.key.removeprefix("plant.") for f in fits for p in f.params)
    values = {p.key.removeprefix("plant."): f.values[p.key] for f in fits for p in f.params}
    stderr = {p.key.removeprefix("plant."): f.stderr[p.key] for f in fits for p in f.params}
    corr = np.full((len(keys), len(keys)), np.nan)
    at = 0
    for f in fits:
        block = slice(at, at + len(f.params))
        corr[block, block] = f.correlation
        at += len(f.params)
    ratio, nrmse, n, chi2 = table_scores(table, fitted, s)
    rel_se = [abs(stderr[k] / values[k]) if values[k] else math.inf for k in keys]
    warnings = tuple(n.removeprefix("warning: ") for n in notes if n.startswith("warning: "))
    return JointFit(
        model=fitted,
        keys=keys,
        values=values,
        nominal={k: float(getattr(model.plant, k)) for k in keys},
        start={k: float(start.get(k, values[k])) for k in keys},
        stderr=stderr,
        table_alone=dict(values),
        runs_start={},
        correlation=corr,
        runs=(),
        agreement={"table": SetAgreement("table", n, chi2, ratio, nrmse, _sides(keys))},
        warnings=warnings,
        notes=tuple(n for n in notes if not n.startswith("warning: ")),
        nfev=sum(f.nfev for f in fits),
        inseparable=tuple(inseparable_notes(keys, rel_se, corr, "the table's cells")),
        weighting=_ALONE,
    )


def _names(sets: Sequence[str]) -> str:
    """'the runs', 'the runs and the spectra', ...: the sets by name."""
    named = [f"the {name}" for name in sets] or ["the other sets"]
    return named[0] if len(named) == 1 else ", ".join(named[:-1]) + " and " + named[-1]


def _disagreement(
    agreement: Mapping[str, SetAgreement],
    gap_ratio: float,
    alone: Mapping[str, float],
    runs_start: Mapping[str, float],
    joint: Mapping[str, float],
) -> list[str]:
    """One sentence naming each set's gap, when a set is above `gap_ratio` x its noise."""
    gaps = {name: a.gaps(gap_ratio) for name, a in agreement.items()}
    if not any(gaps.values()):
        return []
    table = agreement.get("table")
    table_alone_ok = table is not None and all(v <= gap_ratio for v in table.alone.values())
    per_set = "; ".join(
        f"{name}: "
        + (
            ", ".join(f"{c} {agreement[name].noise_ratio[c]:.1f}x noise" for c in g)
            if g
            else "at noise"
        )
        for name, g in gaps.items()
    )
    fn = "stroke_natural_frequency_hz"
    said = [f"table alone {alone.get(fn, math.nan):.1f} Hz"]
    if fn in runs_start:  # runs were given
        said.append(f"runs' frequency-domain estimate {runs_start[fn]:.1f} Hz")
    where = f" (stroke natural frequency: {', '.join(said)}, joint {joint[fn]:.1f} Hz)"
    if table is None:
        return [
            "after the joint fit a gap above noise remains (" + per_set + where + "): the sets "
            "disagree (another robot, other conditions), or the model misses physics "
            "(`discrepancy` with the same inputs looks for it)"
        ]
    # the sets beside the table, by name (the runs, the spectra, any other kind)
    rest = [name for name in gaps if name != "table"]
    rest_gaps = [name for name in rest if gaps[name]]
    if table_alone_ok and gaps["table"] and not rest_gaps:
        head = f"the table and {_names(rest)} disagree: after the joint fit " + per_set + where
        return [head + "; are they the same robot under the same conditions?"]
    if table_alone_ok and gaps["table"]:
        return [
            "neither set reaches its noise with one plant (after the joint fit "
            + per_set
            + where
            + "): the sets disagree (another robot, other conditions), or the model misses "
            "physics that shows differently in each (`discrepancy` with both looks for it)"
        ]
    if table_alone_ok:
        who = _names(rest_gaps)
        return [
            f"a gap above noise remains on {who} after the joint fit ("
            + per_set
            + where
            + "): the sets disagree, or the model misses physics seen there (`discrepancy` "
            f"on {who} alone tells which)"
        ]
    return [
        "after the joint fit a gap above noise remains ("
        + per_set
        + where
        + "); the table alone does not reach its noise either: physics the model misses"
    ]
