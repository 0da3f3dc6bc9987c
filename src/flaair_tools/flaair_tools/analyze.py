"""`flaair analyze BAG... --out DIR`: the paper's analysis of recorded experiments, from the bags.

For every bag (its experiment on /flaair/experiment, its runs on /flaair/run_marker), using the
live front-end estimate recorded on /flaair/wing_state against the ground truth on
/flaair/wing_state/truth:
  chirp         Bode of sensor vs truth (paper Fig. Bode a), gains (deg/V), amplitude and phase
                RMSE, all-sample and lag-corrected time RMSE (paper, Sensor Performance)
  stepped_sine  pitch Bode from steady-state stepped sines (paper Fig. Bode b) and the same figures
  collision     the paper's FFT metric: pitch spectrum vs a pure sine, with and without the
                obstacle (RMSE over 0-500 Hz and of the time data), plus the monitor's events
  transition    stroke frequency and amplitude from the Hilbert transform (paper Fig. async)
Writes DIR/report.json (every number) and DIR/report.html with PNG figures.

Example:
  bin/flaair analyze out/demo/bags/* --out out/demo/report
"""
from __future__ import annotations

import argparse
import html
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from flaair_common import topics
from flaair_sensors import characterization as ch
from flaair_sensors.calibration import CalibrationError, calibrate
from flaair_tools import bagio
from flaair_tools.runs import Run, load_runs

EXPERIMENT_TOPIC = "/flaair/experiment"
# The paper's published figures, for the side-by-side table (deg, deg/V).
PAPER = {
    "stroke_gain_deg_per_v": 25.5, "pitch_gain_deg_per_v": 108.0,
    "stroke_amplitude_rmse_deg": 0.44, "pitch_amplitude_rmse_deg": 4.04, "pitch_amplitude_rmse_band_deg": 2.44,
    "pitch_time_rmse_deg": 8.20, "pitch_time_rmse_lag_corrected_deg": 4.44, "pitch_time_rmse_lag_corrected_band_deg": 3.93,
    "stroke_phase_rmse_deg": 9.69, "pitch_phase_rmse_deg": 14.41,
    "collision_spectrum_rmse_deg": 3.23, "no_collision_spectrum_rmse_deg": 0.53,
    "collision_time_rmse_deg": 15.81, "no_collision_time_rmse_deg": 3.34,
}


class AnalysisError(ValueError):
    """A bag cannot be analysed; the message names the bag, run or topic."""


def experiment_info(bag: Path) -> dict[str, Any]:
    """The experiment description recorded in the bag (empty for imported lab data)."""
    if EXPERIMENT_TOPIC not in bagio.bag_info(bag).topics:
        return {}
    for _, _, message in bagio.iter_messages(bag, [EXPERIMENT_TOPIC]):
        return json.loads(message.data)
    return {}


