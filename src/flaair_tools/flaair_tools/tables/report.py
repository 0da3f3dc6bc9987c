"""Documents and the report of the table workflow (discrepancy.json, report.html and its
figures). A shell module: matplotlib and Jinja2 are imported here only.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Template
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from flaair_analysis.discrepancy.evidence_search import Judged, ParamFit
from flaair_analysis.tables.fit import PITCH_KEYS, STROKE_KEYS
from flaair_analysis.tables.reader import Table, summarise
from flaair_analysis.tables.steady_state import steady_response
from flaair_analysis.tables.workflow import NOT_SEARCHED, TableDiscrepancy
from flaair_common.strictjson import json_safe
from flaair_model.settings import TableSettings
from flaair_model.terms import DiscoveredTerm
from flaair_sensors.figures import literal_texts

__all__ = [
    "discrepancy_doc",
    "response_figure",
    "summary_line",
    "table_doc",
    "write_report",
]


def table_doc(table: Table) -> dict[str, Any]:
    """The table's summary: levels, frequencies, responses, the peak per level."""
    return {
        "name": table.name,
        "source": table.source,
        "points": table.n_points,
        "drive_levels_v": table.levels_v,
        "frequency_range_hz": [table.frequency_hz.min(), table.frequency_hz.max()],
        "responses": {c: int(np.isfinite(v).sum()) for c, v in table.responses.items()},
        "peaks": [s.__dict__ for s in summarise(table)],
    }


def _param_doc(fit: ParamFit, keys: Sequence[str]) -> dict[str, Any]:
    return {k.split(".")[-1]: {"value": fit.values[k], "stderr": fit.stderr[k]} for k in keys}


def _judged_doc(j: Judged) -> dict[str, Any]:
    keys = [p.key for p in j.candidate.params]
    return {
        "name": j.candidate.name,
        "side": j.candidate.side,
        "parameters": _param_doc(j.fit, keys),
        "heldout_drop": j.drop,
        "z": j.z,
        "failed": j.failed,
    }


def discrepancy_doc(result: TableDiscrepancy, table: Table) -> dict[str, Any]:
    """discrepancy.json of a table: status, effects, discovered, identification, gaps per column
    (NRMSE on held-out levels) before, identified and after, what was not searched and why.
    """
    effects, discovered = [], []
    for j in result.accepted:
        doc = _judged_doc(j)
        if j.candidate.is_term:
            kind, site = j.candidate.name.split("@")
            coef = doc["parameters"].popitem()[1]
            term = DiscoveredTerm(kind, site, coef["value"])
            discovered.append(
                {
                    "kind": kind,
                    "acts_on": site,
                    "expression": term.expression,
                    "words": term.row.words,
                    "examples": term.row.examples,
                    "parameters": {"coefficient": coef},
                    "heldout_drop": j.drop,
                    "z": j.z,
                    "hypothesis": "a term outside the vocabulary: a hypothesis for the lab to test",
                }
            )
        else:
            effects.append(doc)
    return {
        "input": "table",
        "status": result.status,
        "summary": summary_line(result),
        "effects": effects,
        "discovered": discovered,
        "identification": result.identification.as_dict(),
        "plant_parameters": {
            k: {
                "value": getattr(result.model_out.plant, k),
                "nominal": getattr(result.model_in.plant, k),
            }
            for k in (*STROKE_KEYS, *PITCH_KEYS)
        },
        "gap_before": result.gaps["gap_before"],
        "gap_identified": result.gaps["gap_identified"],
        "gap_after": result.gaps["gap_after"],
        "gap_measure": "NRMSE per response column on held-out drive levels (each level "
        "predicted by the model fitted on the others); gap_before: the model as given",
        "heldout_noise_ratio": result.noise_ratio,
        "searched": result.searched,
        "not_searched": NOT_SEARCHED,
        "candidates": [_judged_doc(j) for j in result.tried],
        "notes": result.notes,
        "table": table_doc(table),
    }


def summary_line(result: TableDiscrepancy) -> str:
    """One sentence: the status and what was found."""
    names = [j.candidate.name for j in result.accepted]
    if not result.searched:
        fits = (
            "the fitted plant fits it to noise"
            if result.status == "no_discrepancy"
            else "a gap is left in sample"
        )
        return (
            f"{result.status}: one drive level, so no level could be held out and the effects "
            f"search did not run (it needs two or more); {fits}"
        )
    if result.status == "no_discrepancy":
        return "no_discrepancy: the fitted plant predicts the held-out drive levels to noise"
    if result.status == "explained":
        return f"explained by {', '.join(names)} (judged on held-out drive levels)"
    found = f" after {', '.join(names)}" if names else ""
    return f"unexplained: a gap is left on held-out drive levels{found}"


