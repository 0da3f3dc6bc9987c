r"""`flaair analyze BAG... --out DIR`: the paper's analysis of experiments and lab runs, from bags.

Every run's drive is recognised from the drive signal itself (chirp, stepped sine, single sine,
dSA transition, free run; flaair_tools.analysis.runkind) unless the bag says what it is (a FLAAIR
experiment, or `flaair import --kind`), and each gets its analysis, using the front-end
estimate against the ground truth on /flaair/wing_state/truth:
  chirp         Bode of sensor vs truth (paper Fig. Bode a), gains (deg/V), amplitude and phase
                RMSE, all-sample and lag-corrected time RMSE (paper, Sensor Performance)
  stepped sine  per-step amplitude and phase at each step's frequency -> Bode points (paper
                Fig. Bode b), and the same figures (the pitch headline figures come from here)
  sine          gain and phase at its one frequency, and the paper's collision metric
  collision     (the collision experiment) the metric with and without the obstacle, the
                monitor's onset/clearance times and its detection latency in wingbeats
  transition    stroke frequency and amplitude from the Hilbert transform (paper Fig. async)
  free          stroke frequency and amplitude of the sensor and the truth
Writes DIR/report.html (one self-contained file: summary first, figures embedded) and
DIR/report.json (every number; strict JSON, null where a figure is undefined), and the figures
as PNG files beside them.

Headline: each figure names the run it comes from. Of several bags holding a transition (the
paper's robot beside a damaged or altered one), the first given is the headline's, its note
naming the others; --headline-transition RUN chooses (a bag's path or directory name, its
experiment, or its transition run).

Gains: the sweep figures are "for this gain" (fitted against ground truth, as in the paper).
The estimate everything else uses comes from --calibration FILE (calibration.yaml written by
`flaair calibrate`), else from the live front end recorded in the bag, else from the model's
gains. On model gains, pitch reads ~4x small on a real robot (the model over-predicts the
hinge sensor ~4.3x): analyze then warns, and the report carries a banner.

Partial bags: a run holding less than its marker announced (a recovered bag, a run cut short)
or a recorded run missing altogether is reported with what is missing (runs, step
frequencies, sweep range). The exit code is then 3, unless --allow-partial is given (0).

Run CSV columns and units: docs/formats/MEASURED_RUN_CSV.md. Terms: docs/GLOSSARY.md.

Exit codes: 0 done; 2 bad input (bag, calibration file); 3 partial data without --allow-partial.

Example:
  bin/flaair analyze out/demo/bags/* --out out/demo/report \
      --calibration out/demo/calibration/calibration.yaml
"""

from __future__ import annotations

import argparse
import json
import signal as os_signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from flaair_analysis.headline import headline
from flaair_common import topics
from flaair_common.cli_help import HelpFormatter
from flaair_common.outputs import check_output, writing_outputs
from flaair_common.strictjson import json_safe
from flaair_model.config import ConfigError, load_yaml
from flaair_model.model_io import load_model
from flaair_sensors.analysis_io import analysis_bands_from_config, analysis_values
from flaair_sensors.core.bode import CharacterizationError
from flaair_sensors.core.frontend_params import (
    FrontendError,
    FrontendParams,
    params_from_calibration,
    params_from_model,
)
from flaair_sensors.frontend_io import frontend_tuning_from_config
from flaair_sim.core.drive import stepped_sine_frequencies_hz
from flaair_tools import bagio
from flaair_tools.analysis import diagnostic_events
from flaair_tools.analysis import report as html_report
from flaair_tools.analysis.per_run import (
    AnalysisError,
    analyze_collision,
    analyze_free,
    analyze_sine,
    analyze_sweep,
    analyze_transition,
    offline_estimate,
)
from flaair_tools.analysis.runkind import DriveKind, RecognitionParams, RunKindError, recognise
from flaair_tools.bagio.runs import RUN_TOPICS, Run, runs_of_bag

EXPERIMENT_TOPIC = "/flaair/experiment"
# Every topic the analysis reads (each bag is read once).
BAG_TOPICS = (
    *RUN_TOPICS,
    EXPERIMENT_TOPIC,
    topics.WING_STATE,
    topics.COLLISION_EVENTS,
    topics.CONTROLLER_STATE,
)
EXIT_BAD_INPUT = 2
EXIT_PARTIAL = 3
OUT_FILES = ("report.html", "report.json")
MODEL_GAINS_WARNING = (
    "the front end runs on the model's gains (no --calibration): the model over-predicts the hinge "
    "sensor ~4.3x on a real robot, so pitch reads ~4x small - the live pitch figures and the "
    "collision metric come out too small and a collision can be missed. The sweep figures use "
    "gains fitted against ground truth and are unaffected. Give --calibration FILE (from `flaair "
    "calibrate`)."
)
# The kind an experiment (config/experiments.yaml) gives each of its runs.
EXPERIMENT_RUN_KIND = {
    "chirp": "chirp",
    "stepped_sine": "stepped_sine",
    "collision": "sine",
    "transition": "transition",
}


