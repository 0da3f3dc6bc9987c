"""The analysis report: figures (PNG files) and one self-contained HTML file (Jinja2, autoescaped).

The HTML holds everything a reader needs to see, so it can be e-mailed alone: the summary first
(headline figures beside the paper's with labels and units, one verdict line per experiment),
warnings (model gains, missing data), then each experiment's text and figures, embedded as
base64 PNG. Every text, run names included, goes through Jinja2's autoescape; nothing is
passed through raw. The numbers stay in report.json beside it, linked.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Environment, FileSystemLoader, select_autoescape

from flaair_sensors.analysis_io import analysis_values
from flaair_tools.analysis.transition import plot_transition

TEMPLATES = Path(__file__).resolve().parents[1] / "templates"
TEMPLATE = "report.html.j2"
INSET_WINGBEATS = 3


def _environment() -> Environment:
    env = Environment(
        loader=FileSystemLoader(TEMPLATES),
        autoescape=select_autoescape(["html", "j2"]),
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["num"] = fmt
    return env


def fmt(value: Any, digits: int = 3) -> str:
    """A number for people: `digits` significant digits, '-' when undefined."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float)):
        return f"{value:.{digits}g}"
    return str(value)


def file_stem(text: str) -> str:
    """A file-name-safe form of a run or experiment name."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("._") or "run"


# ----------------------------------------------------------------------------- figures


def write_figures(
    results: list[dict[str, Any]], plots: list[dict[str, Any]], out_dir: Path
) -> list[dict[str, Any]]:
    """Draw every figure of the analysis as a PNG in out_dir; returns their descriptions.

    Each description: file, title, caption, experiment (the bag's experiment name). Per-run
    Bode figures are named in the run's entry ("figure").
    """
    # deferred: matplotlib (0.7 s); `analyze` imports this module, and its --help draws nothing
    from flaair_sensors.figures import (
        collision_fft_figure,
        overlaid_bode_figure,
        save_bode_figure,
        save_figure,
    )

    out: list[dict[str, Any]] = []
    sweeps: dict[str, Any] = {}
    for result, plot in zip(results, plots, strict=True):
        experiment = result["experiment"]
        for run_name, bode in plot.get("bode", {}).items():
            entry = result["runs"][run_name]
            path = out_dir / f"{file_stem(experiment)}_{file_stem(run_name)}_bode.png"
            save_bode_figure(
                path,
                bode,
                bode,
                title=f"{run_name}: sensor (fitted gains) vs ground truth",
                dpi=110,
            )
            entry["figure"] = path.name
            drive_vpp = 2 * entry["drive_amplitude_v"]
            sweeps[f"{run_name} ({drive_vpp:.0f} Vpp, {entry['method']})"] = bode
            out.append(
                {
                    "file": path.name,
                    "experiment": experiment,
                    "title": f"Bode of run {run_name}",
                    "caption": f"{run_name}: amplitude and "
                    "phase of the "
                    "sensor-derived angles "
                    "(fitted gains, blue) "
                    "against ground truth "
                    "(orange); "
                    f"{entry['method']} "
                    "analysis.",
                }
            )
        if "collision" in plot:
            path = out_dir / f"{file_stem(experiment)}_fft.png"
            save_figure(_collision_figure(plot["collision"], collision_fft_figure), path)
            result["collision"]["figure"] = path.name
            out.append(
                {
                    "file": path.name,
                    "experiment": experiment,
                    "title": "Collision: FFT of the sensor pitch",
                    "caption": "FFT of the sensor-derived pitch with the obstacle (blue) and "
                    "without (green) against a pure "
                    f"sine at the drive frequency (red); insets: {INSET_WINGBEATS} "
                    "wingbeats of each in time.",
                }
            )
        if "transition" in plot:
            record, hilbert, resonance_hz = plot["transition"]
            path = out_dir / f"{file_stem(experiment)}_transition.png"
            plot_transition(
                record,
                hilbert,
                path,
                resonance_hz=resonance_hz,
                title="Synchronous to asynchronous transition (recorded bag)",
            )
            result["transition"]["figure"] = path.name
            out.append(
                {
                    "file": path.name,
                    "experiment": experiment,
                    "title": "dSA transition",
                    "caption": "Stroke, its frequency and amplitude (Hilbert transform) and "
                    "K_r over the transition.",
                }
            )
    if len(sweeps) >= 2:
        path = out_dir / "sweeps_overlaid_bode.png"
        save_figure(overlaid_bode_figure(sweeps, title="Every sweep overlaid (drive levels)"), path)
        out.insert(
            0,
            {
                "file": path.name,
                "experiment": None,
                "title": "Bodes of every sweep, overlaid",
                "caption": "One colour per run "
                "(drive level): "
                "sensor-derived "
                "(solid) and ground "
                "truth (dashed).",
            },
        )
    return out


def _collision_figure(data: dict[str, Any], draw: Any) -> Any:
    drive_hz = data["frequency_hz"]
    spectra, insets, reference, axis = {}, {}, None, None
    for run_name, label in (("collision", "collision"), ("no_collision", "no collision")):
        if run_name not in data["runs"]:
            continue
        metric, pitch_deg, fs = data["runs"][run_name]
        axis, reference = metric.frequency_hz, np.degrees(metric.reference_spectrum_rad)
        spectra[label] = np.degrees(metric.signal_spectrum_rad)
        n = round(INSET_WINGBEATS * fs / drive_hz)
        tail = pitch_deg[-n:]
        insets[label] = (np.arange(tail.size) / fs * 1e3, tail)
    if axis is None:  # lab data without the two named parts: every run
        for run_name, (metric, _pitch_deg, _fs) in data["runs"].items():
            axis, reference = metric.frequency_hz, np.degrees(metric.reference_spectrum_rad)
            spectra[run_name] = np.degrees(metric.signal_spectrum_rad)
    return draw(axis, spectra, reference, drive_hz, insets)


# ----------------------------------------------------------------------------- text


def verdicts(report: dict[str, Any], factor: float) -> list[dict[str, str]]:
    """One line per experiment (bag): what it shows, and whether that matches the paper."""
    lines = []
    for bag in report["bags"]:
        lines.append(
            {
                "experiment": bag["experiment"],
                "text": _verdict(bag, report["headline"], factor),
                "ok": not bag["missing"] and not bag["warnings"],
            }
        )
    return lines


def _verdict(bag: dict[str, Any], headline: dict[str, Any], factor: float) -> str:
    parts = []
    if bag["missing"]:
        parts.append(f"INCOMPLETE ({len(bag['missing'])} part(s) missing); ")
    if "collision" in bag:
        c = bag["collision"]
        runs = c["runs"]
        if (
            "collision" in runs
            and "no_collision" in runs
            and "spectrum_rmse_deg" in runs["collision"]
        ):
            seen = runs["collision"]["collision"] and not runs["no_collision"]["collision"]
            parts.append(
                f"{'collision seen' if seen else 'collision NOT separated'}: metric "
                f"{fmt(runs['collision']['spectrum_rmse_deg'])} deg with the obstacle vs "
                f"{fmt(runs['no_collision']['spectrum_rmse_deg'])} deg without (threshold "
                f"{fmt(c['threshold_deg'])} deg; paper 3.23 vs 0.53)"
            )
        obstacle = c.get("obstacle")
        if obstacle:
            if obstacle["onset_s"] is None:
                parts.append("; the live monitor reported no onset")
            else:
                parts.append(
                    "; the live monitor saw it "
                    f"{fmt(obstacle['detection_latency_wingbeats'], 2)} wingbeats after "
                    "the first strike"
                )
        return "".join(parts) + "."
    if "transition" in bag:
        t = bag["transition"]
        parts.append(
            f"self-excited flapping settles at {fmt(t['final_frequency_hz'], 4)} Hz and "
            f"{fmt(t['final_amplitude_deg'])} deg stroke (stroke resonance "
            f"{fmt(t['resonance_hz'], 4)} Hz; the paper: slightly above resonance). "
        )
    kinds: dict[str, int] = {}
    for run in bag["runs"].values():
        kinds[run["drive"]["kind"]] = kinds.get(run["drive"]["kind"], 0) + 1
    if bag["runs"]:
        parts.append(
            ", ".join(
                f"{n} {kind.replace('_', ' ')} run{'s' if n > 1 else ''}"
                for kind, n in kinds.items()
            )
            + ": "
        )
    judged = []
    for name, run in bag["runs"].items():
        for channel, key in (
            ("stroke", "amplitude_rmse_deg"),
            ("pitch", "amplitude_rmse_band_deg"),
        ):
            value = run.get(channel, {}).get(key) if isinstance(run.get(channel), dict) else None
            paper = headline.get(f"{channel}_{key}", {}).get("paper")
            if value is not None and paper is not None and run["method"] in ("chirp", "stepped"):
                judged.append((name, channel, value, paper))
    if judged:
        worst = max(judged, key=lambda j: j[2] / j[3])
        ok = all(v <= factor * p for _, _, v, p in judged)
        parts.append(
            (
                "the sensors track the wing as well as the paper's"
                if ok
                else "tracking worse than the paper's"
            )
            + f" (worst: {worst[1]} amplitude "
            f"RMSE {fmt(worst[2])} deg in "
            f"{worst[0]}, paper "
            f"{fmt(worst[3])} deg)"
        )
    for name, run in bag["runs"].items():
        metric = run.get("collision_metric", {})
        if "spectrum_rmse_deg" in metric:
            parts.append(
                f"; {name} at {fmt(run['frequency_hz'], 4)} Hz: collision metric "
                f"{fmt(metric['spectrum_rmse_deg'])} deg "
                f"({'collision' if metric['collision'] else 'no collision'})"
            )
    return "".join(parts).rstrip(": ") + "."


def write_html(report: dict[str, Any], out_dir: Path, json_name: str = "report.json") -> Path:
    """DIR/report.html: one self-contained file (figures embedded), linking report.json."""
    factor = float(analysis_values()["verdict_rmse_factor"])
    images = {
        f["file"]: base64.b64encode((out_dir / f["file"]).read_bytes()).decode("ascii")
        for f in report["figures"]
        if (out_dir / f["file"]).exists()
    }
    html = (
        _environment()
        .get_template(TEMPLATE)
        .render(
            report=report,
            verdicts=verdicts(report, factor),
            images=images,
            json_name=json_name,
            factor=factor,
        )
    )
    path = out_dir / "report.html"
    path.write_text(html, encoding="utf-8")
    return path