def _aligned_estimate(blocks: bagio.Blocks, sample_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    position = np.searchsorted(blocks.sample_index, sample_index)
    position = np.clip(position, 0, len(blocks.sample_index) - 1)
    found = blocks.sample_index[position] == sample_index
    stroke = np.where(found & blocks["stroke_valid"][position].astype(bool), np.radians(blocks["stroke_deg"][position]), np.nan)
    pitch = np.where(found & blocks["pitch_valid"][position].astype(bool), np.radians(blocks["pitch_deg"][position]), np.nan)
    return stroke, pitch


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def _sweep_figures(run: Run, stroke_est: np.ndarray, pitch_est: np.ndarray, method: str,
                   frequency_track: np.ndarray | None) -> tuple[ch.Bode, dict[str, Any]]:
    fs = run.sample_rate_hz
    drive = run["drive_v"]
    stroke_t, pitch_t = np.radians(run["stroke_deg"]), np.radians(run["pitch_deg"])
    if method == "chirp":
        bode = ch.bode_from_chirp(drive, stroke_est, pitch_est, stroke_t, pitch_t, fs, frequency_hz_per_sample=frequency_track)
    else:
        bode = ch.bode_from_stepped(drive, stroke_est, pitch_est, stroke_t, pitch_t, fs, frequency_track)
    result = ch.characterize(bode, drive, stroke_est, pitch_est, stroke_t, pitch_t, fs, frequency_track)
    figures = {name: {k: (_finite(v) if isinstance(v, float) else v) for k, v in metrics.__dict__.items()}
               for name, metrics in (("stroke", result.stroke), ("pitch", result.pitch))}
    return bode, figures


def analyze_sweep(run: Run, stroke_est: np.ndarray, pitch_est: np.ndarray, method: str,
                  frequency_track: np.ndarray | None, reference_v: float, figure: Path) -> dict[str, Any]:
    """Gains, Bode and the paper's RMSE figures of one chirp or stepped-sine run.

    As the paper does, the gain of each sensor is fitted against ground truth first and the
    RMSE figures are "for this gain": the front-end core runs offline on the recorded
    voltages with the fitted gains (`stroke`, `pitch`). The figures of the live estimate as
    recorded (the front end's own gains) are kept beside them (`live`).
    """
    from flaair_sensors import frontend
    from flaair_sensors.figures import save_bode_figure

    fs = run.sample_rate_hz
    out: dict[str, Any] = {"method": method}
    live_bode, out["live"] = _sweep_figures(run, stroke_est, pitch_est, method, frequency_track)
    try:
        gains = calibrate(run.columns, reference_v, sample_rate_hz=fs, frequency_hz_per_sample=frequency_track)
    except CalibrationError as exc:
        out["gain_error"] = str(exc)
        out.update(stroke=out["live"]["stroke"], pitch=out["live"]["pitch"])
        bode = live_bode
    else:
        # Fitted gain and offset only: the lag stays in the estimate, as the paper reports it.
        params = frontend.params_from_calibration(gains, fs, compensate_lag=False)
        est = frontend.estimate(run["stroke_sensor_v"], run["pitch_sensor_v"], params)
        bode, calibrated = _sweep_figures(run, np.where(est.stroke_valid, est.stroke_rad, np.nan),
                                          np.where(est.pitch_valid, est.pitch_rad, np.nan), method, frequency_track)
        for name in ("stroke", "pitch"):
            calibrated[name]["gain_deg_per_v"] = gains[name]["gain_deg_per_v"]
            calibrated[name]["sensor_lag_s"] = gains[name]["lag_s"]
            out[name] = calibrated[name]
    save_bode_figure(figure, bode, bode, title=f"{run.name}: sensor (fitted gains) vs ground truth")
    out["figure"] = figure.name
    out["bode"] = {name: {k: np.asarray(v).tolist() for k, v in getattr(bode, name).__dict__.items()
                          if isinstance(v, np.ndarray)} for name in ("stroke", "pitch")}
    return out


def stepped_track(info: dict[str, Any], run_name: str, n: int, fs: float, drive_v: np.ndarray) -> np.ndarray:
    """Drive frequency per sample of a stepped-sine run, from the drive parameters in the bag."""
    from flaair_sim.drive import stepped_sine, stepped_sine_frequencies_hz

    for spec in info.get("runs", []):
        if spec["name"] == run_name:
            d = spec["drive"]
            freqs = stepped_sine_frequencies_hz(d["start_hz"], d["stop_hz"], d["step_hz"])
            _, track = stepped_sine(fs, d["amplitude_v"], freqs, d["dwell_s"])
            return np.resize(track, n) if len(track) >= n else np.concatenate([track, np.zeros(n - len(track))])
    return ch.frequency_track_from_drive(drive_v, fs)[1]


def analyze_collision(runs: list[Run], estimates: dict[str, tuple[np.ndarray, np.ndarray]], info: dict[str, Any],
                      bag: Path, figure: Path) -> dict[str, Any]:
    """The paper's collision metric per run, the monitor's events, and the FFT figure."""
    import matplotlib.pyplot as plt

    from flaair_control.collision import spectral_metric

    frequency_hz = float(info["runs"][0]["drive"]["frequency_hz"]) if info.get("runs") else \
        float(np.median(ch.frequency_track_from_drive(runs[0]["drive_v"], runs[0].sample_rate_hz)[1]))
    out: dict[str, Any] = {"drive_frequency_hz": frequency_hz, "runs": {}}
    fig, ax = plt.subplots(figsize=(7, 4))
    reference_drawn = False
    for run in runs:
        pitch = estimates[run.name][1]
        valid = pitch[np.isfinite(pitch)]
        metric = spectral_metric(valid, run.sample_rate_hz, frequency_hz)
        out["runs"][run.name] = {"spectrum_rmse_deg": metric.spectral_rmse_deg, "time_rmse_deg": metric.time_rmse_deg,
                                 "collision": bool(metric.collision)}
        ax.plot(metric.frequency_hz, np.degrees(metric.signal_spectrum_rad), label=f"sensor pitch: {run.name}")
        if not reference_drawn:
            ax.plot(metric.frequency_hz, np.degrees(metric.reference_spectrum_rad), "r--", label=f"pure {frequency_hz:g} Hz sine")
            reference_drawn = True
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("pitch amplitude [deg]")
    ax.set_xlim(0, 500)
    ax.legend()
    ax.set_title("Collision: FFT of sensor-derived pitch (paper Fig. collisions b)")
    fig.tight_layout()
    fig.savefig(figure, dpi=120)
    plt.close(fig)
    out["figure"] = figure.name
    events = []
    if topics.COLLISION_EVENTS in bagio.bag_info(bag).topics:
        for _, _, message in bagio.iter_messages(bag, [topics.COLLISION_EVENTS]):
            events.append({"kind": "onset" if message.kind == 1 else "clearance", "wingbeat_index": int(message.wingbeat_index),
                           "time_s": message.header.stamp.sec + message.header.stamp.nanosec * 1e-9})
    out["events"] = events
    return out


def analyze_transition(bag: Path, figure: Path, final_window_s: float = 0.5) -> dict[str, Any]:
    """Sync-to-async transition: stroke frequency and amplitude from the Hilbert transform.

    The recorded sensor-derived stroke is band-passed, Hilbert-transformed and smoothed by a
    Savitzky-Golay filter (paper); K_r comes from the recorded controller state.
    """
    from flaair_control import transition as tr
    from flaair_control.transition_figure import TransitionRecord, plot_transition
    from flaair_model.model_io import load_model

    wing = bagio.read_blocks(bag, topics.WING_STATE)
    fs = float(wing.sample_rate_hz)
    stroke_deg = np.where(wing["stroke_valid"].astype(bool), wing["stroke_deg"], np.nan)
    time_s = wing.sample_index / fs
    states = [m for _, _, m in bagio.iter_messages(bag, [topics.CONTROLLER_STATE])]
    if not states:
        raise AnalysisError(f"{bag}: no {topics.CONTROLLER_STATE} messages (was the controller running?)")
    kr_time_s = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in states])
    record = TransitionRecord(time_s, stroke_deg, kr_time_s, np.array([m.k_r for m in states]),
                              np.array([m.stroke_frequency_hz for m in states]), np.array([m.drive_v for m in states]), 0)
    result = tr.hilbert_analysis(stroke_deg, fs, start_time_s=float(time_s[0]))
    resonance_hz = load_model().plant.stroke_natural_frequency_hz
    plot_transition(record, result, figure, resonance_hz=resonance_hz,
                    title="Synchronous to asynchronous transition (recorded bag)")
    end_s = float(time_s[-1])
    final = tr.window_stats(result.time_s, result.frequency_hz, end_s - final_window_s, end_s)
    final_amplitude = tr.window_stats(result.time_s, result.amplitude, end_s - final_window_s, end_s)
    ramp_start = float(kr_time_s[np.argmax(record.kr < record.kr[0] - 1e-9)]) if (record.kr < record.kr[0] - 1e-9).any() else end_s
    initial = tr.window_stats(result.time_s, result.frequency_hz, float(time_s[0]), ramp_start)
    return {
        "figure": figure.name,
        "resonance_hz": resonance_hz,
        "initial_frequency_hz": _finite(initial.mean),
        "final_frequency_hz": _finite(final.mean),
        "final_frequency_spread_hz": _finite(final.std),
        "final_amplitude_deg": _finite(final_amplitude.mean),
        "final_amplitude_spread_deg": _finite(final_amplitude.std),
        "final_k_r": float(record.kr[-1]),
    }


