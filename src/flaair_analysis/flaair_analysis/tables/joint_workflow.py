"""The discrepancy workflow on runs beside other sets of the same robot: a table, a multisine
set's line spectra, or both (docs/TABLES.md, docs/MULTISINE.md). Pure.

What is joint and what is not:

1. The plant is fitted on every set (`joint.identify_joint`): joint.
2. The runs' search (`discrepancy.workflow.analyse`, started from the joint plant, judged on
   held-out runs), its findings (effects, discovered terms) then judged on every other set:
   the table's held-out drive levels (each level predicted by the joint plant with the
   findings, its plant refitted on the other levels) and the multisine's line spectra of all
   four channels (the plant refitted on their video channels). Kept when no set's chi-square
   rises beyond its noise: by more than 2 sqrt(2 N) over N residuals (two standard deviations
   of a chi-square: what noise alone moves it by). The runs have already required a better
   held-out prediction of the runs, so the rule reads "improves one set without worsening
   another beyond noise". Refused: none of them is in the model, the status is `unexplained`
   and a note says why. With a multisine set and no other runs, the set's runs are searched as
   time series (the spectra's check is then in sample, and a note says so).
3. Where the table's held-out levels still keep a gap (a column above `gap_ratio` x noise), the
   table's own search (`workflow.analyse_table`, from the model so far, judged on held-out
   levels); its findings judged on the runs: kept when the runs' chi-square (from their fitted
   states) does not rise by more than 2 sqrt(2 N) over their N samples. An effect only a table
   shows (a stop the runs' quieter drive never reaches) is found this way.
4. With anything kept, the plant is refitted on every set with it in place (the findings'
   values as their own search fitted them).
5. The multisine's odd and even lines read against the joint plant and the model written
   (`multisine.analysis.model_reading`): which channels show distortion the model does not
   predict, and where it points.

Not joint: a candidate is fitted and ranked on one set (its own search's) and only checked on
the others; the findings' values are not refitted on every set.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

from flaair_analysis.discrepancy.diagnosis import diagnose, noise_estimates
from flaair_analysis.discrepancy.evidence_search import plant_params, with_values
from flaair_analysis.discrepancy.runs import Run, simulate_runs
from flaair_analysis.discrepancy.workflow import DiscrepancyResult, analyse
from flaair_analysis.evidence import EvidenceSet, chi2_allowance
from flaair_analysis.multisine.analysis import model_reading
from flaair_analysis.multisine.spectrum_evidence import SpectrumEvidence
from flaair_model.model import Model
from flaair_model.settings import DiscrepancySettings, TableSettings

from .fit import PITCH_KEYS, STROKE_KEYS
from .joint import JointFit, identify_joint, run_scores
from .reader import Table
from .steady_state import steady_response
from .table_evidence import prediction_scores
from .workflow import TableDiscrepancy, analyse_table, heldout_predictions

__all__ = [
    "JointDiscrepancy",
    "TableCheck",
    "analyse_evidence",
    "analyse_joint",
    "set_check",
    "spectra_check",
    "table_heldout",
]


@dataclass(frozen=True)
class TableCheck:
    """The table's held-out drive levels predicted by a model (plant refitted on the others).

    Attributes
    ----------
    noise_ratio, nrmse : {column: RMS residual / noise, RMS residual / RMS measured}.
    chi2, n : sum of squares of the noise-weighted held-out residuals, and the cells.
    held_out : whether levels were held out; a one-level table is predicted in sample (nothing
        to hold out), and says so.
    """

    noise_ratio: dict[str, float]
    nrmse: dict[str, float]
    chi2: float
    n: int
    held_out: bool = True
    label: str = ""  # how the prediction was made, where not a table's levels

    @property
    def kind(self) -> str:
        """How the levels were predicted, in words: 'held-out drive levels' or 'in sample ...'."""
        if self.label:
            return self.label
        if self.held_out:
            return "held-out drive levels"
        return "in sample: one drive level, nothing held out"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "noise_ratio": self.noise_ratio,
            "nrmse": self.nrmse,
            "chi2_per_cell": self.chi2 / max(self.n, 1),
            "cells": self.n,
            "held_out": self.held_out,
        }


@dataclass(frozen=True)
class JointDiscrepancy:
    """Outcome of `analyse_joint`.

    Attributes
    ----------
    status : `unexplained` when the table refused the runs' findings, or with the model written
        the runs (their diagnosis) or the table's held-out levels keep a gap; else `explained`
        when something was kept, `no_discrepancy` when nothing was needed.
    joint : the plant fitted on both before the search.
    runs_result : the runs' workflow started from the joint plant.
    final : the plant refitted on both with the findings in place (None: nothing kept).
    model_out : what to write: `final`'s model, or the joint plant alone.
    kept : the runs' findings passed the table's check (True when there were none).
    table_before, table_after : the table's held-out levels, joint plant and model_out.
    notes : what the table check decided, in words.
    """

    status: str
    joint: JointFit
    runs_result: DiscrepancyResult
    final: JointFit | None
    model_out: Model
    table_before: TableCheck | None
    table_after: TableCheck | None
    kept: bool
    notes: tuple[str, ...]
    spectra_before: TableCheck | None = None
    spectra_after: TableCheck | None = None
    localisation: dict[str, Any] = field(default_factory=dict)  # "before"/"after": multisine doc
    # any other kind of set (`EvidenceSet`): {name: (its check with the joint plant, with
    # model_out)}
    others: dict[str, tuple[TableCheck, TableCheck]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary of the joint parts (the runs' part is the runs' report)."""
        return {
            "status": self.status,
            "joint_identification": self.joint.as_dict(),
            "final_identification": self.final.as_dict() if self.final is not None else None,
            "table_heldout_before": _doc(self.table_before),
            "table_heldout_after": _doc(self.table_after),
            "table_chi2_allowance": chi2_allowance(self.table_before.n)
            if self.table_before
            else None,
            "spectra_before": _doc(self.spectra_before),
            "spectra_after": _doc(self.spectra_after),
            "spectra_chi2_allowance": (
                chi2_allowance(self.spectra_before.n) if self.spectra_before else None
            ),
            "multisine": self.localisation,
            "other_sets": {
                name: {
                    "before": _doc(before),
                    "after": _doc(after),
                    "chi2_allowance": chi2_allowance(before.n),
                }
                for name, (before, after) in self.others.items()
            },
            "findings_kept": self.kept,
            "notes": list(self.notes),
            "what_is_joint": "plant fitted on every set (runs, table, multisine spectra); the "
            "runs' search (held-out runs) checked on the table's held-out drive levels and on "
            "the spectra; where the table keeps a gap, the table's search (held-out levels) "
            "checked on the runs; plant refitted on every set",
        }


