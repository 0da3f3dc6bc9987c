"""Scoring the discrepancy workflow on the hidden-effect datasets: one outcome per case, the
confusion table over cases.

A case passes when its outcome is exactly right (`flaair_analysis.exact_score`: the status, the
named effects and the discovered terms all equal the truth's, none below the resolution limit
named), the named effects' parameters are within `PARAMETER_TOLERANCE`, and the model error on
every channel with a gap drops by at least `MIN_GAP_REDUCTION`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..exact_score import ExactScore, score_exact, term_label
from .case import DatasetCase
from .vocabulary import CHANNELS
from .workflow import DiscrepancyResult

__all__ = [
    "MIN_GAP_REDUCTION",
    "PARAMETER_TOLERANCE",
    "CaseOutcome",
    "confusion_table",
    "expected_column",
    "found_label",
    "per_chain",
    "score_case",
    "score_result",
]

PARAMETER_TOLERANCE = 0.15  # found parameters within 15 % of the truth
MIN_GAP_REDUCTION = 0.5  # model-error NRMSE reduced by at least half on every channel with a gap


@dataclass(frozen=True)
class CaseOutcome:
    """How the workflow did on one case.

    Attributes
    ----------
    case : case name.
    true_label, found_label : confusion-table row and column.
    status, expected_status : reported and expected status.
    found : names of the found effects, sorted.
    parameter_errors : {effect.key: relative error} of the hidden effects' parameters.
    gap_reduction : {channel: 1 - model-error NRMSE after / before} on channels with a gap before.
    correct : exactly right (`score_result`: status, names and terms), parameters within 15 %,
        gap reduced by >= 50 % on every channel that had one (outside cases: status unexplained,
        exactly the hidden vocabulary effects found (usually none), no term, the gap on the
        expected channel).
    problems : why it is not correct.
    elapsed_s : analysis time.
    """

    case: str
    true_label: str
    found_label: str
    status: str
    expected_status: str
    found: tuple[Any, ...]
    parameter_errors: dict[str, Any]
    gap_reduction: dict[str, Any]
    correct: bool
    problems: tuple[Any, ...]
    elapsed_s: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready outcome."""
        return {
            "case": self.case,
            "true": self.true_label,
            "found": self.found_label,
            "status": self.status,
            "expected_status": self.expected_status,
            "found_effects": list(self.found),
            "parameter_errors": self.parameter_errors,
            "gap_reduction": self.gap_reduction,
            "correct": self.correct,
            "problems": list(self.problems),
            "elapsed_s": self.elapsed_s,
        }


def expected_column(true_label: str) -> str:
    """Confusion-table column of a right answer for a row label ('a+outside:x' -> 'a (gap left)';
    hidden 'plant:' effects are not named: 'a+plant:wing_damage'
    -> 'a'; 'below:a' -> 'none (gap left)').
    """
    parts = true_label.split("+")
    names = "+".join(
        p for p in parts if p != "none" and not p.startswith(("outside:", "plant:", "below:"))
    )
    gap = any(p.startswith(("outside:", "below:")) for p in parts)
    return (names or "none") + (" (gap left)" if gap else "")


def found_label(result: DiscrepancyResult) -> str:
    """Confusion-table column: found effect names, 'none', and ' (gap left)' if unexplained."""
    names = "+".join(sorted(e.name for e in result.effects)) or "none"
    return names + (" (gap left)" if result.status == "unexplained" else "")


def _excess(nrmse: float, floor: float) -> float:
    return math.sqrt(max(nrmse**2 - floor**2, 0.0))


def _split(params: dict[str, Any]) -> bool:
    return bool(params) and all(isinstance(v, dict) for v in params.values())