def response_figure(result: TableDiscrepancy, table: Table, s: TableSettings, path: Path) -> None:
    """Amplitude against frequency, one colour per drive level: measured points, the model before
    (dotted), the fitted plant alone (dashed), the final model (solid), and each level's held-out
    prediction of the final model (crosses).
    """
    cols = [c for c in table.responses if "phase" not in c]
    fig = Figure(figsize=(11, 4.2 * len(cols)))
    FigureCanvasAgg(fig)
    dense = np.linspace(table.frequency_hz.min(), table.frequency_hz.max(), 60)
    levels = table.levels_v
    f = np.tile(dense, levels.size)
    a = np.repeat(levels, dense.size)
    bias = np.zeros_like(f)
    curves = steady_response([result.model_in, result.identified, result.model_out], f, a, bias, s)
    colours = [f"C{i}" for i in range(levels.size)]
    for row, c in enumerate(cols):
        ax = fig.add_subplot(len(cols), 1, row + 1)
        idx = table.level_index
        for i, level in enumerate(levels):
            sl = slice(i * dense.size, (i + 1) * dense.size)
            sel = idx == i
            col = colours[i]
            ax.plot(
                table.frequency_hz[sel],
                table.responses[c][sel],
                "o",
                color=col,
                label=f"{level:g} V measured",
            )
            ax.plot(dense, curves[c][0, sl], ":", color=col, lw=1)
            ax.plot(dense, curves[c][1, sl], "--", color=col, lw=1)
            ax.plot(dense, curves[c][2, sl], "-", color=col, lw=1.8)
            ax.plot(
                table.frequency_hz[sel], result.predictions["final"][c][sel], "x", color=col, ms=7
            )
        ax.plot([], [], "k:", label="model before")
        ax.plot([], [], "k--", label="fitted plant alone")
        ax.plot([], [], "k-", label="final model")
        ax.plot([], [], "kx", ls="", label="held-out prediction (level left out)")
        ax.set_xlabel("drive frequency (Hz)")
        ax.set_ylabel(c)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=2)
        ax.set_title(f"{c}: every drive level held out in turn")
    literal_texts(fig).tight_layout()  # literal before the layout draws a text
    fig.savefig(path, dpi=90)  # a table or robot name drawn as written


_PAGE = """<!doctype html><html><head><meta charset="utf-8"><title>{{ title }}</title>
<style>body{font-family:sans-serif;max-width:1150px;margin:1em auto;color:#222}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;
text-align:right}th{background:#eee}td:first-child{text-align:left}.st{font-size:1.3em}
.note{color:#a40}</style></head><body>
<h1>{{ title }}</h1>
<p class="st"><b>{{ doc.status }}</b> ({{ doc.summary }})</p>
<img src="table_response.png" style="width:100%">
<h2>Gap per response (NRMSE on held-out drive levels)</h2>
<table><tr><th>column</th><th>model before</th><th>fitted plant</th><th>final model</th></tr>
{% for c, v in doc.gap_before.items() %}<tr><td>{{ c }}</td><td>{{ fmt(v) }}</td>
<td>{{ fmt(doc.gap_identified[c]) }}</td><td>{{ fmt(doc.gap_after[c]) }}</td></tr>{% endfor %}
</table>
{% for e in doc.effects %}<h2>Effect: {{ e.name }}</h2><p>{% for k, p in e.parameters.items() %}
{{ k }} = {{ "%.4g"|format(p.value) }} &plusmn; {{ "%.2g"|format(p.stderr) }}; {% endfor %}
held-out error above noise {{ "%.0f"|format(100 * e.heldout_drop) }} % lower.</p>{% endfor %}
{% for t in doc.discovered %}<h2>Discovered term (hypothesis): {{ t.acts_on }} += {{ t.expression }}
</h2><p>{{ t.words }}, e.g. {{ t.examples }}. Held-out error above noise
{{ "%.0f"|format(100 * t.heldout_drop) }} % lower. {{ t.hypothesis }}.</p>{% endfor %}
<h2>Fitted plant</h2><table><tr><th>parameter</th><th>fitted</th><th>model</th><th>change</th></tr>
{% for k, p in doc.plant_parameters.items() %}<tr><td>{{ k }}</td><td>{{ "%.5g"|format(p.value) }}
</td><td>{{ "%.5g"|format(p.nominal) }}</td>
<td>{{ "%+.1f"|format(100 * (p.value / p.nominal - 1)) }} %</td></tr>{% endfor %}</table>
<h2>Candidates judged</h2><table><tr><th>candidate</th><th>held-out drop</th><th>z</th>
<th>rules</th></tr>{% for c in doc.candidates %}<tr><td>{{ c.name }}</td>
<td>{{ "%.0f"|format(100 * c.heldout_drop) }} %</td><td>{{ "%.1f"|format(c.z) }}</td>
<td style="text-align:left">{{ c.failed|join("; ") if c.failed else "passed every rule" }}</td>
</tr>{% endfor %}</table>
<h2>Not searched on a table</h2><table>{% for k, v in doc.not_searched.items() %}<tr><td>{{ k }}
</td><td style="text-align:left">{{ v }}</td></tr>{% endfor %}</table>
{% if doc.notes %}<h2>Notes</h2><ul>{% for n in doc.notes %}<li class="note">{{ n }}</li>
{% endfor %}</ul>{% endif %}
<p>Table {{ doc.table.name }} ({{ doc.table.source }}): {{ doc.table.points }} points,
drive levels {{ doc.table.drive_levels_v|join(", ") }} V.</p></body></html>
"""


def write_report(result: TableDiscrepancy, table: Table, s: TableSettings, out: Path) -> dict:
    """discrepancy.json, table_response.png and report.html into `out`; returns the document."""
    doc = json_safe(discrepancy_doc(result, table))
    (out / "discrepancy.json").write_text(json.dumps(doc, indent=2, allow_nan=False), "utf-8")
    response_figure(result, table, s, out / "table_response.png")

    def fmt(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    html = Template(_PAGE, autoescape=True).render(
        title=f"Discrepancy on table {table.name}", doc=doc, fmt=fmt
    )
    (out / "report.html").write_text(html, "utf-8")
    return doc