# per set checked: what its chi-square is, its residuals' unit, what keeps a gap
_WORDS = {
    "table": ("held-out chi-square", "cells", "held-out levels"),
    "spectra": ("line-spectra chi-square", "line residuals", "line spectra"),
}
_OTHER_WORDS = ("chi-square", "residuals", "residuals")  # another kind of set


def set_check(evidence: EvidenceSet, model: Model, s: TableSettings) -> TableCheck:
    """Another kind of set predicted by `model` with its plant refitted on the set (as the
    spectra's check: a finding is judged with the plant it trades off against); in sample.
    """
    refitted = identify_joint([], None, model, {}, s, extra=[evidence]).model
    ratio, nrmse, n, chi2 = evidence.set_scores(refitted)
    return TableCheck(ratio, nrmse, chi2, n, held_out=False, label=f"{evidence.name}, in sample")


def _doc(check: TableCheck | None) -> dict[str, Any] | None:
    return check.as_dict() if check is not None else None


def spectra_check(spectra: SpectrumEvidence, model: Model, s: TableSettings) -> TableCheck:
    """The multisine's line spectra predicted by `model` with its plant refitted on the spectra's
    video channels (as a table's held-out levels refit theirs: a finding is judged with the plant
    it trades off against); in sample.
    """
    refitted = identify_joint([], None, model, {}, s, spectra=spectra).model
    ratio, nrmse, n, chi2 = spectra.scores(refitted)
    return TableCheck(ratio, nrmse, chi2, n, held_out=False, label="multisine line spectra")


