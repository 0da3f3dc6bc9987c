"""report.html of `flaair multisine analyze`: the classic figure per channel (the BLA with its
noise and distortion standard deviations; the output's line powers at excited, odd and even
lines with the noise, the band levels and the model's lines), the design, the classes, the
disagreements and where they point. A shell module: matplotlib and Jinja2 are imported here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Template
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from flaair_analysis.multisine.analysis import ChannelSpectra
from flaair_sensors.figures import literal_texts

__all__ = ["channel_figure", "figure_file", "write_report"]


def figure_file(channel: str) -> str:
    """The PNG of one channel's figure."""
    return f"figure_{channel}.png"


def _db(x: np.ndarray) -> np.ndarray:
    return 10.0 * np.log10(np.maximum(x, 1e-30))


def channel_figure(
    name: str, entry: dict[str, Any], design: dict[str, Any], shown: ChannelSpectra, path: Path
) -> None:
    """(a) BLA magnitude, std_noise and std_nl in dB re 1 unit/V; (b) line powers and noise in
    dB re 1 unit^2 from 0 to 3 x the top excited line (where the channel's rate allows).
    """
    unit = entry["unit"]
    f0 = design["base_frequency_hz"]
    fig = Figure(figsize=(10, 7.4))
    FigureCanvasAgg(fig)
    ax_a, ax_b = fig.subplots(2, 1)
    bla = entry["bla"]
    f = np.array([b["freq_hz"] for b in bla])
    ax_a.plot(f, _db(np.array([b["mag"] for b in bla]) ** 2), "k.-", label="BLA |G|")
    ax_a.plot(f, _db(np.array([b["std_noise"] for b in bla]) ** 2), "g.", label="std_noise")
    if all(b["std_nl"] is not None for b in bla):
        ax_a.plot(f, _db(np.array([b["std_nl"] for b in bla]) ** 2), "r.", label="std_nl")
    ax_a.set_ylabel(f"dB re 1 {unit}/V")
    ax_a.set_xlabel("frequency (Hz)")
    ax_a.set_title(f"{name}: best linear approximation ({entry['class']})")
    ax_a.grid(alpha=0.3)
    ax_a.legend(fontsize=8, loc="lower left")
    excited = np.array(design["excited_lines"])
    top = min(3 * int(excited.max()), shown.power.size - 1)
    k = np.arange(1, top + 1)
    power, sigma2 = _db(shown.power[1 : top + 1]), _db(shown.sigma2[1 : top + 1])
    is_exc = np.isin(k, excited)
    is_odd = (k % 2 == 1) & ~is_exc
    is_even = k % 2 == 0
    if shown.model_power is not None:  # beneath the measured lines, open and larger
        model = _db(shown.model_power[1 : top + 1])
        ax_b.plot(k * f0, model, "o", mfc="none", color="tab:orange", ms=7, mew=0.8, label="model")
    ax_b.plot(k * f0, sigma2, "-", color="0.55", lw=0.8, label="noise sigma2")
    ax_b.plot(k[is_even] * f0, power[is_even], "b.", ms=4, label="even lines")
    ax_b.plot(k[is_odd] * f0, power[is_odd], "r.", ms=4, label="odd lines not excited")
    ax_b.plot(k[is_exc] * f0, power[is_exc], "k.", ms=5, label="excited lines")
    band = (excited.min() * f0, excited.max() * f0)
    styles = {"signal": "k", "noise": "0.5", "odd": "r", "even": "b"}
    for key, colour in styles.items():
        level = entry["levels_db"][key]
        if level is not None:
            ax_b.hlines(level, *band, colors=colour, linestyles="--", lw=1)
    floor = float(np.min(sigma2[np.isfinite(sigma2)])) if sigma2.size else -100.0
    ax_b.set_ylim(bottom=max(floor - 10.0, float(np.max(power)) - 160.0))
    ax_b.set_ylabel(f"dB re 1 {unit}^2")
    ax_b.set_xlabel("frequency (Hz); dashed: band levels (signal, noise, odd, even)")
    ax_b.set_title(f"{name}: output line powers")
    ax_b.grid(alpha=0.3)
    ax_b.legend(fontsize=8, loc="upper right", ncol=2)
    fig.subplots_adjust(left=0.08, right=0.98, top=0.96, bottom=0.07, hspace=0.32)
    literal_texts(fig).savefig(path, dpi=80)