def analyze_bag(bag: Path, out_dir: Path, reference_v: float) -> dict[str, Any]:
    """Every number of one bag (see module docstring)."""
    info = experiment_info(bag)
    kind = info.get("kind", "chirp")
    runs = load_runs([bag])
    live = topics.WING_STATE in bagio.bag_info(bag).topics
    estimates = {}
    if live:
        estimate_blocks = bagio.read_blocks(bag, topics.WING_STATE)
        for run in runs:
            estimates[run.name] = _aligned_estimate(estimate_blocks, run_sample_index(bag, run, estimate_blocks))
    else:
        # Lab data carries no live estimate: run the same front-end core offline on the voltages.
        from flaair_sensors import frontend
        from flaair_model.model_io import load_model

        model = load_model()
        for run in runs:
            params = frontend.params_from_model(model, run.sample_rate_hz)
            est = frontend.estimate(run["stroke_sensor_v"], run["pitch_sensor_v"], params)
            estimates[run.name] = (np.where(est.stroke_valid, est.stroke_rad, np.nan), np.where(est.pitch_valid, est.pitch_rad, np.nan))
    result: dict[str, Any] = {"bag": str(bag), "experiment": info.get("name", bag.name), "kind": kind, "runs": {},
                              "estimate_source": "live front end (/flaair/wing_state)" if live else
                              "front-end core run offline on the recorded voltages (model gains)"}
    stem = info.get("name", bag.name)
    if kind == "collision":
        result["collision"] = analyze_collision(runs, estimates, info, bag, out_dir / f"{stem}_fft.png")
        return result
    if kind == "transition":
        result["transition"] = analyze_transition(bag, out_dir / f"{stem}_transition.png")
        return result
    for run in runs:
        track = None
        method = "chirp"
        if kind == "stepped_sine":
            method = "stepped"
            track = stepped_track(info, run.name, run.n_samples, run.sample_rate_hz, run["drive_v"])
        stroke_est, pitch_est = estimates[run.name]
        result["runs"][run.name] = analyze_sweep(run, stroke_est, pitch_est, method, track, reference_v,
                                                 out_dir / f"{stem}_{run.name}_bode.png")
    return result