def settings() -> tuple[RecognitionParams, dict[str, Any]]:
    """Drive recognition thresholds and the other analysis settings (config/flaair.yaml analyze)."""
    values = analysis_values()
    return RecognitionParams.from_mapping(values), values


def experiment_info(contents: bagio.BagContents) -> dict[str, Any]:
    """The experiment description recorded in the bag (empty for imported lab data)."""
    for message in contents.messages(EXPERIMENT_TOPIC)[:1]:
        return json.loads(message.data)
    return {}


# ----------------------------------------------------------------------------- estimates and gains


def load_calibration(path: Path) -> dict[str, Any]:
    """A calibration.yaml from `flaair calibrate`, checked; the error names the file and key."""
    try:
        calibration = load_yaml(path)
        params_from_calibration(calibration, 20000.0, **frontend_tuning_from_config())
    except (ConfigError, OSError, FrontendError, TypeError, ValueError) as exc:
        raise AnalysisError(f"--calibration {path}: {exc}") from None
    return calibration


def frontend_params(calibration: dict[str, Any] | None, fs_hz: float) -> FrontendParams:
    """The front end's parameters as the node would run them (config/flaair.yaml frontend_node)."""
    tuning = frontend_tuning_from_config()
    if calibration is not None:
        return params_from_calibration(calibration, fs_hz, **tuning)
    return params_from_model(load_model(), fs_hz, **tuning)


def _aligned_estimate(
    blocks: bagio.Blocks, sample_index: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    position = np.clip(
        np.searchsorted(blocks.sample_index, sample_index), 0, len(blocks.sample_index) - 1
    )
    found = blocks.sample_index[position] == sample_index
    stroke = np.where(
        found & blocks["stroke_valid"][position].astype(bool),
        np.radians(blocks["stroke_deg"][position]),
        np.nan,
    )
    pitch = np.where(
        found & blocks["pitch_valid"][position].astype(bool),
        np.radians(blocks["pitch_deg"][position]),
        np.nan,
    )
    return stroke, pitch


def run_sample_index(
    markers: dict[str, bagio.RunMarker], run: Run, blocks: bagio.Blocks
) -> np.ndarray:
    """Absolute sample indices of a run's samples (its marker's first index + time)."""
    first = (
        markers[run.name].first_sample_index if run.name in markers else int(blocks.sample_index[0])
    )
    return first + np.round(run["time_s"] * run.sample_rate_hz).astype(np.int64)


def live_runs_on_model_gains(live_pitch: np.ndarray, model_pitch: np.ndarray) -> bool:
    """True if the recorded live pitch is what the model's gains give (within 10 % in RMS)."""
    both = np.isfinite(live_pitch) & np.isfinite(model_pitch)
    if both.sum() < 100:
        return True
    ratio = np.sqrt(np.mean(live_pitch[both] ** 2) / max(np.mean(model_pitch[both] ** 2), 1e-30))
    return abs(ratio - 1.0) < 0.1


def estimates(
    contents: bagio.BagContents,
    runs: list[Run],
    calibration: dict[str, Any] | None,
    calibration_file: Path | None,
) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], str, bool]:
    """Front-end estimate of every run, where it came from, and whether it runs on model gains."""
    if calibration is not None:
        return (
            {
                run.name: offline_estimate(run, frontend_params(calibration, run.sample_rate_hz))
                for run in runs
            },
            "front-end core run offline on the recorded voltages with the "
            f"calibration {calibration_file}",
            False,
        )
    model_est = {
        run.name: offline_estimate(run, frontend_params(None, run.sample_rate_hz)) for run in runs
    }
    if not contents.has(topics.WING_STATE):
        return model_est, "front-end core run offline on the recorded voltages (model gains)", True
    blocks = contents.blocks(topics.WING_STATE)
    markers = {m.run: m for m in contents.run_markers()}
    live = {
        run.name: _aligned_estimate(blocks, run_sample_index(markers, run, blocks)) for run in runs
    }
    on_model = all(live_runs_on_model_gains(live[r.name][1], model_est[r.name][1]) for r in runs)
    return (
        live,
        "live front end (/flaair/wing_state)"
        + (", model gains" if on_model else ", calibrated gains"),
        on_model,
    )