def per_chain(params: dict[str, Any]) -> dict[str, Any]:
    """An effect's numeric parameters per sensor chain it acts on: {'': {...}} for an effect without
    a chain; {'stroke': {...}, 'pitch': {...}} for one value on both chains or one per chain.
    """
    if _split(params):
        return {
            side: {k: float(v) for k, v in p.items() if not isinstance(v, str)}
            for side, p in params.items()
        }
    values = {k: float(v) for k, v in params.items() if not isinstance(v, str)}
    channel = params.get("channel")
    if channel is None:
        return {"": values}
    return {
        side: dict(values) for side in (("stroke", "pitch") if channel == "both" else (channel,))
    }


def score_result(case: DatasetCase, result: DiscrepancyResult) -> ExactScore:
    """The exact score of a workflow result against a case's truth (status, names, terms)."""
    return score_exact(
        status=result.status,
        names=(e.name for e in result.effects),
        terms=(term_label(d.term.kind, d.term.acts_on) for d in result.discovered),
        expected_status=case.expected_status,
        expected_names=case.expected_names,
        expected_terms=(term_label(t.kind, t.acts_on) for t in case.terms),
    )


def score_case(
    case: DatasetCase, result: DiscrepancyResult, elapsed_s: float = math.nan
) -> CaseOutcome:
    """Judge a workflow result against the case's hidden truth."""
    found = tuple(sorted(e.name for e in result.effects))
    problems = list(score_result(case, result).problems())
    errors: dict[str, Any] = {}
    reduction: dict[str, Any] = {}
    by_name = {e.name: e for e in result.effects}
    for name, params in case.effects:
        if name not in by_name:
            continue
        hidden, got_sides = per_chain(params), per_chain(by_name[name].parameters)
        if set(hidden) != set(got_sides):
            problems.append(f"{name} acts on {'+'.join(got_sides)}, hidden on {'+'.join(hidden)}")
            continue
        for side, values in hidden.items():
            for key, value in values.items():
                got = float(got_sides[side][key])
                rel = abs(got - value) / abs(value) if value else abs(got)
                label = f"{name}.{key}" + (
                    f"[{side}]" if len(hidden) > 1 and _split(params) else ""
                )
                errors[label] = max(rel, errors.get(label, 0.0))
                if rel > PARAMETER_TOLERANCE:
                    problems.append(f"{label} = {got:.4g}, hidden {value:.4g} ({rel:.0%} off)")
    if case.outside:
        gap_channels = {r["channel"] for r in result.remaining}
        if case.expected_gap_channel not in gap_channels:
            problems.append(
                f"no gap reported on {case.expected_gap_channel} (gaps: {sorted(gap_channels)})"
            )
    elif case.below_limit:
        if not result.remaining:
            problems.append("no gap reported")
    elif case.effects:
        for c in CHANNELS:
            if not result.diagnosis_before.channels[c].has_gap:
                continue
            floor = result.diagnosis_before.channels[c].noise_nrmse
            before = _excess(result.gap_before[c], floor)
            after = _excess(result.gap_after[c], floor)
            reduction[c] = 1.0 - after / before if before > 0 else 0.0
            if reduction[c] < MIN_GAP_REDUCTION:
                problems.append(f"{c}: gap reduced by {reduction[c]:.0%} only")
    return CaseOutcome(
        case=case.name,
        true_label=case.true_label,
        found_label=found_label(result),
        status=result.status,
        expected_status=case.expected_status,
        found=found,
        parameter_errors=errors,
        gap_reduction=reduction,
        correct=not problems,
        problems=tuple(problems),
        elapsed_s=elapsed_s,
    )


def confusion_table(outcomes: Sequence[CaseOutcome]) -> dict[str, Any]:
    """{"rows": true labels, "columns": found labels,
    "counts": [[...]], "correct": k, "total": n}.
    """
    rows = sorted({o.true_label for o in outcomes})
    cols = sorted({o.found_label for o in outcomes})
    counts = [
        [sum(1 for o in outcomes if o.true_label == r and o.found_label == c) for c in cols]
        for r in rows
    ]
    return {
        "rows": rows,
        "columns": cols,
        "counts": counts,
        "correct": sum(o.correct for o in outcomes),
        "total": len(outcomes),
    }


# ------------------------------------------------------------------ randomized off-nominal robots