def run_sample_index(bag: Path, run: Run, blocks: bagio.Blocks) -> np.ndarray:
    """Absolute sample indices of a run's samples (its marker's first index + time)."""
    markers = {m.run: m for m in bagio.read_run_markers(bag)}
    first = markers[run.name].first_sample_index if run.name in markers else int(blocks.sample_index[0])
    return first + np.round(run["time_s"] * run.sample_rate_hz).astype(np.int64)


def headline(bags: list[dict[str, Any]]) -> dict[str, dict[str, float | None]]:
    """The paper's headline figures as measured here, beside the paper's."""
    ours: dict[str, float | None] = {}

    def first_run(kind: str) -> dict[str, Any] | None:
        for bag in bags:
            if bag["kind"] == kind and bag["runs"]:
                return next(iter(bag["runs"].values()))
        return None

    chirp, stepped = first_run("chirp"), first_run("stepped_sine")
    if chirp:
        ours["stroke_gain_deg_per_v"] = chirp["stroke"].get("gain_deg_per_v")
        ours["stroke_amplitude_rmse_deg"] = chirp["stroke"]["amplitude_rmse_deg"]
        ours["stroke_phase_rmse_deg"] = chirp["stroke"]["phase_rmse_deg"]
    if stepped:
        ours["pitch_gain_deg_per_v"] = stepped["pitch"].get("gain_deg_per_v")
        ours["pitch_amplitude_rmse_deg"] = stepped["pitch"]["amplitude_rmse_deg"]
        ours["pitch_amplitude_rmse_band_deg"] = stepped["pitch"]["amplitude_rmse_band_deg"]
        ours["pitch_time_rmse_deg"] = stepped["pitch"]["time_rmse_deg"]
        ours["pitch_time_rmse_lag_corrected_deg"] = stepped["pitch"]["time_rmse_lag_corrected_deg"]
        ours["pitch_time_rmse_lag_corrected_band_deg"] = stepped["pitch"]["time_rmse_lag_corrected_band_deg"]
        ours["pitch_phase_rmse_deg"] = stepped["pitch"]["phase_rmse_deg"]
    for bag in bags:
        runs = bag.get("collision", {}).get("runs", {})
        if "collision" in runs and "no_collision" in runs:
            ours["collision_spectrum_rmse_deg"] = runs["collision"]["spectrum_rmse_deg"]
            ours["no_collision_spectrum_rmse_deg"] = runs["no_collision"]["spectrum_rmse_deg"]
            ours["collision_time_rmse_deg"] = runs["collision"]["time_rmse_deg"]
            ours["no_collision_time_rmse_deg"] = runs["no_collision"]["time_rmse_deg"]
    table = {name: {"flaair": ours.get(name), "paper": value} for name, value in PAPER.items()}
    for bag in bags:
        if "transition" in bag:
            t = bag["transition"]
            table["transition_final_frequency_hz"] = {"flaair": t["final_frequency_hz"], "paper": None,
                                                      "note": f"stroke resonance {t['resonance_hz']:g} Hz; paper: slightly above it"}
            table["transition_final_amplitude_deg"] = {"flaair": t["final_amplitude_deg"], "paper": None}
    return table