# ----------------------------------------------------------------------------- per-run analyses


# ----------------------------------------------------------------------------- completeness


def completeness(
    info: dict[str, Any],
    runs: list[Run],
    missing_runs: list[str],
    kinds: dict[str, DriveKind],
    min_fraction: float,
    tolerance_hz: float,
) -> list[str]:
    """What a cut-short bag lacks: one sentence per missing
    run, short run, step frequency or sweep range.
    """
    notes = [f"run '{name}' is marked but has no samples in the bag" for name in missing_runs]
    expected_parts: dict[str, dict[str, Any]] = {}
    for spec in info.get("runs", []):
        for part in spec.get("markers") or [[spec["name"]]]:
            expected_parts[part[0]] = spec.get("drive", {})
    present = {run.name for run in runs} | set(missing_runs)
    notes += [
        f"run '{name}' of the experiment is not in the bag at all"
        for name in expected_parts
        if name not in present
    ]
    for run in runs:
        if run.fraction_present >= min_fraction:
            continue
        kind = kinds[run.name]
        note = (
            f"run '{run.name}' holds {run.fraction_present:.0%} of its marked samples "
            f"({run.n_samples / run.sample_rate_hz:.3g} of "
            f"{run.expected_n_samples / run.sample_rate_hz:.3g} s)"
        )
        drive = expected_parts.get(run.name, {})
        found = [s.frequency_hz for s in kind.steps]
        if drive.get("waveform") == "stepped_sine":
            wanted = stepped_sine_frequencies_hz(
                drive["start_hz"], drive["stop_hz"], drive["step_hz"]
            )
            lost = [f for f in wanted if not any(abs(f - g) <= tolerance_hz for g in found)]
            note += f"; steps missing: {', '.join(f'{f:g}' for f in lost)} Hz" if lost else ""
        elif drive.get("waveform") == "chirp" and kind.sweep_hz:
            note += (
                f"; sweep covered {kind.sweep_hz[0]:.0f}-{kind.sweep_hz[1]:.0f} Hz "
                f"of {drive['start_hz']:g}-{drive['stop_hz']:g} Hz"
            )
        elif kind.kind == "stepped_sine":
            note += (
                f"; steps found: {', '.join(f'{f:.4g}' for f in found)} Hz, "
                "the steps after them are missing"
            )
        elif kind.sweep_hz:
            note += (
                f"; drive seen {kind.sweep_hz[0]:.0f}-{kind.sweep_hz[1]:.0f} Hz, "
                "the rest of the run is missing"
            )
        notes.append(note)
    return notes


# ----------------------------------------------------------------------------- one bag


def run_kinds(
    contents: bagio.BagContents,
    runs: list[Run],
    info: dict[str, Any],
    explicit: dict[str, str],
    recognition: RecognitionParams,
) -> tuple[dict[str, DriveKind], list[str]]:
    """Every run's drive, recognised; an explicit kind (experiment
    or import --kind) wins, with a warning if they differ.
    """
    bag, has_controller = contents.info.path, contents.has(topics.CONTROLLER_STATE)
    kinds, warnings = {}, []
    for run in runs:
        drive = run["drive_v"] if "drive_v" in run else np.zeros(run.n_samples)
        found = recognise(
            drive, run.sample_rate_hz, recognition, has_controller_state=has_controller
        )
        wanted = explicit.get(run.name) or EXPERIMENT_RUN_KIND.get(info.get("kind", ""))
        if wanted and wanted != found.kind:
            warnings.append(
                f"{bag}: run '{run.name}' is marked '{wanted}' but its drive looks "
                f"like '{found.kind}' ({found.reason}); analysed as '{wanted}'"
            )
            if (wanted == "stepped_sine" and not found.steps) or (
                wanted == "sine" and not found.steps
            ):
                warnings[-1] += " without steps found: analysed as a sweep"
                wanted = "chirp"
            found = DriveKind(
                wanted,
                f"marked '{wanted}' in the bag; {found.reason}",
                found.steps,
                found.sweep_hz,
                found.drive_amplitude_v,
            )
        kinds[run.name] = found
    return kinds, warnings