def table_heldout(table: Table, model: Model, s: TableSettings) -> TableCheck:
    """Each level of `table` predicted by `model` with its plant refitted on the other levels."""
    cols = list(table.responses)
    keys = [
        *(STROKE_KEYS if any(c.startswith("stroke") for c in cols) else ()),
        *(PITCH_KEYS if any(c.startswith("pitch") for c in cols) else ()),
    ]
    if table.levels_v.size < 2:  # nothing to hold out: the model as it is
        resp = steady_response(
            [model], table.frequency_hz, table.drive_amplitude_v, table.drive_bias_v, s
        )
        pred = {c: resp[c][0] for c in cols}
    else:
        quick = replace(s, max_nfev=s.heldout_max_nfev)
        pred = heldout_predictions(table, model, plant_params(model, keys, {}, 1.5), quick, cols)
    ratio, nrmse, n_cells, chi2 = prediction_scores(table, pred, s)
    return TableCheck(ratio, nrmse, chi2, n_cells, held_out=table.levels_v.size >= 2)


def analyse_joint(
    runs: Sequence[Run],
    table: Table | None,
    model: Model,
    noise: Mapping[str, float],
    s: TableSettings,
    settings: DiscrepancySettings,
    progress: Callable[[str], None] | None = None,
    spectra: SpectrumEvidence | None = None,
    search_runs: Sequence[Run] = (),
    drive_limit_v: float | None = None,
    extra: Sequence[EvidenceSet] = (),
) -> JointDiscrepancy:
    """Plant on every set, the runs' search checked on the others, plant on every set again
    (module docstring). `search_runs`: the runs searched when `runs` is empty (a multisine set's
    own runs, read as time series); `drive_limit_v`: the plant's drive clamp, for the spectra's
    reading of a model; `extra`: any other kind of set (`EvidenceSet`), fitted with the plant and
    checking the findings as the spectra do.
    """
    if progress:
        progress("joint plant")
    joint = identify_joint(runs, table, model, noise, s, settings.decimate, spectra, extra)
    searched = list(joint.runs) or list(search_runs)
    if not searched:
        raise ValueError("no runs to search: give measured runs (or a multisine run set)")
    notes: list[str] = []
    if not joint.runs:
        notes.append(
            "no time-series runs beside the multisine set: its runs are searched as time "
            "series, so the spectra's check of the findings is in sample"
        )
    result = analyse(searched, joint.model, settings, progress=progress)
    checks = _checks(table, spectra, s, extra)
    if progress and checks:
        progress("checks on " + ", ".join(checks))
    before = {name: check(joint.model) for name, check in checks.items()}
    current, after, kept = joint.model, dict(before), True
    names = [e.name for e in result.effects] + [
        f"{d.term.kind}@{d.term.acts_on}" for d in result.discovered
    ]
    if names:
        findings = replace(result.model_out, plant=joint.model.plant)
        kept, trial = _checked(checks, before, findings, names, notes)
        if kept:
            current, after = findings, trial
    else:
        notes.append("the runs' search added nothing")
    if table is not None:
        table_found = _table_search(
            table, current, after["table"], searched, noise, s, settings, notes
        )
        if table_found is not None:
            current = table_found
    final = None
    if current is not joint.model:
        if progress:
            progress("joint plant again")
        final = identify_joint(runs, table, current, noise, s, settings.decimate, spectra, extra)
        current = final.model
        after = {name: check(current) for name, check in checks.items()}
        notes.append("the plant refitted on every set with what was kept")
    runs_now = list(final.runs) if final is not None and final.runs else searched
    sims = simulate_runs([current], runs_now)[0]
    runs_gaps = diagnose(runs_now, sims, current, noise, settings).gaps
    if runs_gaps:
        notes.append(f"with the model written the runs keep a gap on {', '.join(runs_gaps)}")
    set_gaps = _set_gaps(after, s.gap_ratio, notes)
    localisation = _multisine_reading(spectra, joint.model, current, drive_limit_v, notes)
    if not kept or runs_gaps or set_gaps:
        status = "unexplained"
    else:
        status = "explained" if final is not None else "no_discrepancy"
    return JointDiscrepancy(
        status,
        joint,
        result,
        final,
        current,
        before.get("table"),
        after.get("table"),
        kept,
        tuple(notes),
        before.get("spectra"),
        after.get("spectra"),
        localisation,
        {o.name: (before[o.name], after[o.name]) for o in extra},
    )


