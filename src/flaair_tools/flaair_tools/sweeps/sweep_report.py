"""The studies behind `bin/flaair sweep`: run, write
JSON/CSV, draw the figures, write the reading.
"""

from __future__ import annotations

import argparse
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure  # no pyplot: a notebook user's backend is left alone
from tqdm import tqdm

from flaair_analysis import wingbeat
from flaair_control.dsa_io import stroke_controller_values
from flaair_model.config import config_dir
from flaair_model.model_io import load_model
from flaair_sensors.frontend_io import frontend_values
from flaair_tools.sweeps import sweep


def _values() -> dict[str, Any]:
    return stroke_controller_values()


def _tasks_section(config: Path) -> dict[str, Any]:
    """The `tasks:` section of the sweeps file given, else of
    config/sweeps.yaml (a grid file need not repeat it).
    """
    try:
        return sweep.load_section(config, "tasks")
    except sweep.SweepError:
        default = config_dir() / "sweeps.yaml"
        if config.resolve() == default.resolve():
            raise
        return sweep.load_section(default, "tasks")


def run_study(args: argparse.Namespace, config: Path) -> int:
    """Dispatch one study (see flaair_tools.sweeps.sweep)."""
    if args.study == "stroke":
        return stroke_study(args, config)
    model = load_model()
    values = _values()
    key = {"wing-damage": "wing_damage", "dsa-map": "dsa_map"}[args.study]
    section = sweep.load_section(config, key)
    rows = (
        sweep.wing_damage_rows(section, values, model)
        if args.study == "wing-damage"
        else sweep.dsa_map_rows(section, values)
    )
    sizing = sweep.TaskSizing.from_mapping(_tasks_section(config))
    results, timing = sweep.execute(
        rows,
        sizing,
        model,
        scheduler=args.scheduler,
        workers=args.workers,
        in_process=args.in_process,
        show_progress=not args.no_progress,
    )
    document: dict[str, Any] = {"sweep": args.study, "config": section, "timing": timing}
    if args.study == "wing-damage":
        results = sweep.add_relative(results)
        wing_damage_figure(results, args.out / "wing_damage.png")
        text = wing_damage_reading(results, timing)
    else:
        results, onsets = sweep.add_theory(results, model, float(section["oscillating_deg"]))
        document["onsets"] = onsets
        dsa_map_figure(results, args.out / "dsa_map.png")
        text = dsa_map_reading(results, onsets, timing)
    document["rows"] = results
    sweep.write_json(args.out / "sweep.json", document)
    sweep.write_csv(args.out / "sweep.csv", results)
    (args.out / "reading.md").write_text(text)
    print(
        f"{len(results)} points, {timing['robot_seconds']:.0f} robot-s in {timing['wall_s']:.2f} "
        f"s ({timing['robot_seconds_per_s']:.0f} robot-s/s, {timing['engine']}); wrote "
        f"{args.out}/sweep.json, sweep.csv, *.png, reading.md"
    )
    return 0


# --------------------------------------------------------------------------- wing damage

_LABELS = {
    "sync_open_loop": "synchronous, open loop at the undamaged resonance",
    "dsa": "dSA self-excited",
    "dsa_stroke_control": "dSA + stroke-amplitude controller",
}
_FIGURES = (
    ("frequency_rel", "stroke frequency"),
    ("amplitude_rel", "stroke amplitude"),
    ("pitch_amplitude_rel", "pitch amplitude"),
    ("lift_rel", "lift proxy  A² f²"),
)


def wing_damage_figure(rows: list[dict[str, Any]], path: Path) -> None:
    """2 x 2 panels: each figure relative to the undamaged wing vs the inertia factor."""
    fig = Figure(figsize=(11, 8))
    axes = fig.subplots(2, 2, sharex=True)
    colors = {"sync_open_loop": "tab:gray", "dsa": "tab:blue", "dsa_stroke_control": "tab:red"}
    exponents = sorted({r["aero_damping_exponent"] for r in rows})
    styles = ["-", "--", ":", "-."]
    for ax, (key, title) in zip(axes.flat, _FIGURES, strict=True):
        for drive, color in colors.items():
            for exponent, style in zip(exponents, styles, strict=False):  # styles to spare
                sel = sorted(
                    (
                        r
                        for r in rows
                        if r["drive"] == drive and r["aero_damping_exponent"] == exponent
                    ),
                    key=lambda r: r["inertia_factor"],
                )
                ax.plot(
                    [r["inertia_factor"] for r in sel],
                    [r[key] for r in sel],
                    style,
                    color=color,
                    marker="o",
                    ms=3,
                    label=f"{_LABELS[drive]}, damping ∝ inertia^{exponent:g}",
                )
        ax.axhline(1.0, color="k", lw=0.5)
        ax.set_title(f"{title} / undamaged")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("wing inertia factor")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8)
    fig.suptitle("Wing damage: steady flapping relative to the undamaged wing")
    fig.tight_layout(rect=(0, 0.1, 1, 0.96))
    fig.savefig(path, dpi=110)