def marker_values(contents: bagio.BagContents) -> dict[str, dict[str, Any]]:
    """Every run marker's JSON by run name: an explicit kind (`flaair import --kind`), and for a
    lab run its files, rig, sync and video (`flaair import RUN.mat`).
    """
    return {
        str(values["run"]): values
        for values in (
            json.loads(message.data) for message in contents.messages(bagio.RUN_MARKER_TOPIC)
        )
    }


def analyze_bag(
    bag: Path,
    reference_v: float,
    calibration: dict[str, Any] | None = None,
    calibration_file: Path | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Every number of one bag (see module docstring), and the data its figures are drawn from."""
    recognition, config = settings()
    contents = bagio.read_bag(bag, BAG_TOPICS)  # the bag is read once
    info = experiment_info(contents)
    missing_runs: list[tuple[str, str]] = []
    runs = runs_of_bag(contents, missing=missing_runs)
    markers = marker_values(contents)
    kinds, warnings = run_kinds(
        contents,
        runs,
        info,
        {name: str(m["kind"]) for name, m in markers.items() if m.get("kind")},
        recognition,
    )
    est, source, on_model = estimates(contents, runs, calibration, calibration_file)
    name = info.get("name", bag.name)
    result: dict[str, Any] = {
        "bag": str(bag),
        "experiment": name,
        "kind": info.get("kind", "lab runs"),
        "description": info.get("description", "runs imported from the lab"),
        "runs": {},
        "estimate_source": source,
        "model_gains": on_model,
        "warnings": warnings,
        "diagnostic_events": diagnostic_events.from_bag(bag),
    }
    result["missing"] = completeness(
        info,
        runs,
        [r for _, r in missing_runs],
        kinds,
        float(config["min_run_fraction"]),
        float(config["tolerance_hz"]),
    )
    plots: dict[str, Any] = {"bode": {}, "runs": {}}
    if info.get("kind") == "collision":
        result["collision"], plots["collision"] = analyze_collision(
            runs, est, info, contents, kinds
        )
        return result, plots
    if any(k.kind == "transition" for k in kinds.values()):
        result["transition"], plots["transition"] = analyze_transition(contents)
    for run in runs:
        kind = kinds[run.name]
        stroke_est, pitch_est = est[run.name]
        entry: dict[str, Any]
        try:
            if kind.kind in ("chirp", "unrecognised"):
                entry, plots["bode"][run.name] = analyze_sweep(
                    run, stroke_est, pitch_est, "chirp", None, reference_v
                )
            elif kind.kind == "stepped_sine":
                entry, plots["bode"][run.name] = analyze_sweep(
                    run,
                    stroke_est,
                    pitch_est,
                    "stepped",
                    kind.frequency_track(run.n_samples),
                    reference_v,
                )
            elif kind.kind == "sine":
                entry = analyze_sine(run, stroke_est, pitch_est, kind, reference_v)
            elif kind.kind == "free":
                entry = analyze_free(run, stroke_est)
            else:
                entry = {"method": "transition"}
        except CharacterizationError as exc:
            entry = {"method": kind.kind, "error": str(exc)}
            warnings.append(f"{bag}: run '{run.name}': {exc}")
        entry["drive"] = kind.as_dict()
        entry["fraction_present"] = run.fraction_present
        entry["drive_amplitude_v"] = kind.drive_amplitude_v
        if "video" in markers.get(run.name, {}):  # a lab run: the video's rate and coverage
            entry["video"] = markers[run.name]["video"]
        result["runs"][run.name] = entry
    return result, plots


# ----------------------------------------------------------------------------- top level


def analyze(
    bags: list[Path],
    out_dir: Path,
    *,
    progress: bool = True,
    calibration_file: Path | None = None,
    headline_transition: str | None = None,
) -> dict[str, Any]:
    """Analyse `bags` into out_dir (report.html, report.json, PNG figures); return the report.

    Parameters
    ----------
    bags
        Bag directories (FLAAIR experiments or `flaair import`ed lab runs).
    out_dir
        Report directory (created).
    progress
        Show a progress bar.
    calibration_file
        calibration.yaml from `flaair calibrate`; None: the live front end's or the model's gains.
    headline_transition
        The bag, experiment or run the transition headline comes from (None: the first bag
        holding a transition; the headline's note names it and the others).
    """
    calibration = load_calibration(calibration_file) if calibration_file is not None else None
    try:
        settings()
    except (ConfigError, RunKindError) as exc:
        raise AnalysisError(f"config/flaair.yaml analyze: {exc}") from None
    out_dir.mkdir(parents=True, exist_ok=True)
    reference_v = load_model().sensors.reference_voltage_v
    results, plots = [], []
    for bag in tqdm(bags, desc="analysing bags", unit="bag", disable=not progress):
        try:
            result, plot = analyze_bag(Path(bag), reference_v, calibration, calibration_file)
        except (bagio.BagError, CharacterizationError, KeyError) as exc:
            raise AnalysisError(str(exc) if str(bag) in str(exc) else f"{bag}: {exc}") from None
        results.append(result)
        plots.append(plot)
    report: dict[str, Any] = {
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "bags": results,
        "calibration_file": str(calibration_file) if calibration_file else None,
    }
    report["model_gains_warning"] = (
        MODEL_GAINS_WARNING if any(r["model_gains"] for r in results) else None
    )
    report["partial"] = [
        note for r in results for note in (f"{r['bag']}: {m}" for m in r["missing"])
    ]
    report["headline"] = headline(results, analysis_bands_from_config(), headline_transition)
    report["figures"] = html_report.write_figures(results, plots, out_dir)
    report = json_safe(report)
    (out_dir / "report.json").write_text(json.dumps(report, indent=1, allow_nan=False))
    html_report.write_html(report, out_dir)
    return report


def print_headline(report: dict[str, Any]) -> None:
    """The headline table on stdout."""
    print(f"{'figure':52s} {'FLAAIR':>10s} {'paper':>8s}  unit")
    for v in report["headline"].values():
        ours = "-" if v["flaair"] is None else f"{v['flaair']:.3g}"
        paper = "-" if v["paper"] is None else f"{v['paper']:.3g}"
        print(f"{v['label']:52s} {ours:>10s} {paper:>8s}  {v['unit']}  {v.get('note', '')}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="flaair analyze",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "bags",
        nargs="+",
        type=Path,
        help="bags recorded by `flaair experiment` or made by `flaair import`",
    )
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        help="report directory (report.html, report.json, figures)",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing report in --out")
    parser.add_argument(
        "--calibration",
        type=Path,
        default=None,
        metavar="FILE",
        help="calibration.yaml from `flaair calibrate`: the front end runs on "
        "these gains (default: the live front end's gains, else the model's, "
        "with a warning)",
    )
    parser.add_argument(
        "--allow-partial",
        action="store_true",
        help="exit 0 even when runs, steps "
        "or parts of a sweep are "
        "missing (recovered or "
        "cut-short bags); without it "
        "such a bag gives exit code 3 "
        "(the report is still "
        "written)",
    )
    parser.add_argument(
        "--headline-transition",
        metavar="RUN",
        help="the bag (path or directory name), experiment or run the headline's transition "
        "figures come from (default: the first bag holding a transition; the headline names it "
        "and any others)",
    )
    args = parser.parse_args(argv)
    os_signal.signal(os_signal.SIGTERM, lambda *_: sys.exit(130))
    try:  # the output checked before anything is computed; a failed run leaves no new --out
        written = check_output(args.out, [*args.bags, args.calibration], args.force, OUT_FILES)
        with writing_outputs(args.out, written) as stage:  # the report renamed in when whole
            report = analyze(
                args.bags,
                stage,
                calibration_file=args.calibration,
                headline_transition=args.headline_transition,
            )
    except (AnalysisError, bagio.BagError, ValueError, OSError, KeyboardInterrupt) as exc:
        interrupted = isinstance(exc, KeyboardInterrupt)
        print(f"flaair analyze: {'interrupted' if interrupted else exc}", file=sys.stderr)
        return 130 if interrupted else EXIT_BAD_INPUT
    for bag in report["bags"]:
        for warning in bag["warnings"]:
            print(f"flaair analyze: warning: {warning}", file=sys.stderr)
    if report["model_gains_warning"]:
        print(f"flaair analyze: WARNING: {report['model_gains_warning']}", file=sys.stderr)
    print_headline(report)
    print(f"report: {args.out / 'report.html'} (numbers in {args.out / 'report.json'})")
    if report["partial"]:
        for note in report["partial"]:
            print(f"flaair analyze: incomplete: {note}", file=sys.stderr)
        if not args.allow_partial:
            print(
                f"flaair analyze: {len(report['partial'])} part(s) of the data are missing "
                "(listed above); the figures cover only what is there. Pass --allow-partial to "
                "accept that (exit 0).",
                file=sys.stderr,
            )
            return EXIT_PARTIAL
        print("flaair analyze: --allow-partial: reporting on the data present", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
