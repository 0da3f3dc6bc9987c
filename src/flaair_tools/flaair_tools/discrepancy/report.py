"""Discrepancy report: DIR/discrepancy.json, figures (matplotlib Agg) and DIR/report.html.

`write_report` writes everything for one analysis; `write_validation` writes the confusion table
of the hidden-effect datasets (validation.json, validation.html), which `write_report` can also
embed in report.html.
"""
from __future__ import annotations

import html
import json
import math
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .diagnosis import bode_points  # noqa: E402
from .runs import CHANNELS, Run  # noqa: E402
from .settings import Settings  # noqa: E402
from .workflow import DiscrepancyResult, format_parameters  # noqa: E402

__all__ = ["result_to_dict", "write_json", "write_figures", "write_report", "write_validation", "confusion_html"]

_UNITS = {"stroke_deg": "deg", "pitch_deg": "deg", "stroke_sensor_v": "V", "pitch_sensor_v": "V"}


def _clean(value: Any) -> Any:
    """JSON-safe copy: NaN/inf -> None, numpy scalars -> Python, tuples -> lists."""
    if isinstance(value, Mapping):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return [_clean(v) for v in value.tolist()]
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def result_to_dict(result: DiscrepancyResult, model_out: str, settings: Settings = Settings()) -> dict:
    """The discrepancy.json document.

    Keys: status, effects [{name, channel, parameters, evidence, explains}], gap_before,
    gap_after (held-out NRMSE per channel), model_out, plus gap_in_sample_after, noise_rms,
    remaining (where a gap is left), diagnosis before/after, searches, summary, runs, rules,
    plant_parameters {key: {value, nominal, stderr}}, identification (start values,
    correlations, inseparable combinations), not_separable [{effect, reason}], approximate
    (named effects that leave a gap where they act).
    """
    def diag(d: Any) -> dict:
        return {c: asdict(g) for c, g in d.channels.items()}

    searches = []
    for s in result.searches:
        searches.append({"channel": s.channel, "truth_referenced": s.truth_referenced, "skipped": s.skipped,
                         "steps": [[ev.as_dict() for ev in step] for step in s.steps]})
    doc = {
        "status": result.status,
        "effects": [{"name": e.name, "channel": e.channel, "parameters": e.parameters, "evidence": e.evidence,
                     "explains": list(e.explains)} for e in result.effects],
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
    }
    return _clean(doc)


