"""Discrepancy report: DIR/discrepancy.json, the figures (`report_figures`) and DIR/report.html.

`write_report` writes everything for one analysis; `write_validation` writes the confusion table
of the hidden-effect datasets (validation.json, validation.html), which `write_report` can also
embed in report.html.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, fields, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Environment, FileSystemLoader, select_autoescape

from flaair_analysis.discrepancy import FoundEffect
from flaair_analysis.discrepancy.runs import Run
from flaair_analysis.discrepancy.scoring import expected_column
from flaair_analysis.discrepancy.vocabulary import CHANNELS
from flaair_analysis.discrepancy.workflow import DiscrepancyResult, format_parameters
from flaair_common.strictjson import json_safe
from flaair_model.settings import DiscrepancySettings

from .report_figures import write_figures

__all__ = [
    "form_check_text",
    "result_to_dict",
    "write_json",
    "write_report",
    "write_validation",
]


def result_to_dict(
    result: DiscrepancyResult, model_out: str, settings: DiscrepancySettings
) -> dict:
    """The discrepancy.json document.

    Keys: status, effects [{name, channel, parameters, evidence, explains}], gap_before,
    gap_after (held-out NRMSE per channel), model_out, plus gap_in_sample_after, noise_rms,
    remaining (where a gap is left), diagnosis before/after, searches, summary, runs, rules,
    plant_parameters {key: {value, nominal, stderr}}, identification (start values,
    correlations, inseparable combinations), not_separable [{effect, reason}], approximate
    (effects fitted on a channel that keeps a gap, as `effects`: in the model, not named),
    discovered [{kind, acts_on, expression,
    parameters {value, stderr}, gap_before, gap_after, candidates_beaten, evidence}] (terms from
    the library, hypotheses), discovery_candidates (every term tried, per step).
    """

    def diag(d: Any) -> dict:
        return {c: asdict(g) for c, g in d.channels.items()}

    searches = []
    for s in result.searches:
        searches.append(
            {
                "channel": s.channel,
                "truth_referenced": s.truth_referenced,
                "skipped": s.skipped,
                "steps": [[ev.as_dict() for ev in step] for step in s.steps],
            }
        )
    doc = {
        "status": result.status,
        "effects": [_effect_doc(e) for e in result.effects],
        "gap_before": result.gap_before,
        "gap_after": result.gap_after,
        "model_out": model_out,
        "gap_in_sample_after": result.gap_in_sample_after,
        "noise_rms": result.noise,
        "remaining": list(result.remaining),
        "summary": result.summary,
        "runs": list(result.run_names),
        "diagnosis_before": diag(result.diagnosis_before),
        "diagnosis_after": diag(result.diagnosis_after),
        "searches": searches,
        "rules": _flat(settings),
        "plant_parameters": result.plant_parameters,
        "identification": result.plant_fit.as_dict() if result.plant_fit is not None else None,
        "not_separable": list(result.not_separable),
        "approximate": [_effect_doc(e) for e in result.approximate],
        "discovered": [d.as_dict() for d in result.discovered],
        "discovery_candidates": list(result.discovery_tried),
    }
    return json_safe(doc)


def _flat(settings: DiscrepancySettings) -> dict[str, Any]:
    """The settings as one flat mapping (the shared judging rules beside the runs' own)."""
    out: dict[str, Any] = {}
    for f in fields(settings):
        value = getattr(settings, f.name)
        out.update(asdict(value) if is_dataclass(value) else {f.name: value})
    return out


def _effect_doc(e: FoundEffect) -> dict[str, Any]:
    """An effect's entry: name, channel, parameters, evidence, explains."""
    return {
        "name": e.name,
        "channel": e.channel,
        "parameters": e.parameters,
        "evidence": e.evidence,
        "explains": list(e.explains),
    }


def write_json(path: Path, doc: Any) -> None:
    """Write a JSON document (NaN/inf as null)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(json_safe(doc), indent=2), encoding="utf-8")


def _discovered(result: DiscrepancyResult, figs: Mapping[str, str]) -> list[dict]:
    """Each discovered term for the page: words, equation, gaps, candidates beaten, figure."""
    out = []
    for i, d in enumerate(result.discovered):
        t = d.term
        where = {
            "stroke_dynamics": "a torque (N m) in the stroke equation of motion",
            "pitch_dynamics": "a torque (N m) in the pitch equation of motion",
            "drive": "volts added to the drive before the actuator",
        }.get(t.acts_on, f"volts added to {t.acts_on} (voltages measured from V_HREF)")
        params = ", ".join(
            f"{k} = {_f(v)} (SE {_f(d.stderr.get(k))})"
            for k, v in [("coefficient", t.coefficient), *t.shape]
        )
        beaten = [
            [
                b["term"],
                b["acts_on"],
                b["expression"] or "-",
                b["heldout_nrmse_after"],
                b["nrmse_margin"],
                ", ".join(b["failed_rules"]) or "passed, lost on error",
            ]
            for b in d.beaten
        ]
        out.append(
            {
                "title": f"{t.row.words.capitalize()} on {t.acts_on}",
                "equation": f"{t.acts_on} += {t.expression}",
                "words": f"{t.row.words.capitalize()}, acting as {where}; such a term stands for "
                f"{t.row.examples or 'physics the vocabulary does not name'}.",
                "parameters": params,
                "gap": _table(
                    ["channel", "held-out NRMSE without", "held-out NRMSE with"],
                    [[c, d.gap_before[c], d.gap_after[c]] for c in CHANNELS],
                ),
                "beaten": _table(
                    ["candidate", "acts on", "fitted", "held-out NRMSE", "margin", "failed rules"],
                    beaten,
                )
                if beaten
                else None,
                "fig": figs.get(f"discovered_{i}"),
                "form_check": form_check_text(d.uncertainty),
            }
        )
    return out


def form_check_text(uncertainty: Mapping[str, Any]) -> str | None:
    """Whether the runs tell a discovered form from the next best of its step, and the run that
    would where they do not (`discovery_uncertainty.form_uncertainty`), in a lab's words.
    """
    rival = uncertainty.get("next_best")
    if not rival:
        return None
    other = f"{rival['term']} on {rival['acts_on']}"
    margin = uncertainty.get("relative_margin")
    if uncertainty.get("distinguishable"):
        return (
            f"The next best form, {other}, predicts the held-out runs {100 * margin:.1f} % worse: "
            "these runs tell the two apart."
        )
    tied = (
        f"These runs do not tell this form from {other}: their held-out errors are within "
        f"{100 * (margin or 0.0):.2g} % of each other."
    )
    run = uncertainty.get("suggested_experiment") or {}
    if not run:
        return tied
    if not run["separates"]:
        return (
            f"{tied} No steady sine tried would: the two models differ by at most "
            f"{run['over_noise']:.2f} x the noise, so for such runs they are the same physics."
        )
    return (
        f"{tied} A run that would: a {run['waveform']} of {run['drive_amplitude_v']:.0f} V at "
        f"{run['frequency_hz']:.0f} Hz for {run['duration_s']:g} s, where the two models differ "
        f"by {run['over_noise']:.1f} x the noise."
    )


# --------------------------------------------------------------------------------------- HTML
# Jinja2 templates (templates/discrepancy_*.html.j2), autoescaped: every text, run and file names
# included, reaches the page as text, never as markup.

TEMPLATES = Path(__file__).resolve().parents[1] / "templates"


def _environment() -> Environment:
    return Environment(
        loader=FileSystemLoader(TEMPLATES),
        autoescape=select_autoescape(["html", "j2"]),
        trim_blocks=True,
        lstrip_blocks=True,
    )


def _f(v: Any, digits: int = 4) -> str:
    """A cell's text: numbers to `digits` significant digits, '-' when undefined."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.{digits}g}" if math.isfinite(float(v)) else "-"
    return str(v)


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> dict:
    """A table for the templates: header and rows of cell texts (escaped when rendered)."""
    return {"header": list(header), "rows": [[_f(c) for c in row] for row in rows]}


def _confusion(table: Mapping[str, Any], outcomes: Sequence[Mapping[str, Any]] = ()) -> dict:
    """A confusion table (true vs found), cells marked right or wrong, and the per-case outcomes."""
    rows = [
        {
            "label": r,
            "cells": [
                {"text": n or "", "cls": ("ok" if _label_match(r, col) else "bad") if n else ""}
                for col, n in zip(table["columns"], counts, strict=True)
            ],
        }
        for r, counts in zip(table["rows"], table["counts"], strict=True)
    ]
    cases = (
        _table(
            [
                "case",
                "true",
                "found",
                "status",
                "correct",
                "parameter errors",
                "gap reduction",
                "problems",
                "time s",
            ],
            [
                [
                    o["case"],
                    o["true"],
                    o["found"],
                    o["status"],
                    o["correct"],
                    ", ".join(
                        f"{k}: {v:.1%}" for k, v in (o.get("parameter_errors") or {}).items()
                    ),
                    ", ".join(f"{k}: {v:.0%}" for k, v in (o.get("gap_reduction") or {}).items()),
                    "; ".join(o.get("problems") or []),
                    o.get("elapsed_s"),
                ]
                for o in outcomes
            ],
        )
        if outcomes
        else None
    )
    return {
        "correct": table["correct"],
        "total": table["total"],
        "columns": list(table["columns"]),
        "rows": rows,
        "cases": cases,
    }


def _label_match(true: str, found: str) -> bool:
    return found == expected_column(true)


def _rules(s: DiscrepancySettings) -> dict[str, str]:
    """The decision rules' numbers, as the report states them."""
    return {
        "gap_noise_ratio": f"{s.gap_noise_ratio:g}",
        "whiteness_decimate": f"{s.whiteness_decimate}",
        "ljung_box_lags": f"{s.ljung_box_lags}",
        "whiteness_alpha": f"{s.whiteness_alpha:g}",
        "min_heldout_drop": f"{s.rules.min_heldout_drop:.0%}",
        "max_delta_bic": f"{s.max_delta_bic:g}",
        "min_z": f"{s.rules.min_z:g}",
        "consistency_alpha": f"{s.consistency_alpha:g}",
        "consistency_rel_tol": f"{s.consistency_rel_tol:.0%}",
        "max_effects_per_channel": f"{s.max_effects_per_channel}",
    }


def _plant_section(result: DiscrepancyResult) -> Any:
    """The fitted plant parameters beside the model's, and what the data cannot tell."""
    plant = None
    if result.plant_parameters:
        notes = list(result.plant_fit.inseparable) if result.plant_fit is not None else []
        notes += [f"{d['effect']} is not searched for: {d['reason']}" for d in result.not_separable]
        plant = {
            "table": _table(
                ["parameter", "fitted", "model", "change", "standard error (identification)"],
                [
                    [
                        k,
                        p["value"],
                        p["nominal"],
                        f"{p['value'] / p['nominal'] - 1.0:+.2%}",
                        p["stderr"],
                    ]
                    for k, p in result.plant_parameters.items()
                ],
            ),
            "notes": notes,
        }
    return plant


def _effects_table(effects_found: Sequence[FoundEffect]) -> Any:
    """Each effect with its evidence (rules R1-R6); None for none."""
    effects = None
    if effects_found:
        rows = []
        for e in effects_found:
            ev = e.evidence
            rules = ev.get("rules") or {}
            rows.append(
                [
                    e.name,
                    e.channel,
                    format_parameters(e.parameters),
                    ", ".join(ev.get("candidate", "").split("+")),
                    ev.get("heldout_gap_drop"),
                    ev.get("delta_bic_heldout"),
                    ", ".join(_f(z) for z in ev.get("z_from_null") or []),
                    ", ".join(_f(p) for p in ev.get("consistency_p") or []),
                    ", ".join(k for k, v in rules.items() if v),
                    ", ".join(e.explains),
                ]
            )
        effects = _table(
            [
                "effect",
                "found on",
                "parameters",
                "candidate",
                "held-out gap drop",
                "held-out dBIC",
                "z from null",
                "consistency p",
                "rules passed",
                "can change",
            ],
            rows,
        )
    return effects


def _remaining_table(result: DiscrepancyResult) -> Any:
    """Where a gap is left: band, drive level, worst stretch."""
    remaining = (
        _table(
            [
                "channel",
                "worst band Hz",
                "full/low drive error ratio",
                "worst stretch",
                "model-error NRMSE",
                "reading",
            ],
            [
                [
                    r["channel"],
                    r["band_hz"],
                    r["drive_level_ratio"],
                    f"{r['stretch'][0]} {r['stretch'][1]:.3f}-{r['stretch'][2]:.3f} s",
                    r["model_error_nrmse"],
                    r["note"],
                ]
                for r in result.remaining
            ],
        )
        if result.remaining
        else None
    )
    return remaining


def _diagnosis_tables(result: DiscrepancyResult) -> Any:
    """Each channel's diagnosis under the input model and the output model."""
    diagnosis = []
    for label, d in (
        ("input model", result.diagnosis_before),
        ("output model", result.diagnosis_after),
    ):
        rows = []
        for c in CHANNELS:
            g = d.channels[c]
            rows.append(
                [
                    c,
                    g.has_gap,
                    g.noise_ratio,
                    g.ljung_box_p,
                    g.xcorr_drive,
                    g.worst_band_hz,
                    g.level_ratio,
                    ", ".join(f"h{k}: {v:.0%}" for k, v in g.harmonic_fraction.items()),
                    f"{g.worst_stretch[0]} {g.worst_stretch[1]:.3f}-{g.worst_stretch[2]:.3f} s",
                    g.interpretation,
                ]
            )
        diagnosis.append(
            (
                label,
                _table(
                    [
                        "channel",
                        "gap",
                        "residual/noise",
                        "Ljung-Box p",
                        "xcorr with drive",
                        "worst band Hz",
                        "full/low drive ratio",
                        "harmonics of residual",
                        "worst stretch",
                        "reading",
                    ],
                    rows,
                ),
            )
        )
    return diagnosis


def _search_tables(result: DiscrepancyResult) -> Any:
    """Each channel's search, step by step: every candidate and its verdict."""
    searches = []
    for s in result.searches:
        rows = [
            [
                i,
                "+".join(ev.labels),
                ", ".join(_f(v) for v in ev.values),
                ev.heldout_gap_drop,
                ev.delta_bic_heldout,
                ", ".join(_f(z) for z in ev.z),
                ", ".join(_f(p) for p in ev.consistency_p),
                "; ".join(" / ".join(f"{n}: {_f(v)}" for n, v, _ in pr) for pr in ev.per_run),
                ", ".join(k for k, v in ev.rules.items() if not v) or "-",
                "accepted" if ev.accepted else "refused",
            ]
            for i, step in enumerate(s.steps)
            for ev in step
        ]
        searches.append(
            {
                "title": s.channel + (" (truth-referenced)" if s.truth_referenced else ""),
                "skipped": s.skipped,
                "table": _table(
                    [
                        "step",
                        "candidate",
                        "value",
                        "held-out gap drop",
                        "held-out dBIC",
                        "z",
                        "consistency p",
                        "per-run estimates",
                        "failed rules",
                        "verdict",
                    ],
                    rows,
                ),
            }
        )
    return searches


def _gap_table(result: DiscrepancyResult) -> Any:
    """The held-out gap per channel, input and output model, beside the noise floor."""
    return _table(
        [
            "channel",
            "input model",
            "output model",
            "output model, in-sample",
            "noise floor",
            "noise RMS",
        ],
        [
            [
                c,
                result.gap_before[c],
                result.gap_after[c],
                result.gap_in_sample_after[c],
                result.diagnosis_before.channels[c].noise_nrmse,
                result.noise[c],
            ]
            for c in CHANNELS
        ],
    )


# the other sets of a joint document: label, its check before and after the findings
_OTHER_SETS = (
    ("table", "table_heldout_before", "table_heldout_after"),
    ("multisine line spectra", "spectra_before", "spectra_after"),
)


def _fmt(x: Any) -> str:
    return "-" if x is None else f"{x:.4g}"


def _sets_section(joint: Mapping[str, Any]) -> dict[str, Any]:
    """The other sets' checks (before and after the findings) and the multisine's reading."""
    rows = []
    for label, before_key, after_key in _OTHER_SETS:
        before, after = joint.get(before_key), joint.get(after_key)
        if not before or not after:
            continue
        for c, ratio in before["noise_ratio"].items():
            rows.append(
                [label, c, _fmt(ratio), _fmt(after["noise_ratio"].get(c)),
                 _fmt(before["nrmse"].get(c)), _fmt(after["nrmse"].get(c))]
            )  # fmt: skip
    reading = joint.get("multisine") or {}
    lines = []
    for stage, label in (("before", "joint plant"), ("after", "model written")):
        if stage not in reading:
            continue
        for c, entry in reading[stage]["channels"].items():
            excess = {
                k: (v - entry["noise_db"]) if v is not None else None
                for k, v in entry["unexplained_db"].items()
            }
            lines.append(
                [label, c, ", ".join(entry["disagrees"]) or "none",
                 _fmt(excess.get("odd")), _fmt(excess.get("even"))]
            )  # fmt: skip
    findings = [
        f"{f['distortion']} on {', '.join(f['channels'])}: {f['points_to']}"
        for f in reading.get("before", {}).get("localisation", {}).get("findings", [])
    ]
    return {
        "checks": _table(
            ["set", "channel or column", "noise ratio before", "after", "NRMSE before", "after"],
            rows,
        ),
        "reading": _table(
            [
                "model",
                "channel",
                "distortion it does not predict",
                "odd dB over noise",
                "even dB over noise",
            ],
            lines,
        )
        if lines
        else None,
        "findings": findings,
        # the multisine's reading is its own table and list above
        "notes": [n for n in joint.get("notes", []) if not n.startswith("the multisine (")],
    }


def _context(
    runs: Sequence[Run],
    result: DiscrepancyResult,
    doc: Mapping[str, Any],
    figs: Mapping[str, str],
    settings: DiscrepancySettings,
    validation: Mapping[str, Any] | None,
) -> dict:
    """Everything report.html shows, as plain values for the template."""
    return {
        "status": result.status,
        "summary": result.summary,
        "model_out": str(doc.get("model_out")),
        "runs": [
            f"{r.name} ({r.n / r.fs_hz:.2f} s at {r.fs_hz:g} Hz, drive {r.drive_level_v:.0f} V)"
            for r in runs
        ],
        "gap": _gap_table(result),
        "figs": figs,
        "plant": _plant_section(result),
        "effects": _effects_table(result.effects),
        "approximate": _effects_table(result.approximate),
        "remaining": _remaining_table(result),
        "diagnosis": _diagnosis_tables(result),
        "searches": _search_tables(result),
        "r": _rules(settings),
        "discovered": _discovered(result, figs),
        "validation": _confusion(validation["confusion"], validation.get("cases", ()))
        if validation
        else None,
    }


def write_report(
    out_dir: Path,
    runs: Sequence[Run],
    result: DiscrepancyResult,
    model_out: str,
    settings: DiscrepancySettings,
    validation: Mapping[str, Any] | None = None,
    joint: Mapping[str, Any] | None = None,
) -> dict:
    """Write discrepancy.json, the figures and report.html
    into `out_dir`; returns the JSON document. `joint`: the joint workflow's document
    (`JointDiscrepancy.as_dict`) when the runs were one set among others.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = result_to_dict(result, model_out, settings)
    write_json(out_dir / "discrepancy.json", doc)
    figs = write_figures(out_dir, runs, result)
    context = _context(runs, result, doc, figs, settings, validation)
    if joint is not None:
        context["status"] = joint["status"]
        context["sets"] = _sets_section(joint)
    page = _environment().get_template("discrepancy_report.html.j2").render(context)
    (out_dir / "report.html").write_text(page, encoding="utf-8")
    return doc


def write_validation(
    out_dir: Path,
    outcomes: Sequence[Mapping[str, Any]],
    confusion: Mapping[str, Any],
    total_s: float,
) -> dict:
    """Write validation.json and validation.html (confusion table of the dataset cases)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {"confusion": confusion, "cases": list(outcomes), "total_s": total_s}
    write_json(out_dir / "validation.json", doc)
    page = (
        _environment()
        .get_template("discrepancy_validation.html.j2")
        .render(
            n_cases=len(outcomes),
            total_s=f"{total_s:.0f}",
            confusion=_confusion(confusion, outcomes),
        )
    )
    (out_dir / "validation.html").write_text(page, encoding="utf-8")
    return json_safe(doc)
