"""Discrepancy report: DIR/discrepancy.json, figures (matplotlib, no pyplot) and DIR/report.html.

`write_report` writes everything for one analysis; `write_validation` writes the confusion table
of the hidden-effect datasets (validation.json, validation.html), which `write_report` can also
embed in report.html.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Environment, FileSystemLoader, select_autoescape
from matplotlib.figure import Figure  # no pyplot: a notebook user's backend is left alone

from flaair_common.strictjson import json_safe
from flaair_sensors.figures import literal_texts

from .diagnosis import bode_points
from .runs import CHANNELS, Run, simulate_runs
from .settings import Settings
from .workflow import DiscrepancyResult, format_parameters

__all__ = [
    "confusion_html",
    "result_to_dict",
    "write_figures",
    "write_json",
    "write_report",
    "write_validation",
]

_UNITS = {"stroke_deg": "deg", "pitch_deg": "deg", "stroke_sensor_v": "V", "pitch_sensor_v": "V"}


def result_to_dict(
    result: DiscrepancyResult, model_out: str, settings: Settings = Settings()
) -> dict:
    """The discrepancy.json document.

    Keys: status, effects [{name, channel, parameters, evidence, explains}], gap_before,
    gap_after (held-out NRMSE per channel), model_out, plus gap_in_sample_after, noise_rms,
    remaining (where a gap is left), diagnosis before/after, searches, summary, runs, rules,
    plant_parameters {key: {value, nominal, stderr}}, identification (start values,
    correlations, inseparable combinations), not_separable [{effect, reason}], approximate
    (named effects that leave a gap where they act), discovered [{kind, acts_on, expression,
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
        "effects": [
            {
                "name": e.name,
                "channel": e.channel,
                "parameters": e.parameters,
                "evidence": e.evidence,
                "explains": list(e.explains),
            }
            for e in result.effects
        ],
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
        "rules": {f.name: getattr(settings, f.name) for f in fields(settings)},
        "plant_parameters": result.plant_parameters,
        "identification": result.plant_fit.as_dict() if result.plant_fit is not None else None,
        "not_separable": list(result.not_separable),
        "approximate": list(result.approximate),
        "discovered": [d.as_dict() for d in result.discovered],
        "discovery_candidates": list(result.discovery_tried),
    }
    return json_safe(doc)


def write_json(path: Path, doc: Any) -> None:
    """Write a JSON document (NaN/inf as null)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(json_safe(doc), indent=2), encoding="utf-8")


# ------------------------------------------------------------------------------------ figures


def _fig_gap(result: DiscrepancyResult, path: Path) -> None:
    fig = Figure(figsize=(7, 3.6))
    ax = fig.subplots()
    x = np.arange(len(CHANNELS))
    floor = [result.diagnosis_before.channels[c].noise_nrmse for c in CHANNELS]
    ax.bar(x - 0.27, [result.gap_before[c] for c in CHANNELS], 0.27, label="input model (held-out)")
    ax.bar(x, [result.gap_after[c] for c in CHANNELS], 0.27, label="output model (held-out)")
    ax.bar(x + 0.27, floor, 0.27, label="noise floor", color="0.7")
    ax.set_yscale("log")
    ax.set_xticks(x, CHANNELS)
    ax.set_ylabel("NRMSE")
    ax.set_title(f"Gap per channel - status: {result.status}")
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    literal_texts(fig).savefig(path, dpi=110)


def _save_stacked(fig: Figure, axes: Sequence[Any], path: Path) -> None:
    """Legend on the top axes, time axis on the bottom one, saved."""
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    literal_texts(fig).savefig(path, dpi=100)


def _fig_overlay(runs: Sequence[Run], result: DiscrepancyResult, path: Path) -> None:
    fig = Figure(figsize=(9, 10))
    axes = fig.subplots(len(CHANNELS), 1)
    names = [r.name for r in runs]
    for ax, c in zip(axes, CHANNELS):
        run_name, t0, t1, _ = result.diagnosis_before.channels[c].worst_stretch
        j = names.index(run_name) if run_name in names else 0
        run = runs[j]
        mid = 0.5 * (t0 + t1) if math.isfinite(t0) else 0.5 * run.n / run.fs_hz
        a = max(0, int((mid - 0.03) * run.fs_hz))
        b = min(run.n, int((mid + 0.03) * run.fs_hz))
        t = np.arange(a, b) / run.fs_hz
        ax.plot(t, run.channel(c)[a:b], ".", ms=2, color="k", label="measured")
        ax.plot(t, result.sims_before[j][c][a:b], lw=1.2, label="input model")
        ax.plot(t, result.sims_after[j][c][a:b], lw=1.2, ls="--", label="output model")
        ax.set_ylabel(f"{c} [{_UNITS[c]}]")
        ax.set_title(f"{run.name}, worst stretch of {c}", fontsize=9)
        ax.grid(True, alpha=0.3)
    _save_stacked(fig, axes, path)


def _fig_bode(runs: Sequence[Run], result: DiscrepancyResult, path: Path) -> None:
    fig = Figure(figsize=(14, 6))
    axes = fig.subplots(2, len(CHANNELS), sharex=True)
    markers = "os^vD<>"
    for j, run in enumerate(runs):
        before = bode_points(run, result.sims_before[j])
        after = bode_points(run, result.sims_after[j])
        f = before["frequency_hz"]
        order = np.argsort(f)
        f = f[order]
        for k, c in enumerate(CHANNELS):
            meas = before[c]["measured"][order]
            mb = before[c]["model"][order]
            ma = after[c]["model"][order]
            lab = lambda s: f"{s} ({run.name})"
            axes[0, k].plot(
                f,
                np.abs(meas),
                markers[j % len(markers)],
                ms=3,
                mfc="none",
                color="k",
                label=lab("measured"),
            )
            axes[0, k].plot(
                f,
                np.abs(mb),
                "-",
                lw=1,
                color="C0",
                alpha=0.8,
                label=lab("input model") if j == 0 else None,
            )
            axes[0, k].plot(
                f,
                np.abs(ma),
                "--",
                lw=1,
                color="C1",
                alpha=0.9,
                label=lab("output model") if j == 0 else None,
            )
            axes[1, k].plot(
                f,
                np.degrees(np.angle(meas)),
                markers[j % len(markers)],
                ms=3,
                mfc="none",
                color="k",
            )
            axes[1, k].plot(f, np.degrees(np.angle(mb)), "-", lw=1, color="C0", alpha=0.8)
            axes[1, k].plot(f, np.degrees(np.angle(ma)), "--", lw=1, color="C1", alpha=0.9)
    for k, c in enumerate(CHANNELS):
        axes[0, k].set_title(c, fontsize=9)
        axes[0, k].set_ylabel(f"|{c}/drive| [{_UNITS[c]}/V]", fontsize=8)
        axes[1, k].set_ylabel("phase vs drive [deg]", fontsize=8)
        axes[1, k].set_xlabel("drive frequency [Hz]")
        for ax in axes[:, k]:
            ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    literal_texts(fig).savefig(path, dpi=100)


def _fig_bands(result: DiscrepancyResult, path: Path) -> None:
    fig = Figure(figsize=(14, 3.2))
    axes = fig.subplots(1, len(CHANNELS))
    for ax, c in zip(axes, CHANNELS):
        b = result.diagnosis_before.channels[c].band_nrmse
        a = result.diagnosis_after.channels[c].band_nrmse
        labels = list(b)
        x = np.arange(len(labels))
        before = np.array([b[k] for k in labels], dtype=float)
        after = np.array([a.get(k, np.nan) for k in labels], dtype=float)
        ax.bar(x - 0.2, before, 0.4, label="input model")
        ax.bar(x + 0.2, after, 0.4, label="output model")
        ax.set_xticks(x, labels, rotation=60, fontsize=7)
        ax.set_title(f"{c}: model error by band", fontsize=9)
        ax.set_ylabel("model-error NRMSE", fontsize=8)
        ax.grid(True, axis="y", alpha=0.3)
        shown = np.concatenate([before, after])
        shown = shown[np.isfinite(shown) & (shown > 0)]
        if shown.size:  # log: the output model's error is often 100x below the input model's
            ax.set_yscale("log")
            ax.set_ylim(shown.min() / 2, shown.max() * 4)
            if np.any(np.concatenate([before, after]) == 0):
                ax.text(
                    0.98,
                    0.97,
                    "no bar: error at the noise",
                    ha="right",
                    va="top",
                    fontsize=7,
                    color="0.35",
                    transform=ax.transAxes,
                )
        else:
            ax.set_yticks([])
            ax.text(
                0.5,
                0.5,
                "no model error above the noise\nin any band",
                ha="center",
                va="center",
                fontsize=8,
                color="0.4",
                transform=ax.transAxes,
            )
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    literal_texts(fig).savefig(path, dpi=100)


def _fig_discovered(runs: Sequence[Run], result: DiscrepancyResult, index: int, path: Path) -> None:
    """Residual of the channel a discovered term closes, on the first three runs: without and with
    it.
    """
    d = result.discovered[index]
    c = d.channel
    without = replace(
        result.model_out, discovered=tuple(t for t in result.model_out.discovered if t != d.term)
    )
    runs = list(runs)[:3]
    before = simulate_runs([without], runs)[0]
    fig = Figure(figsize=(9, 2.2 * len(runs)))
    axes = np.atleast_1d(fig.subplots(len(runs), 1))
    for ax, run, b, a in zip(axes, runs, before, result.sims_after):
        t = np.arange(run.n) / run.fs_hz
        ax.plot(t, run.channel(c) - b[c], lw=0.6, label=f"without {d.term.feature_expression}")
        ax.plot(t, run.channel(c) - a[c], lw=0.6, label="with it")
        ax.set_ylabel(f"residual [{_UNITS[c]}]")
        ax.set_title(f"{run.name}: measured - model, {c}", fontsize=9)
        ax.grid(True, alpha=0.3)
    _save_stacked(fig, axes, path)


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
            }
        )
    return out


def write_figures(out_dir: Path, runs: Sequence[Run], result: DiscrepancyResult) -> dict[str, str]:
    """Write gap.png, overlay.png, bode.png, bands.png and discovered_K.png per discovered term;
    returns {figure: file name}.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    figs = {"gap": "gap.png", "overlay": "overlay.png", "bode": "bode.png", "bands": "bands.png"}
    for i in range(len(result.discovered)):
        figs[f"discovered_{i}"] = f"discovered_{i}.png"
        _fig_discovered(runs, result, i, out_dir / figs[f"discovered_{i}"])
    _fig_gap(result, out_dir / figs["gap"])
    _fig_overlay(runs, result, out_dir / figs["overlay"])
    _fig_bode(runs, result, out_dir / figs["bode"])
    _fig_bands(result, out_dir / figs["bands"])
    return figs


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
                for col, n in zip(table["columns"], counts)
            ],
        }
        for r, counts in zip(table["rows"], table["counts"])
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


