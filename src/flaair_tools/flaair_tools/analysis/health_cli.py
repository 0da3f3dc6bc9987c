"""flaair health: the health monitor's core on recorded bags, offline.

Each bag's film voltages (/flaair/sensor_v) and the drive applied to the same samples
(/flaair/drive/applied, else /flaair/drive) go through `flaair_control.core.health.step` in
one call, the same function the health node runs block by block. DIR/health.json (strict JSON)
holds per bag the change `events` ({sample_index, time_s, parameter, ratio, stderr, wingbeat})
and the per-wingbeat series (estimates of wing_inertia, stroke_film_gain, pitch_film_gain,
actuator_gain as ratios to the model, each with its standard error; null where a wingbeat gave
no estimate) and the `baseline` the change test judged against at the end of the bag (null if none
was learned); DIR/health.png shows each estimate against time with the events marked.

A healthy run's health.json given with --baseline (or as health_node's baseline_file) is
judged against from the first wingbeat: a change before the run could learn its own baseline (a
damage during the K_r ramp, whose synchronous lead is too short to learn one) is reported.
How the monitor works: docs/HEALTH.md. Terms (K_r): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure  # no pyplot: a notebook user's backend is left alone

from flaair_common import topics
from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import OutputError, check_output, writing_outputs
from flaair_common.strictjson import json_safe
from flaair_control.core import change_test, health
from flaair_control.health_io import (
    baseline_dict,
    film_calibration,
    health_params_from_config,
    health_values,
)
from flaair_model.model_io import load_model
from flaair_model.validation import ModelError
from flaair_sensors.figures import literal_texts
from flaair_tools import bagio

DRIVE_TOPICS = (topics.DRIVE_APPLIED, topics.DRIVE)

OUT_FILES = ("health.json", "health.png")


class HealthInputError(ValueError):
    """A bag the monitor cannot read: the message names the bag and what is missing."""


def bag_inputs(bag: Path) -> tuple[float, np.ndarray, health.HealthInputs]:
    """(sample rate, sample indices, films and drive on the samples both streams hold)."""
    contents = bagio.read_bag(bag, [topics.SENSOR_VOLTAGE, *DRIVE_TOPICS])
    # the applied drive where the bag has any (a recorder may keep an advertised, silent topic)
    drive_topic = next((t for t in DRIVE_TOPICS if contents.has(t) and contents.raw.get(t)), None)
    missing = [
        name
        for name, ok in (
            (topics.SENSOR_VOLTAGE, contents.has(topics.SENSOR_VOLTAGE)),
            (" or ".join(DRIVE_TOPICS), drive_topic is not None),
        )
        if not ok
    ]
    if missing or drive_topic is None:
        raise HealthInputError(f"{bag}: no {' and no '.join(missing)}: films and drive needed")
    films = contents.blocks(topics.SENSOR_VOLTAGE)
    drive = contents.blocks(drive_topic)
    common, i_f, i_d = np.intersect1d(
        films.sample_index, drive.sample_index, assume_unique=True, return_indices=True
    )
    if common.size == 0:
        raise HealthInputError(f"{bag}: the films and {drive_topic} share no sample")
    inputs = health.HealthInputs(
        films["stroke_sensor_v"][i_f], films["pitch_sensor_v"][i_f], drive["drive_v"][i_d]
    )
    return films.sample_rate_hz, common, inputs


def run_bag(bag: Path, values: dict[str, Any], model_file: Path | None) -> dict[str, Any]:
    """The monitor on one bag: its events and per-wingbeat series, JSON-ready."""
    fs, index, inputs = bag_inputs(bag)
    values = {**values, "sample_rate_hz": fs}
    params = health_params_from_config(
        values, load_model(model_file or values["model_file"] or None)
    )
    end, out = health.step(health.initial_state(params), inputs, params)
    baseline = change_test.baseline_of(end.detector)
    offset = int(index[0])
    beats = out.wingbeats
    series: dict[str, Any] = {
        "wingbeat": [b.wingbeat for b in beats],
        "sample_index": [b.sample_index + offset for b in beats],
        "time_s": [(b.sample_index + offset) / fs for b in beats],
        "frequency_hz": [b.frequency_hz for b in beats],
    }
    for k, name in enumerate(health.PARAMETERS):
        series[name] = [b.estimate[k] for b in beats]
        series[f"{name}_stderr"] = [b.stderr[k] for b in beats]
    events = [
        {
            "sample_index": e.sample_index + offset,
            "time_s": (e.sample_index + offset) / fs,
            "parameter": e.parameter,
            "ratio": e.ratio,
            "stderr": e.stderr,
            "wingbeat": e.wingbeat,
            "alternatives": list(e.alternatives),
            "offset_deg": e.offset_deg,
        }
        for e in out.events
    ]
    estimated = sum(b.valid for b in beats)
    note = None
    if estimated == 0:
        note = "no estimate: the run is too short or too quiet (drive off or wing stalled)"
    elif params.baseline is None and not any(
        n.text.startswith(change_test.BASELINE_TEXT) for n in out.notes
    ):
        note = health.no_baseline_text(beats, params)
    return {
        "bag": str(bag),
        "events": events,
        "wingbeats": series,
        "estimated": estimated,
        "note": note,
        "baseline": None if baseline is None else baseline_dict(baseline, params),
        "baseline_given": params.baseline is not None,
    }


def _robust_limits(y: np.ndarray) -> tuple[float, float] | None:
    """Axis limits holding the estimates from their 2nd to their 98th percentile, padded: a
    transient wingbeat's wild estimate (the K_r ramp's) would otherwise flatten the trace and
    hide a change of a few per cent. None for too few estimates.
    """
    ok = y[np.isfinite(y)]
    if ok.size < 20:
        return None
    lo, hi = (float(v) for v in np.percentile(ok, [2.0, 98.0]))
    pad = max(0.15 * (hi - lo), 0.02 * max(abs(lo), abs(hi)), 1e-6)
    return lo - pad, hi + pad


def write_figure(results: list[dict[str, Any]], path: Path) -> None:
    """Each estimate against time, the events marked (one column of panels per bag)."""
    fig = Figure(figsize=(6.0 * len(results), 8.0))
    axes = fig.subplots(len(health.PARAMETERS), len(results), squeeze=False, sharex="col")
    for col, res in enumerate(results):
        s = res["wingbeats"]
        t = np.asarray(s["time_s"], dtype=float)
        for row, name in enumerate(health.PARAMETERS):
            ax = axes[row, col]
            y = np.asarray([np.nan if v is None else v for v in s[name]], dtype=float)
            e = np.asarray([np.nan if v is None else v for v in s[f"{name}_stderr"]], dtype=float)
            ax.plot(t, y, lw=0.8)
            ax.fill_between(t, y - 2 * e, y + 2 * e, alpha=0.3, lw=0)
            if (limits := _robust_limits(y)) is not None:
                ax.set_ylim(*limits)
                beyond = int(np.sum((y < limits[0]) | (y > limits[1])))
                if beyond:
                    ax.text(0.01, 0.95, f"{beyond} wingbeat(s) beyond the axis (transients)",
                            transform=ax.transAxes, fontsize=7, va="top", color="0.4")  # fmt: skip
            for ev in res["events"]:
                ax.axvline(ev["time_s"], color="r" if ev["parameter"] == name else "0.7", lw=0.8)
            ax.set_ylabel(f"{name}\n(x model)", fontsize=8)
            if row == 0:
                ax.set_title(Path(res["bag"]).name, fontsize=9)
        axes[-1, col].set_xlabel("time [s]")
    literal_texts(fig).tight_layout()  # literal before the layout draws a text
    fig.savefig(path, dpi=100)  # a bag's name drawn as written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="flaair health",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "bags", nargs="+", type=Path, help="bags with /flaair/sensor_v and /flaair/drive[/applied]"
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace existing outputs in --out")
    parser.add_argument(
        "--model",
        type=Path,
        default=None,
        help="model the estimates are ratios to "
        "(default: health_node's model_file, config/model.yaml)",
    )
    parser.add_argument(
        "--calibration",
        type=Path,
        default=None,
        help="a `bin/flaair calibrate` calibration.yaml: the films' lags (lag_s) are turned back "
        "before the estimate and the film gains are ratios to its gains (default: "
        "health_node's stroke/pitch_film_delay_s, the model's films)",
    )
    parser.add_argument(
        "--baseline",
        type=Path,
        default=None,
        metavar="HEALTH.json",
        help="the health.json of a healthy run of this robot (same model and calibration): its "
        "baseline is judged against from the first wingbeat (default: health_node's "
        "baseline_file, else each bag learns its own)",
    )
    args = parser.parse_args(argv)
    given = (args.model, args.calibration, args.baseline)
    inputs = [*args.bags, *(p for p in given if p is not None)]
    try:  # the outputs checked before anything is computed
        written = check_output(args.out, inputs, args.force, OUT_FILES)
        values = health_values()
        if args.calibration is not None:
            values["calibration_file"] = str(args.calibration)
            film_calibration(args.calibration)  # refused by its field before a bag is read
        if args.baseline is not None:
            values["baseline_file"] = str(args.baseline)
        if values["baseline_file"]:  # refused before a bag is read
            health_params_from_config(
                values, load_model(args.model or values["model_file"] or None)
            )
        results = [run_bag(bag, values, args.model) for bag in args.bags]
    except (bagio.BagError, HealthInputError, ModelError, ValueError, OSError) as exc:
        print(f"flaair health: {exc}", file=sys.stderr)
        return 2
    doc = {
        "events": [dict(ev, bag=r["bag"]) for r in results for ev in r["events"]],
        "bags": results,
    }
    try:
        with writing_outputs(args.out, written) as stage:
            text = json.dumps(json_safe(doc), indent=1, allow_nan=False)
            (stage / "health.json").write_text(text)
            write_figure(results, stage / "health.png")
    except OutputError as exc:
        print(f"flaair health: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("flaair health: interrupted; nothing written", file=sys.stderr)
        return 130
    for r in results:
        if r["note"]:
            print(f"flaair health: {r['bag']}: {r['note']}", file=sys.stderr)
        for ev in r["events"]:
            what = health.change_text(
                ev["parameter"], ev["ratio"], ev["stderr"], ev["offset_deg"], ev["alternatives"]
            )
            print(
                f"{r['bag']}: {what} at {ev['time_s']:.3f} s (sample {ev['sample_index']}, "
                f"wingbeat {ev['wingbeat']})"
            )
    n_events = len(doc["events"])
    print(f"wrote {args.out / 'health.json'} and {args.out / 'health.png'} ({n_events} event(s))")
    return 0