def write_html(report: dict[str, Any], out_dir: Path) -> Path:
    """DIR/report.html: the headline table, every figure, and the numbers per bag."""
    def cell(value: float | None) -> str:
        return "" if value is None else f"{value:.3g}"

    rows = "".join(f"<tr><td>{html.escape(name)}</td><td>{cell(v['flaair'])}</td><td>{cell(v['paper'])}</td></tr>"
                   for name, v in report["headline"].items())
    figures = "".join(f'<figure><img src="{html.escape(p.name)}" style="max-width:900px"><figcaption>{html.escape(p.stem)}</figcaption></figure>'
                      for p in sorted(out_dir.glob("*.png")))
    body = (
        "<!doctype html><html><head><meta charset='utf-8'><title>FLAAIR analysis</title>"
        "<style>body{font-family:sans-serif;margin:2em}td,th{padding:2px 10px;border-bottom:1px solid #ddd}"
        "pre{background:#f6f6f6;padding:1em;overflow:auto}</style></head><body>"
        f"<h1>FLAAIR analysis</h1><p>{len(report['bags'])} bag(s), analysed {html.escape(report['created'])}; "
        "every number comes from the bags (live front-end estimate vs recorded ground truth).</p>"
        f"<h2>Headline figures beside the paper's</h2><table><tr><th>figure</th><th>FLAAIR</th><th>paper</th></tr>{rows}</table>"
        f"<h2>Figures</h2>{figures}<h2>All numbers</h2><pre>{html.escape(json.dumps(report, indent=1)[:200000])}</pre>"
        "</body></html>")
    path = out_dir / "report.html"
    path.write_text(body, encoding="utf-8")
    return path


def analyze(bags: list[Path], out_dir: Path, *, progress: bool = True) -> dict[str, Any]:
    """Analyse `bags` into out_dir (report.json, report.html, PNGs); return the report."""
    from flaair_model.model_io import load_model

    out_dir.mkdir(parents=True, exist_ok=True)
    reference_v = load_model().sensors.reference_voltage_v
    results = []
    for bag in tqdm(bags, desc="analysing bags", unit="bag", disable=not progress):
        try:
            results.append(analyze_bag(Path(bag), out_dir, reference_v))
        except (bagio.BagError, ch.CharacterizationError, KeyError) as exc:
            raise AnalysisError(f"{bag}: {exc}") from None
    report = {"created": time.strftime("%Y-%m-%d %H:%M:%S"), "bags": results}
    report["headline"] = headline(results)
    (out_dir / "report.json").write_text(json.dumps(report, indent=1, default=float))
    write_html(report, out_dir)
    return report


def print_headline(report: dict[str, Any]) -> None:
    """The headline table on stdout."""
    print(f"{'figure':42s} {'FLAAIR':>10s} {'paper':>8s}")
    for name, v in report["headline"].items():
        ours = "-" if v["flaair"] is None else f"{v['flaair']:.3g}"
        paper = "-" if v["paper"] is None else f"{v['paper']:.3g}"
        print(f"{name:42s} {ours:>10s} {paper:>8s}  {v.get('note', '')}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flaair analyze", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bags", nargs="+", type=Path, help="bags recorded by `flaair experiment` or imported")
    parser.add_argument("--out", type=Path, required=True, help="report directory")
    args = parser.parse_args(argv)
    try:
        report = analyze(args.bags, args.out)
    except (AnalysisError, bagio.BagError, ValueError, OSError) as exc:
        print(f"flaair analyze: {exc}", file=sys.stderr)
        return 2
    print_headline(report)
    print(f"report: {args.out / 'report.html'} (numbers in {args.out / 'report.json'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