def _at(rows: list[dict[str, Any]], drive: str, factor: float, exponent: float) -> dict[str, Any]:
    return min(
        (r for r in rows if r["drive"] == drive and r["aero_damping_exponent"] == exponent),
        key=lambda r: abs(r["inertia_factor"] - factor),
    )


def wing_damage_reading(rows: list[dict[str, Any]], timing: dict[str, Any]) -> str:
    """What the sweep says about robust / adaptive / both, with the numbers."""
    low = min(r["inertia_factor"] for r in rows)
    exponents = sorted({r["aero_damping_exponent"] for r in rows})
    lines = [
        "# Wing damage: robust, adaptive, or both?",
        "",
        f"{len(rows)} points, "
        f"{timing['robot_seconds']:.0f} "
        "simulated robot-seconds "
        f"({timing['engine']}). Figures are "
        "steady values relative to the "
        "undamaged wing of the same drive; "
        "`sweep.json` holds every point.",
        "",
    ]
    for exponent in exponents:
        what = (
            "aerodynamic damping unchanged"
            if exponent == 0
            else f"aerodynamic damping x inertia_factor^{exponent:g}"
        )
        lines += [
            f"## {what}",
            "",
            "| drive | inertia | frequency | amplitude | pitch amplitude | lift proxy |",
            "|---|---|---|---|---|---|",
        ]
        for factor in (0.7, low):
            for drive in _LABELS:
                r = _at(rows, drive, factor, exponent)
                lines.append(
                    f"| {_LABELS[drive]} | {r['inertia_factor']:.2f} | "
                    f"{r['frequency_rel']:.3f} ({r['stroke_frequency_hz']:.1f} Hz) | "
                    f"{r['amplitude_rel']:.3f} ({r['stroke_amplitude_deg']:.2f} deg) | "
                    f"{r['pitch_amplitude_rel']:.3f} | {r['lift_rel']:.3f} |"
                )
        lines.append("")
    s, d, c = (_at(rows, k, 0.7, exponents[0]) for k in _LABELS)
    lines += [
        "## Reading",
        "",
        "* **Adaptive (frequency).** The dSA wing retunes itself: at 0.7 of its inertia it flaps "
        "at "
        f"{d['frequency_rel']:.3f}x its undamaged frequency ({d['stroke_frequency_hz']:.1f} Hz), "
        "close to the "
        f"sqrt(1/0.7) = {math.sqrt(1 / 0.7):.3f}x shift of its resonance, with no one telling it. "
        f"The synchronous drive cannot: it stays at {s['stroke_frequency_hz']:.1f} Hz, now off "
        "resonance.",
        "* **Robust (amplitude and lift) -- only partly, by itself.** Off resonance the "
        "synchronous wing's amplitude "
        f"falls to {s['amplitude_rel']:.3f}x and its lift proxy to {s['lift_rel']:.3f}x. The free "
        "dSA wing keeps "
        f"flapping but its amplitude moves to {d['amplitude_rel']:.3f}x (lift proxy "
        f"{d['lift_rel']:.3f}x): the "
        "limit cycle's amplitude depends on the inertia through the loop gain.",
        "* **Both, with the amplitude loop.** The dSA wing with the stroke controller holds the "
        "amplitude "
        f"({c['amplitude_rel']:.3f}x) while keeping the adapted frequency "
        f"({c['frequency_rel']:.3f}x), so its lift "
        f"proxy rises to {c['lift_rel']:.3f}x, the frequency gain squared.",
    ]
    if len(exponents) > 1:
        d1 = _at(rows, "dsa", 0.7, exponents[-1])
        lines.append(
            "* **If the lost inertia is lost area** (aerodynamic damping x "
            f"inertia_factor^{exponents[-1]:g}), the free dSA wing is nearly robust by "
            f"itself: amplitude {d1['amplitude_rel']:.3f}x, lift proxy "
            f"{d1['lift_rel']:.3f}x at 0.7 -- less damping lets the limit cycle grow "
            "back."
        )
    lines += [
        "",
        "So: asynchronous (dSA) flyers are *adaptive* -- the frequency follows the "
        "damaged wing's resonance; they are *robust* in amplitude only with the "
        "proprioceptive amplitude loop closed around them; with it they are both. (Ideal "
        "proprioception, steady state, lift proxy amplitude^2 x frequency^2: a screen "
        "for the real experiment, not a force measurement.)",
        "",
    ]
    return "\n".join(lines)