def confusion_html(table: Mapping[str, Any], outcomes: Sequence[Mapping[str, Any]] = ()) -> str:
    """HTML of a confusion table (true vs found) and, if given, the per-case outcomes."""
    parts = _environment().get_template("discrepancy_parts.html.j2").module
    return str(parts.confusion(_confusion(table, outcomes)))


def _label_match(true: str, found: str) -> bool:
    from .datasets import expected_column

    return found == expected_column(true)


def _rules(s: Settings) -> dict[str, str]:
    """The decision rules' numbers, as the report states them."""
    return {
        "gap_noise_ratio": f"{s.gap_noise_ratio:g}",
        "whiteness_decimate": f"{s.whiteness_decimate}",
        "ljung_box_lags": f"{s.ljung_box_lags}",
        "whiteness_alpha": f"{s.whiteness_alpha:g}",
        "min_heldout_drop": f"{s.min_heldout_drop:.0%}",
        "max_delta_bic": f"{s.max_delta_bic:g}",
        "min_z": f"{s.min_z:g}",
        "consistency_alpha": f"{s.consistency_alpha:g}",
        "consistency_rel_tol": f"{s.consistency_rel_tol:.0%}",
        "max_effects_per_channel": f"{s.max_effects_per_channel}",
    }


def _context(
    runs: Sequence[Run],
    result: DiscrepancyResult,
    doc: Mapping[str, Any],
    figs: Mapping[str, str],
    settings: Settings,
    validation: Mapping[str, Any] | None,
) -> dict:
    """Everything report.html shows, as plain values for the template."""
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
    effects = None
    if result.effects:
        rows = []
        for e in result.effects:
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
    return {
        "status": result.status,
        "summary": result.summary,
        "model_out": str(doc.get("model_out")),
        "runs": [
            f"{r.name} ({r.n / r.fs_hz:.2f} s at {r.fs_hz:g} Hz, drive {r.drive_level_v:.0f} V)"
            for r in runs
        ],
        "gap": _table(
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
        ),
        "figs": figs,
        "plant": plant,
        "effects": effects,
        "remaining": remaining,
        "diagnosis": diagnosis,
        "searches": searches,
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
    settings: Settings = Settings(),
    validation: Mapping[str, Any] | None = None,
) -> dict:
    """Write discrepancy.json, the figures and report.html
    into `out_dir`; returns the JSON document.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = result_to_dict(result, model_out, settings)
    write_json(out_dir / "discrepancy.json", doc)
    figs = write_figures(out_dir, runs, result)
    page = (
        _environment()
        .get_template("discrepancy_report.html.j2")
        .render(_context(runs, result, doc, figs, settings, validation))
    )
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