_PAGE = """<!doctype html><html><head><meta charset="utf-8"><title>Multisine analysis</title>
<style>body{font-family:sans-serif;max-width:1000px;margin:1em auto;color:#222}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;
text-align:right}th{background:#eee}td:first-child{text-align:left}img{width:100%}
.dis{color:#a40;font-weight:bold}</style></head><body>
<h1>Multisine analysis: best linear approximation and nonlinear distortion</h1>
<p>Runs: {{ doc.runs|join(", ") }}. Model: {{ doc.model or "none" }}.</p>
<h2>Channels</h2>
<table><tr><th>channel</th><th>signal dB</th><th>noise dB</th><th>odd dB</th><th>even dB</th>
<th>class</th>{% if doc.model %}<th>model class</th><th>unexplained odd dB</th>
<th>unexplained even dB</th><th>disagrees</th>{% endif %}</tr>
{% for name, e in doc.channels.items() %}<tr><td>{{ name }} ({{ e.unit }})</td>
<td>{{ fmt(e.levels_db.signal) }}</td><td>{{ fmt(e.levels_db.noise) }}</td>
<td>{{ fmt(e.levels_db.odd) }}</td><td>{{ fmt(e.levels_db.even) }}</td><td>{{ e["class"] }}</td>
{% if doc.model %}<td>{{ e.model["class"] }}</td><td>{{ fmt(e.model.unexplained_db.odd) }}</td>
<td>{{ fmt(e.model.unexplained_db.even) }}</td>
<td class="dis">{{ e.disagrees|join(", ") or "-" }}</td>{% endif %}</tr>{% endfor %}</table>
<p>A distortion counts at the noise level + {{ doc.margin_db }} dB. Levels: mean line power over
the runs, dB re 1 unit&sup2;; odd and even include the noise.</p>
<h2>Where it points ({{ doc.localisation.basis }})</h2>
{% if doc.localisation.findings %}<ul>{% for f in doc.localisation.findings %}
<li><b>{{ f.distortion }}</b> on {{ f.channels|join(", ") }}: {{ f.points_to }}</li>{% endfor %}
</ul>{% else %}<p>No distortion to localise.</p>{% endif %}
{% for name, e in doc.channels.items() %}<h2>{{ name }}</h2>
<img src="{{ figure(name) }}" alt="{{ name }}">
<p>Class <b>{{ e["class"] }}</b> (signal {{ fmt(e.levels_db.signal) }}, noise
{{ fmt(e.levels_db.noise) }}, odd {{ fmt(e.levels_db.odd) }}, even {{ fmt(e.levels_db.even) }}
dB){% if doc.model %}; the model's class {{ e.model["class"] }}; disagrees:
{% if e.disagrees %}<span class="dis">{{ e.disagrees|join(", ") }}</span>{% else %}nothing
{%- endif %}{% endif %}.</p>
{% endfor %}
{% if doc.skipped %}<h2>Skipped channels</h2><table>{% for name, why in doc.skipped.items() %}
<tr><td>{{ name }}</td><td style="text-align:left">{{ why }}</td></tr>{% endfor %}</table>
{% endif %}
<h2>Design ({{ doc.design.source }})</h2>
<p>fs {{ doc.design.fs_hz }} Hz, period {{ doc.design.period_samples }} samples
(f0 {{ doc.design.base_frequency_hz }} Hz), band {{ doc.design.band_hz|join("-") }} Hz;
{{ doc.design.excited_lines|length }} excited lines, {{ doc.design.odd_detection_lines|length }}
odd detection lines, {{ doc.design.even_lines|length }} even lines;
{{ doc.design.transient_periods }} transient period(s) dropped, {{ doc.design.periods }}
periods x {{ doc.design.realizations }} realization(s) analysed.</p>
</body></html>
"""


def write_report(doc: dict[str, Any], spectra: dict[str, ChannelSpectra], out: Path) -> None:
    """One figure per analysed channel and report.html into `out`."""
    for name, entry in doc["channels"].items():
        channel_figure(name, entry, doc["design"], spectra[name], out / figure_file(name))

    def fmt(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    html = Template(_PAGE, autoescape=True).render(doc=doc, fmt=fmt, figure=figure_file)
    (out / "report.html").write_text(html, "utf-8")