# --------------------------------------------------------------------------- dsa map


def dsa_map_figure(rows: list[dict[str, Any]], path: Path) -> None:
    """Amplitude and frequency vs mu per (r3, kappa), simulated
    (dots) and describing-function theory (lines).
    """
    r3s = sorted({r["r3_rad_s"] for r in rows})
    fig = Figure(figsize=(6 * len(r3s), 8))
    axes = fig.subplots(2, len(r3s), squeeze=False)
    for j, r3 in enumerate(r3s):
        for kappa, color in zip(  # colours to spare
            sorted({r["kappa"] for r in rows}),
            ("tab:blue", "tab:orange", "tab:green", "tab:red"),
            strict=False,
        ):
            sel = sorted(
                (r for r in rows if r["r3_rad_s"] == r3 and r["kappa"] == kappa),
                key=lambda r: r["mu_nm_s_per_rad"],
            )
            mu = np.array([r["mu_nm_s_per_rad"] for r in sel]) * 1e7
            axes[0, j].plot(
                mu,
                [r["stroke_amplitude_deg"] for r in sel],
                "o",
                color=color,
                label=f"κ = {kappa:g} simulated",
            )
            axes[0, j].plot(
                mu,
                [r["theory_amplitude_deg"] for r in sel],
                "-",
                color=color,
                label=f"κ = {kappa:g} theory",
            )
            osc = [r for r in sel if r["oscillating"]]
            axes[1, j].plot(
                np.array([r["mu_nm_s_per_rad"] for r in osc]) * 1e7,
                [r["stroke_frequency_hz"] for r in osc],
                "o",
                color=color,
            )
            axes[1, j].plot(
                mu,
                [r["theory_frequency_hz"] if r["theory_frequency_hz"] else np.nan for r in sel],
                "-",
                color=color,
            )
        axes[0, j].set_title(f"r3 = {r3:g} rad/s")
        axes[0, j].set_ylabel("stroke amplitude [deg]")
        axes[1, j].set_ylabel("emergent frequency [Hz]")
        axes[1, j].set_xlabel("mu [1e-7 N m s/rad]")
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
        axes[0, j].legend(fontsize=7)
    fig.suptitle(
        "dSA map: self-excited stroke vs mu, kappa, r3 (dots: simulation, lines: Hopf / "
        "describing function)"
    )
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=110)


def dsa_map_reading(
    rows: list[dict[str, Any]], onsets: list[dict[str, Any]], timing: dict[str, Any]
) -> str:
    """Onset boundary and theory agreement, with the numbers."""
    lines = [
        "# dSA parameter map",
        "",
        f"{len(rows)} points ({timing['engine']}).",
        "",
        "| r3 [rad/s] | kappa | theory onset mu* [N m s/rad] | at [Hz] | simulated onset "
        "between | consistent |",
        "|---|---|---|---|---|---|",
    ]
    for o in onsets:
        lo, hi = o["simulated_onset_between"]
        note = " (sqrt(kappa) r3 <= w_n: mu* = 0 at the resonance)" if o["degenerate"] else ""
        lines.append(
            f"| {o['r3_rad_s']:g} | {o['kappa']:g} | "
            f"{o['theory_onset_mu_nm_s_per_rad']:.3g}{note} | "
            f"{o['theory_onset_frequency_hz']:.1f} | {lo if lo is not None else '-'} .. "
            f"{hi if hi is not None else '-'} | "
            f"{ {True: 'yes', False: 'NO', None: 'n/a (mu* = 0)'}[o['onset_consistent']] } "
            "|"
        )
    osc = [r for r in rows if r["oscillating"] and r["amplitude_error_rel"] is not None]
    if osc:
        amp = np.array([abs(r["amplitude_error_rel"]) for r in osc])
        freq = np.array([abs(r["frequency_error_rel"]) for r in osc])
        clamped = sum(1 for r in rows if r["oscillating"] and r["drive_clamped"])
        lines += [
            "",
            f"Self-excited points within the drive clamp: {len(osc)} ({clamped} more hit "
            f"the {rows[0]['drive_limit_v']:g} V clamp, which the theory leaves out). "
            "Against the describing-function limit cycle "
            "(flaair_control.core.hopf.limit_cycle): amplitude error median "
            f"{100 * np.median(amp):.1f} %, worst {100 * amp.max():.1f} %; frequency "
            f"error median {100 * np.median(freq):.2f} %, worst {100 * freq.max():.2f} "
            "%.",
        ]
    lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------- stroke experiments


