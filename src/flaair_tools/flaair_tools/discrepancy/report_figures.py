"""The discrepancy report's figures (matplotlib `Figure`, no pyplot: a notebook user's backend is
left alone): the gap per channel, measured vs model overlays, the Bode comparison, the residual
bands and one figure per discovered term. `write_figures` writes them all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from flaair_analysis.discrepancy.diagnosis import bode_points
from flaair_analysis.discrepancy.runs import Run, simulate_runs
from flaair_analysis.discrepancy.vocabulary import CHANNELS
from flaair_analysis.discrepancy.workflow import DiscrepancyResult
from flaair_sensors.figures import literal_texts

__all__ = ["write_figures"]

_UNITS = {"stroke_deg": "deg", "pitch_deg": "deg", "stroke_sensor_v": "V", "pitch_sensor_v": "V"}


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
    literal_texts(fig).tight_layout()  # literal before the layout draws a text
    fig.savefig(path, dpi=110)


def _save_stacked(fig: Figure, axes: Sequence[Any], path: Path) -> None:
    """Legend on the top axes, time axis on the bottom one, saved."""
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    literal_texts(fig).tight_layout()  # literal before the layout draws a text
    fig.savefig(path, dpi=100)


def _fig_overlay(runs: Sequence[Run], result: DiscrepancyResult, path: Path) -> None:
    fig = Figure(figsize=(9, 10))
    axes = fig.subplots(len(CHANNELS), 1)
    names = [r.name for r in runs]
    for ax, c in zip(axes, CHANNELS, strict=True):
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
            axes[0, k].plot(
                f,
                np.abs(meas),
                markers[j % len(markers)],
                ms=3,
                mfc="none",
                color="k",
                label=f"measured ({run.name})",
            )
            axes[0, k].plot(
                f,
                np.abs(mb),
                "-",
                lw=1,
                color="C0",
                alpha=0.8,
                label=f"input model ({run.name})" if j == 0 else None,
            )
            axes[0, k].plot(
                f,
                np.abs(ma),
                "--",
                lw=1,
                color="C1",
                alpha=0.9,
                label=f"output model ({run.name})" if j == 0 else None,
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
    literal_texts(fig).tight_layout()  # literal before the layout draws a text
    fig.savefig(path, dpi=100)


def _fig_bands(result: DiscrepancyResult, path: Path) -> None:
    fig = Figure(figsize=(14, 3.2))
    axes = fig.subplots(1, len(CHANNELS))
    for ax, c in zip(axes, CHANNELS, strict=True):
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
    literal_texts(fig).tight_layout(rect=(0, 0, 1, 0.93))  # literal, then laid out
    fig.savefig(path, dpi=100)


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
    for ax, run, b, a in zip(axes, runs, before, result.sims_after[: len(runs)], strict=True):
        t = np.arange(run.n) / run.fs_hz
        ax.plot(t, run.channel(c) - b[c], lw=0.6, label=f"without {d.term.feature_expression}")
        ax.plot(t, run.channel(c) - a[c], lw=0.6, label="with it")
        ax.set_ylabel(f"residual [{_UNITS[c]}]")
        ax.set_title(f"{run.name}: measured - model, {c}", fontsize=9)
        ax.grid(True, alpha=0.3)
    _save_stacked(fig, axes, path)


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