def write_json(path: Path, doc: Any) -> None:
    """Write a JSON document (NaN/inf as null)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_clean(doc), indent=2), encoding="utf-8")


# ------------------------------------------------------------------------------------ figures


def _fig_gap(result: DiscrepancyResult, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(7, 3.6))
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
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fig_overlay(runs: Sequence[Run], result: DiscrepancyResult, path: Path) -> None:
    fig, axes = plt.subplots(len(CHANNELS), 1, figsize=(9, 10))
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
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fig_bode(runs: Sequence[Run], result: DiscrepancyResult, path: Path) -> None:
    fig, axes = plt.subplots(2, len(CHANNELS), figsize=(14, 6), sharex=True)
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
            lab = (lambda s: f"{s} ({run.name})")
            axes[0, k].plot(f, np.abs(meas), markers[j % len(markers)], ms=3, mfc="none", color="k",
                            label=lab("measured"))
            axes[0, k].plot(f, np.abs(mb), "-", lw=1, color="C0", alpha=0.8, label=lab("input model") if j == 0 else None)
            axes[0, k].plot(f, np.abs(ma), "--", lw=1, color="C1", alpha=0.9, label=lab("output model") if j == 0 else None)
            axes[1, k].plot(f, np.degrees(np.angle(meas)), markers[j % len(markers)], ms=3, mfc="none", color="k")
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
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fig_bands(result: DiscrepancyResult, path: Path) -> None:
    fig, axes = plt.subplots(1, len(CHANNELS), figsize=(14, 3.2))
    for ax, c in zip(axes, CHANNELS):
        b = result.diagnosis_before.channels[c].band_nrmse
        a = result.diagnosis_after.channels[c].band_nrmse
        labels = list(b)
        x = np.arange(len(labels))
        ax.bar(x - 0.2, [b[k] for k in labels], 0.4, label="input model")
        ax.bar(x + 0.2, [a.get(k, np.nan) for k in labels], 0.4, label="output model")
        ax.set_xticks(x, labels, rotation=60, fontsize=7)
        ax.set_title(f"{c}: model error by band", fontsize=9)
        ax.set_ylabel("model-error NRMSE", fontsize=8)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_figures(out_dir: Path, runs: Sequence[Run], result: DiscrepancyResult) -> dict[str, str]:
    """Write gap.png, overlay.png, bode.png and bands.png; returns {figure: file name}."""
    out_dir.mkdir(parents=True, exist_ok=True)
    figs = {"gap": "gap.png", "overlay": "overlay.png", "bode": "bode.png", "bands": "bands.png"}
    _fig_gap(result, out_dir / figs["gap"])
    _fig_overlay(runs, result, out_dir / figs["overlay"])
    _fig_bode(runs, result, out_dir / figs["bode"])
    _fig_bands(result, out_dir / figs["bands"])
    return figs


# --------------------------------------------------------------------------------------- HTML


def _f(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.{digits}g}" if math.isfinite(float(v)) else "-"
    return html.escape(str(v))


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c if isinstance(c, str) and c.startswith('<') else _f(c)}</td>"
                                    for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def confusion_html(table: Mapping[str, Any], outcomes: Sequence[Mapping[str, Any]] = ()) -> str:
    """HTML of a confusion table (true vs found) and, if given, the per-case outcomes."""
    rows = []
    for r, counts in zip(table["rows"], table["counts"]):
        cells = []
        for col, n in zip(table["columns"], counts):
            style = ""
            if n:
                style = ' class="ok"' if _label_match(r, col) else ' class="bad"'
            cells.append(f"<td{style}>{n or ''}</td>")
        rows.append(f"<tr><th>{html.escape(r)}</th>{''.join(cells)}</tr>")
    head = "".join(f"<th>{html.escape(c)}</th>" for c in table["columns"])
    out = (f"<p><b>{table['correct']} of {table['total']}</b> cases fully right (name, status, parameters within "
           f"15 %, gap reduced by at least half; outside cases: unexplained with the gap on the right channel). "
           "Row labels: <i>plant:</i> an effect a plant change reproduces (refitted, never named), <i>below:</i> an "
           "effect below the limit of the fitted-plant search (unexplained, nothing named).</p>"
           f"<table class='confusion'><tr><th>true \\ found</th>{head}</tr>{''.join(rows)}</table>")
    if outcomes:
        out += _table(["case", "true", "found", "status", "correct", "parameter errors", "gap reduction", "problems", "time s"],
                      [[o["case"], o["true"], o["found"], o["status"], o["correct"],
                        ", ".join(f"{k}: {v:.1%}" for k, v in (o.get("parameter_errors") or {}).items()),
                        ", ".join(f"{k}: {v:.0%}" for k, v in (o.get("gap_reduction") or {}).items()),
                        "; ".join(o.get("problems") or []), o.get("elapsed_s")] for o in outcomes])
    return out


def _label_match(true: str, found: str) -> bool:
    from .datasets import expected_column

    return found == expected_column(true)


_CSS = """
body{font-family:sans-serif;max-width:1250px;margin:auto;padding:1em;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1em 0;font-size:0.85em}
td,th{border:1px solid #bbb;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#eee} .ok{background:#cfc} .bad{background:#fcc} .status{font-size:1.3em;font-weight:bold}
img{max-width:100%} code{background:#f4f4f4}
"""


def _rules_html(settings: Settings) -> str:
    s = settings
    return f"""<ol>
<li><b>Gap</b>: a channel has a gap when its residual RMS exceeds {s.gap_noise_ratio:g}x the noise RMS (noise from
the median absolute second difference of the residual) AND the residual, decimated {s.whiteness_decimate}x, is not
white (Ljung-Box, {s.ljung_box_lags} lags, p &lt; {s.whiteness_alpha:g}).</li>
<li><b>Order</b>: stroke_deg (structural_damping, collision, wing_damage), pitch_deg (hinge_stiffening),
stroke_sensor_v (sensor_delay, charge_amp_highpass, feedthrough, transmission_nonlinearity, strain_transfer_loss),
pitch_sensor_v (sensor_delay, charge_amp_highpass, strain_transfer_loss). Physics is judged on the ground-truth
channels, which sensor effects cannot touch; sensors with the physics corrected (against the measured angle when the
truth above keeps a gap). A sensor effect of the other sensor is first tried on both sensors with no new parameter,
then with this sensor's own value. On a sensor with a gap, the runs' initial states are fitted again on the
truth and the sensors modelled so far (a video-rate truth leaves them loose).</li>
<li><b>Accept</b> an effect only if ALL hold: R1 the held-out model error of the channel (NRMSE above
noise) drops by more than {s.min_heldout_drop:.0%}; R2 held-out Delta-BIC &lt; {s.max_delta_bic:g}; R3 the parameter is more than {s.min_z:g}
standard errors from its null value and not stuck at a bound of its search range; R4 the per-run estimates (runs differ in drive level and time) agree: chi-square
p &ge; {s.consistency_alpha:g} with a {s.consistency_rel_tol:.0%} model-imperfection allowance, and at least two runs
identify the effect; R6 stroke physics judged on pitch_deg leaves stroke_deg without a gap. Held-out: each run is
predicted with the pooled estimate of the other runs. R5 (form, not acceptance): a sensor effect found on both
sensors becomes one value on both chains when the two estimates agree within 3 combined standard errors plus
{s.consistency_rel_tol:.0%}, else each chain keeps its own.</li>
<li><b>Choose</b> the passing candidate with the lowest held-out BIC; repeat on the channel (at most
{s.max_effects_per_channel}); if a gap is left, pairs of effects are fitted jointly and replace the greedy choice
when they pass all rules and predict held-out runs better.</li>
<li><b>Status</b>: no_discrepancy if no channel has a gap with the input model; explained if effects were added and
no gap is left; unexplained otherwise (where: channel, band, drive level, time stretch).</li>
</ol>"""


def _html(runs: Sequence[Run], result: DiscrepancyResult, doc: Mapping[str, Any], figs: Mapping[str, str],
          settings: Settings, validation: Optional[Mapping[str, Any]]) -> str:
    parts = [f"<html><head><meta charset='utf-8'><title>FLAAIR discrepancy report</title><style>{_CSS}</style></head><body>",
             "<h1>Model vs measurement</h1>",
             f"<p class='status'>Status: {html.escape(result.status)}</p><p>{html.escape(result.summary)}</p>",
             f"<p>Runs: {', '.join(html.escape(f'{r.name} ({r.n / r.fs_hz:.2f} s at {r.fs_hz:g} Hz, drive {r.drive_level_v:.0f} V)') for r in runs)}."
             f" Output model: <code>{html.escape(str(doc.get('model_out')))}</code></p>"]
    parts.append("<h2>Gap per channel (NRMSE on held-out runs)</h2>")
    parts.append(_table(["channel", "input model", "output model", "output model, in-sample", "noise floor", "noise RMS"],
                        [[c, result.gap_before[c], result.gap_after[c], result.gap_in_sample_after[c],
                          result.diagnosis_before.channels[c].noise_nrmse, result.noise[c]] for c in CHANNELS]))
    parts.append(f"<img src='{figs['gap']}'>")
    if result.plant_parameters:
        parts.append("<h2>This robot's plant (fitted first)</h2>")
        parts.append(_table(["parameter", "fitted", "model", "change", "standard error (identification)"],
                            [[k, p["value"], p["nominal"], f"{p['value'] / p['nominal'] - 1.0:+.2%}", p["stderr"]]
                             for k, p in result.plant_parameters.items()]))
        notes = list(result.plant_fit.inseparable) if result.plant_fit is not None else []
        notes += [f"{d['effect']} is not searched for: {d['reason']}" for d in result.not_separable]
        if notes:
            parts.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
    parts.append("<h2>Found effects</h2>")
    if result.effects:
        rows = []
        for e in result.effects:
            ev = e.evidence
            rules = ev.get("rules") or {}
            rows.append([e.name, e.channel, format_parameters(e.parameters),
                         ", ".join(ev.get("candidate", "").split("+")), ev.get("heldout_gap_drop"),
                         ev.get("delta_bic_heldout"), ", ".join(_f(z) for z in ev.get("z_from_null") or []),
                         ", ".join(_f(p) for p in ev.get("consistency_p") or []),
                         ", ".join(k for k, v in rules.items() if v), ", ".join(e.explains)])
        parts.append(_table(["effect", "found on", "parameters", "candidate", "held-out gap drop", "held-out dBIC",
                             "z from null", "consistency p", "rules passed", "can change"], rows))
    else:
        parts.append("<p>None.</p>")
    if result.remaining:
        parts.append("<h2>Where a gap remains</h2>")
        parts.append(_table(["channel", "worst band Hz", "full/low drive error ratio", "worst stretch", "model-error NRMSE", "reading"],
                            [[r["channel"], r["band_hz"], r["drive_level_ratio"],
                              f"{r['stretch'][0]} {r['stretch'][1]:.3f}-{r['stretch'][2]:.3f} s", r["model_error_nrmse"],
                              r["note"]] for r in result.remaining]))
    parts.append("<h2>Where the input model disagrees</h2>")
    for label, d in (("input model", result.diagnosis_before), ("output model", result.diagnosis_after)):
        rows = []
        for c in CHANNELS:
            g = d.channels[c]
            rows.append([c, g.has_gap, g.noise_ratio, g.ljung_box_p, g.xcorr_drive, g.worst_band_hz, g.level_ratio,
                         ", ".join(f"h{k}: {v:.0%}" for k, v in g.harmonic_fraction.items()),
                         f"{g.worst_stretch[0]} {g.worst_stretch[1]:.3f}-{g.worst_stretch[2]:.3f} s", g.interpretation])
        parts.append(f"<h3>{label}</h3>")
        parts.append(_table(["channel", "gap", "residual/noise", "Ljung-Box p", "xcorr with drive", "worst band Hz",
                             "full/low drive ratio", "harmonics of residual", "worst stretch", "reading"], rows))
    parts.append(f"<img src='{figs['bands']}'><img src='{figs['overlay']}'><img src='{figs['bode']}'>")
    parts.append("<h2>Search log</h2>")
    for s in result.searches:
        parts.append(f"<h3>{html.escape(s.channel)}{' (truth-referenced)' if s.truth_referenced else ''}</h3>")
        if s.skipped:
            parts.append(f"<p>Not searched: {html.escape(s.skipped)}.</p>")
            continue
        rows = []
        for i, step in enumerate(s.steps):
            for ev in step:
                rows.append([i, "+".join(ev.labels), ", ".join(_f(v) for v in ev.values), ev.heldout_gap_drop,
                             ev.delta_bic_heldout, ", ".join(_f(z) for z in ev.z),
                             ", ".join(_f(p) for p in ev.consistency_p),
                             "; ".join(" / ".join(f"{n}: {_f(v)}" for n, v, _ in pr) for pr in ev.per_run),
                             ", ".join(k for k, v in ev.rules.items() if not v) or "-",
                             f"<b>{'accepted' if ev.accepted else 'refused'}</b>"])
        parts.append(_table(["step", "candidate", "value", "held-out gap drop", "held-out dBIC", "z", "consistency p",
                             "per-run estimates", "failed rules", "verdict"], rows))
    parts.append("<h2>Decision rules</h2>" + _rules_html(settings))
    parts.append("<h2>Validation on the project's hidden-effect datasets</h2>")
    if validation:
        parts.append(confusion_html(validation["confusion"], validation.get("cases", ())))
    else:
        parts.append("<p>Not embedded; run <code>bin/flaair discrepancy --validate --out DIR</code> "
                     "(or pass <code>--validation DIR/validation.json</code>).</p>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(out_dir: Path, runs: Sequence[Run], result: DiscrepancyResult, model_out: str,
                 settings: Settings = Settings(), validation: Optional[Mapping[str, Any]] = None) -> dict:
    """Write discrepancy.json, the figures and report.html into `out_dir`; returns the JSON document."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = result_to_dict(result, model_out, settings)
    write_json(out_dir / "discrepancy.json", doc)
    figs = write_figures(out_dir, runs, result)
    (out_dir / "report.html").write_text(_html(runs, result, doc, figs, settings, validation), encoding="utf-8")
    return doc


def write_validation(out_dir: Path, outcomes: Sequence[Mapping[str, Any]], confusion: Mapping[str, Any],
                     total_s: float) -> dict:
    """Write validation.json and validation.html (confusion table of the dataset cases)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {"confusion": confusion, "cases": list(outcomes), "total_s": total_s}
    write_json(out_dir / "validation.json", doc)
    page = (f"<html><head><meta charset='utf-8'><title>FLAAIR discrepancy validation</title><style>{_CSS}</style>"
            f"</head><body><h1>Discrepancy workflow on the hidden-effect datasets</h1>"
            f"<p>{len(outcomes)} cases in {total_s:.0f} s.</p>{confusion_html(confusion, outcomes)}</body></html>")
    (out_dir / "validation.html").write_text(page, encoding="utf-8")
    return _clean(doc)