def stroke_study(args: argparse.Namespace, config: Path) -> int:
    """Run the three stroke experiments per mode, one bag each, analysed from the bags."""
    # deferred: the stroke study's ROS messages and bags (rclpy, rosbags: 0.3 s); the Dask
    # studies need none
    from flaair_tools.sweeps import stroke_experiments as se

    section = sweep.load_section(config, "stroke_experiments")
    values = _values()
    frontend_section = frontend_values()
    model = load_model()
    beats = wingbeat.WingbeatParams(
        float(values["sample_rate_hz"]),
        float(values["crossing_hysteresis_deg"]),
        float(values["min_wingbeat_hz"]),
        float(values["max_wingbeat_hz"]),
    )
    results = []
    bags = args.out / "bags"
    bags.mkdir(exist_ok=True)
    for exp in tqdm(
        se.experiments_from_config(section, args.mode),
        desc="stroke experiments",
        unit="run",
        disable=args.no_progress,
    ):
        bag = bags / exp.name
        if bag.exists():
            shutil.rmtree(bag)
        se.write_bag(bag, exp, se.run_closed_loop(exp, model, values, frontend_section))
        results.append(
            se.analyse_bag(
                bag, float(section["settle_band_deg"]), int(section["steady_wingbeats"]), beats
            )
        )
    stroke_figure(results, args.out / "stroke_experiments.png")
    sweep.write_json(
        args.out / "stroke.json",
        {
            "experiments": results,
            "targets": {"settling_wingbeats_max": 20, "steady_error_deg_max": 0.5},
        },
    )
    lines = [
        "# Stroke-amplitude controller on the simulated robot",
        "",
        "From the bags (estimate = what the controller holds; truth = the simulator's wing). "
        f"Settled: every later wingbeat within {section['settle_band_deg']} deg of the "
        "setpoint; steady error: "
        f"mean over the last {section['steady_wingbeats']} wingbeats. Targets: <= 20 "
        "wingbeats, |error| <= 0.5 deg.",
        "",
        "| run | settling [wingbeats] | steady error [deg] | truth: steady error [deg] | "
        "frequency [Hz] | max drive [V] |",
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        e = r["estimate"]
        lines.append(
            f"| {r['experiment']} | {e['settling_wingbeats']} | "
            f"{e['steady_error_deg']:+.3f} | {r['truth']['steady_error_deg']:+.3f} | "
            f"{e['steady_frequency_hz']:.1f} | {r['max_abs_drive_v']:.1f} |"
        )
    (args.out / "reading.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[6:]))
    return 0


def stroke_figure(results: list[dict[str, Any]], path: Path) -> None:
    """Per-wingbeat amplitude around the event, one panel per experiment."""
    names = sorted({r["experiment"].rsplit("_", 1)[0] for r in results})
    fig = Figure(figsize=(5 * len(names), 4))
    axes = fig.subplots(1, len(names), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        for r in (r for r in results if r["experiment"].rsplit("_", 1)[0] == name):
            for key, style in (("estimate", "-"), ("truth", ":")):
                ax.plot(
                    r[key]["wingbeat_time_s"],
                    r[key]["wingbeat_amplitude_deg"],
                    style,
                    marker="." if key == "estimate" else None,
                    label=f"{r['mode']} ({key})",
                )
            ax.axvline(r["event_s"], color="k", lw=0.5)
            ax.step(
                [0, r["event_s"], r[key]["wingbeat_time_s"][-1]],
                [r["setpoint_before_deg"], r["setpoint_after_deg"], r["setpoint_after_deg"]],
                where="post",
                color="k",
                lw=0.8,
                alpha=0.5,
            )
        ax.set_title(name.replace("_", " "))
        ax.set_xlabel("time [s]")
        ax.set_ylabel("stroke amplitude per wingbeat [deg]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