def analyse_evidence(
    runs: Sequence[Run],
    table: Table | None,
    model: Model,
    s: TableSettings,
    settings: DiscrepancySettings,
    progress: Callable[[str], None] | None = None,
    spectra: SpectrumEvidence | None = None,
    search_runs: Sequence[Run] = (),
    drive_limit_v: float | None = None,
    extra: Sequence[EvidenceSet] = (),
) -> DiscrepancyResult | TableDiscrepancy | JointDiscrepancy:
    """The discrepancy workflow on whatever evidence of one robot is given: runs alone by the
    runs' workflow (`discrepancy.workflow.analyse`: judged on held-out runs), a table alone by
    the table's (`workflow.analyse_table`: judged on held-out drive levels), any other mix by
    `analyse_joint` (the runs' search from the plant fitted on every set, its findings checked on
    every other set), with the noise of the runs it searches (`runs`, else `search_runs`).
    Parameters as `analyse_joint`.
    """
    if table is None and spectra is None and not extra:
        return analyse(list(runs), model, settings, progress=progress)
    if not runs and spectra is None and table is not None and not extra:
        if progress:
            progress("table")
        return analyse_table(table, model, s)
    searched = list(runs) or list(search_runs)
    noise = (
        noise_estimates(searched, simulate_runs([model], searched)[0], model) if searched else {}
    )
    return analyse_joint(
        runs, table, model, noise, s, settings, progress, spectra, search_runs, drive_limit_v, extra
    )


def _checks(
    table: Table | None,
    spectra: SpectrumEvidence | None,
    s: TableSettings,
    extra: Sequence[EvidenceSet] = (),
) -> dict[str, Callable[[Model], TableCheck]]:
    """How each set besides the runs predicts a model: the table's held-out drive levels, the
    multisine's line spectra, any other kind refitted on itself (`set_check`).
    """
    checks: dict[str, Callable[[Model], TableCheck]] = {}
    if table is not None:
        checks["table"] = lambda m: table_heldout(table, m, s)
    if spectra is not None:
        checks["spectra"] = lambda m: spectra_check(spectra, m, s)
    for other in extra:
        checks[other.name] = partial(set_check, other, s=s)
    return checks


def _set_gaps(after: Mapping[str, TableCheck], gap_ratio: float, notes: list[str]) -> list[str]:
    """The sets whose prediction keeps a column or channel above `gap_ratio` x noise. The
    multisine's film channels are not fitted (the plant is fitted on the video) and see what is
    left of the plant's error at many times the video's signal to noise: above noise they are a
    note, not a gap.
    """
    out = []
    for name, check in after.items():
        above = [c for c, v in check.noise_ratio.items() if v > gap_ratio]
        films = [c for c in above if name == "spectra" and c.endswith("_v")]
        if gaps := [c for c in above if c not in films]:
            out.append(name)
            notes.append(
                f"the {name}'s {_WORDS.get(name, _OTHER_WORDS)[2]} keep a gap on {', '.join(gaps)}"
            )
        if films:
            notes.append(
                f"the spectra of {', '.join(films)} stay above noise "
                f"({', '.join(f'{check.noise_ratio[c]:.1f}x' for c in films)}): what is left of "
                "the plant's error at the films' signal to noise (the plant is fitted on the "
                "video), or a film effect not found"
            )
    return out


def _checked(
    checks: Mapping[str, Callable[[Model], TableCheck]],
    before: Mapping[str, TableCheck],
    findings: Model,
    names: Sequence[str],
    notes: list[str],
) -> tuple[bool, dict[str, TableCheck]]:
    """The runs' findings checked on every other set: kept unless one set's chi-square rises
    beyond what noise allows; the sets' checks with them.
    """
    trial = {name: check(findings) for name, check in checks.items()}
    kept = True
    for name in checks:
        what, unit, _ = _WORDS.get(name, _OTHER_WORDS)
        rise, allowed = trial[name].chi2 - before[name].chi2, chi2_allowance(before[name].n)
        if rise > allowed:
            kept = False
            notes.append(
                f"the {name} refused the runs' findings ({', '.join(names)}): its {what} rose "
                f"by {rise:.1f} over {before[name].n} {unit} (noise allows {allowed:.1f}); "
                "they are not in the model"
            )
        else:
            notes.append(
                f"the {name}'s {what} {'fell' if rise < 0 else 'rose'} by {abs(rise):.1f} over "
                f"{before[name].n} {unit} with the runs' findings ({', '.join(names)}; noise "
                f"allows a rise of {allowed:.1f}): {'kept' if kept else 'checked'}"
            )
    return kept, trial


def _multisine_reading(
    spectra: SpectrumEvidence | None,
    before: Model,
    after: Model,
    drive_limit_v: float | None,
    notes: list[str],
) -> dict[str, Any]:
    """What the multisine's odd and even lines say of the joint plant and of the model written,
    and a note per distortion the joint plant does not predict ({} without spectra).
    """
    if spectra is None:
        return {}
    reading = {
        "before": model_reading(spectra.runs, before, drive_limit_v),
        "after": model_reading(spectra.runs, after, drive_limit_v),
    }
    for stage, label in (("before", "the joint plant"), ("after", "the model written")):
        for finding in reading[stage]["localisation"]["findings"]:
            notes.append(
                f"the multisine ({label}): {finding['distortion']} distortion the model does not "
                f"predict on {', '.join(finding['channels'])}: {finding['points_to']}"
            )
    return reading


def _table_search(
    table: Table,
    model: Model,
    check: TableCheck,
    runs: Sequence[Run],
    noise: Mapping[str, float],
    s: TableSettings,
    settings: DiscrepancySettings,
    notes: list[str],
) -> Model | None:
    """Where the table's held-out levels keep a gap, the table's own search from `model`; its
    findings added to `model` unless they worsen the runs beyond noise (None: nothing added).
    """
    if table.levels_v.size < 2 or all(v <= s.gap_ratio for v in check.noise_ratio.values()):
        return None
    found = analyse_table(table, model, s)
    params = [p for j in found.accepted for p in j.candidate.params]
    values = {p.key: j.fit.values[p.key] for j in found.accepted for p in j.candidate.params}
    names = [j.candidate.name for j in found.accepted]
    if not values:
        notes.append("the table's own search found nothing for its held-out gap")
        return None
    with_found = with_values(model, params, values)
    _, _, n, chi2_before = run_scores(runs, model, noise, settings.decimate)
    _, _, _, chi2_after = run_scores(runs, with_found, noise, settings.decimate)
    rise = chi2_after - chi2_before
    if rise > chi2_allowance(n):
        notes.append(
            f"the runs refused the table's findings ({', '.join(names)}): their chi-square rose "
            f"by {rise:.1f} over {n} samples (noise allows {chi2_allowance(n):.1f})"
        )
        return None
    notes.append(
        f"the table's own search found {', '.join(names)}; the runs' chi-square "
        f"{'fell' if rise < 0 else 'rose'} by {abs(rise):.1f} over {n} samples with them (noise "
        f"allows a rise of {chi2_allowance(n):.1f}): kept"
    )
    return with_found
