"""The per-run analyses of `flaair analyze`: sweeps (Bode), sines
(RMSE, collision spectrum), free runs, collisions, the transition.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from flaair_analysis.headline import finite_or_none
from flaair_common import topics
from flaair_common.strictjson import json_safe
from flaair_control.core import transition as tr
from flaair_control.core.spectral import spectral_metric
from flaair_control.monitor_io import spectral_metric_params_from_config
from flaair_control.transition_io import hilbert_params_from_config
from flaair_model.model_io import load_model
from flaair_sensors.analysis_io import analysis_bands_from_config
from flaair_sensors.core import characterization as ch
from flaair_sensors.core import frontend
from flaair_sensors.core.bode import Bode, bode_from_chirp, bode_from_stepped, wrap_deg
from flaair_sensors.core.calibration import CalibrationError, calibrate
from flaair_sensors.core.frontend_params import FrontendParams, params_from_calibration
from flaair_sensors.frontend_io import frontend_tuning_from_config
from flaair_tools import bagio
from flaair_tools.analysis.runkind import DriveKind
from flaair_tools.analysis.transition import TransitionRecord
from flaair_tools.bagio.runs import Run

__all__ = [
    "AnalysisError",
    "analyze_collision",
    "analyze_free",
    "analyze_sine",
    "analyze_sweep",
    "analyze_transition",
    "collision_events",
    "collision_metric",
    "first_strike_s",
    "metric_params",
    "offline_estimate",
]


class AnalysisError(ValueError):
    """A bag cannot be analysed; the message names the bag, run or topic."""


def offline_estimate(run: Run, params: FrontendParams) -> tuple[np.ndarray, np.ndarray]:
    """Stroke and pitch (rad, NaN where invalid) of the front-end core run on the run's voltages."""
    est = frontend.estimate(run["stroke_sensor_v"], run["pitch_sensor_v"], params)
    return (
        np.where(est.stroke_valid, est.stroke_rad, np.nan),
        np.where(est.pitch_valid, est.pitch_rad, np.nan),
    )


def _sweep_figures(
    run: Run, stroke_est: np.ndarray, pitch_est: np.ndarray, method: str, track: np.ndarray | None
) -> tuple[Bode, dict[str, Any]]:
    fs, drive = run.sample_rate_hz, run["drive_v"]
    stroke_t, pitch_t = np.radians(run["stroke_deg"]), np.radians(run["pitch_deg"])
    if method == "chirp":
        bode = bode_from_chirp(
            drive, stroke_est, pitch_est, stroke_t, pitch_t, fs, frequency_hz_per_sample=track
        )
    else:
        bode = bode_from_stepped(drive, stroke_est, pitch_est, stroke_t, pitch_t, fs, track)
    bands = analysis_bands_from_config()
    result = ch.characterize(
        bode,
        drive,
        stroke_est,
        pitch_est,
        stroke_t,
        pitch_t,
        fs,
        track,
        amplitude_band_hz=bands.amplitude_band_hz,
        time_band_hz=bands.time_band_hz,
    )
    figures = {
        name: json_safe(dict(metrics.__dict__))
        for name, metrics in (("stroke", result.stroke), ("pitch", result.pitch))
    }
    return bode, figures


def analyze_sweep(
    run: Run,
    stroke_est: np.ndarray,
    pitch_est: np.ndarray,
    method: str,
    track: np.ndarray | None,
    reference_v: float,
) -> tuple[dict[str, Any], Bode]:
    """Gains, Bode and the paper's RMSE figures of one chirp, stepped-sine or sine run.

    As the paper does, each sensor's gain is fitted against ground truth first and the RMSE
    figures are "for this gain": the front-end core runs on the recorded voltages with the
    fitted gains (`stroke`, `pitch`). The figures of the estimate as given (`live`) stay beside.
    """
    fs = run.sample_rate_hz
    out: dict[str, Any] = {"method": method}
    live_bode, out["live"] = _sweep_figures(run, stroke_est, pitch_est, method, track)
    try:
        gains = calibrate(
            run.columns,
            reference_v,
            sample_rate_hz=fs,
            frequency_hz_per_sample=track if method != "chirp" else None,
            amplitude_band_hz=analysis_bands_from_config().amplitude_band_hz,
        )
    except CalibrationError as exc:
        out["gain_error"] = str(exc)
        out.update(stroke=out["live"]["stroke"], pitch=out["live"]["pitch"])
        bode = live_bode
    else:
        # Fitted gain and offset only: the lag stays in the estimate, as the paper reports it.
        params = params_from_calibration(
            gains, fs, **{**frontend_tuning_from_config(), "compensate_lag": False}
        )
        bode, fitted = _sweep_figures(run, *offline_estimate(run, params), method, track)
        for name in ("stroke", "pitch"):
            fitted[name]["gain_deg_per_v"] = finite_or_none(gains[name]["gain_deg_per_v"])
            fitted[name]["sensor_lag_s"] = finite_or_none(gains[name]["lag_s"])
            out[name] = fitted[name]
    out["bode"] = {
        name: json_safe(
            {k: v for k, v in getattr(bode, name).__dict__.items() if isinstance(v, np.ndarray)}
        )
        for name in ("stroke", "pitch")
    }
    return out, bode


def metric_params() -> Any:
    """The collision monitor's paper-metric settings (config/flaair.yaml collision_monitor_node)."""
    return spectral_metric_params_from_config()


def collision_metric(pitch_rad: np.ndarray, fs_hz: float, frequency_hz: float) -> Any:
    """The paper's collision metric of a pitch record (its finite samples)."""
    valid = pitch_rad[np.isfinite(pitch_rad)]
    return spectral_metric(valid, fs_hz, frequency_hz, metric_params())


def analyze_sine(
    run: Run, stroke_est: np.ndarray, pitch_est: np.ndarray, kind: DriveKind, reference_v: float
) -> dict[str, Any]:
    """A single-sine run: gain and phase at its frequency, and the paper's collision metric."""
    out, bode = analyze_sweep(
        run, stroke_est, pitch_est, "sine", kind.frequency_track(run.n_samples), reference_v
    )
    out["frequency_hz"] = kind.frequency_hz
    for name in ("stroke", "pitch"):
        cb = getattr(bode, name)
        out[f"{name}_at_frequency"] = json_safe(
            {
                "sensor_amplitude_deg": cb.sensor_amplitude_deg[0],
                "truth_amplitude_deg": cb.truth_amplitude_deg[0],
                "phase_error_deg": wrap_deg(cb.sensor_phase_deg[0] - cb.truth_phase_deg[0]),
            }
        )
    try:
        metric = collision_metric(pitch_est, run.sample_rate_hz, float(kind.frequency_hz))
        out["collision_metric"] = json_safe(
            {
                "spectrum_rmse_deg": metric.spectral_rmse_deg,
                "time_rmse_deg": metric.time_rmse_deg,
                "collision": bool(metric.collision),
                "threshold_deg": metric_params().threshold_deg,
            }
        )
    except ValueError as exc:
        out["collision_metric"] = {"error": str(exc)}
    return out


def analyze_free(run: Run, stroke_est: np.ndarray) -> dict[str, Any]:
    """A free run: dominant stroke frequency and amplitude, sensor and truth."""
    out: dict[str, Any] = {"method": "free"}
    for name, stroke in (("sensor", np.degrees(stroke_est)), ("truth", run["stroke_deg"])):
        x = stroke[np.isfinite(stroke)]
        if x.size < 16:
            out[name] = {"frequency_hz": None, "amplitude_deg": None}
            continue
        x = x - x.mean()
        spectrum = np.abs(np.fft.rfft(x * np.hanning(x.size)))
        peak = int(np.argmax(spectrum[1:])) + 1
        out[name] = json_safe(
            {
                "frequency_hz": peak * run.sample_rate_hz / x.size,
                "amplitude_deg": np.sqrt(2) * np.std(x),
            }
        )
    return out


def first_strike_s(
    truth_stroke_deg: np.ndarray,
    time_s: np.ndarray,
    window_s: tuple[float, float],
    limit_deg: float,
) -> float | None:
    """Time of the first sample inside the obstacle window
    at which the true stroke reaches the obstacle.
    """
    hit = (time_s >= window_s[0]) & (time_s < window_s[1]) & (truth_stroke_deg >= limit_deg - 0.5)
    return float(time_s[np.argmax(hit)]) if hit.any() else None


def collision_events(contents: bagio.BagContents) -> list[dict[str, Any]]:
    """The monitor's onset and clearance events recorded on /flaair/collision/events."""
    return [
        {
            "kind": "onset" if m.kind == 1 else "clearance",
            "wingbeat_index": int(m.wingbeat_index),
            "time_s": m.header.stamp.sec + m.header.stamp.nanosec * 1e-9,
            "spectrum_rmse_deg": finite_or_none(m.spectrum_rmse_deg),
        }
        for m in contents.messages(topics.COLLISION_EVENTS)
    ]


def analyze_collision(
    runs: list[Run],
    est: dict[str, tuple[np.ndarray, np.ndarray]],
    info: dict[str, Any],
    contents: bagio.BagContents,
    kinds: dict[str, DriveKind],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The paper's collision metric per run part, the
    monitor's events and latency; and the figure data.
    """
    bag = contents.info.path
    drive_hz = next((k.frequency_hz for k in kinds.values() if k.frequency_hz), None)
    if drive_hz is None and info.get("runs"):
        drive_hz = float(info["runs"][0]["drive"]["frequency_hz"])
    if drive_hz is None:
        raise AnalysisError(f"{bag}: the collision runs carry no steady drive frequency")
    out: dict[str, Any] = {
        "drive_frequency_hz": drive_hz,
        "runs": {},
        "threshold_deg": metric_params().threshold_deg,
    }
    figure: dict[str, Any] = {"frequency_hz": drive_hz, "runs": {}}
    for run in runs:
        pitch = est[run.name][1]
        try:
            metric = collision_metric(pitch, run.sample_rate_hz, drive_hz)
        except ValueError as exc:
            out["runs"][run.name] = {"error": str(exc)}
            continue
        out["runs"][run.name] = json_safe(
            {
                "spectrum_rmse_deg": metric.spectral_rmse_deg,
                "time_rmse_deg": metric.time_rmse_deg,
                "collision": bool(metric.collision),
            }
        )
        figure["runs"][run.name] = (metric, np.degrees(pitch), run.sample_rate_hz)
    events = collision_events(contents)
    out["events"] = events
    plant = info.get("plant", {})
    window = plant.get("obstacle_windows_s")
    if window and len(window) >= 2:
        truth = contents.blocks(topics.WING_STATE_TRUTH)
        fs = float(truth.sample_rate_hz)
        strike = first_strike_s(
            np.where(truth["stroke_valid"].astype(bool), truth["stroke_deg"], np.nan),
            truth.sample_index / fs,
            (float(window[0]), float(window[1])),
            float(plant.get("obstacle_stroke_limit_deg", np.inf)),
        )
        onset = next(
            (e for e in events if e["kind"] == "onset" and e["time_s"] >= float(window[0])), None
        )
        clearance = next(
            (e for e in events if e["kind"] == "clearance" and e["time_s"] >= float(window[1])),
            None,
        )
        out["obstacle"] = json_safe(
            {
                "window_s": [float(window[0]), float(window[1])],
                "first_strike_s": strike,
                "onset_s": onset["time_s"] if onset else None,
                "clearance_s": clearance["time_s"] if clearance else None,
                "detection_latency_wingbeats": (onset["time_s"] - strike) * drive_hz
                if onset and strike is not None
                else None,
                "clearance_latency_wingbeats": (clearance["time_s"] - float(window[1])) * drive_hz
                if clearance
                else None,
                "false_onsets": sum(
                    1
                    for e in events
                    if e["kind"] == "onset"
                    and not float(window[0]) <= e["time_s"] < float(window[1]) + 0.1
                ),
            }
        )
    return out, figure


def analyze_transition(
    contents: bagio.BagContents, final_window_s: float = 0.5
) -> tuple[dict[str, Any], Any]:
    """Sync-to-async transition: stroke frequency and amplitude from the Hilbert transform.

    The recorded sensor-derived stroke is band-passed, Hilbert-transformed and smoothed by a
    Savitzky-Golay filter (paper); K_r comes from the recorded controller state.
    """
    bag = contents.info.path
    wing = contents.blocks(topics.WING_STATE)
    fs = float(wing.sample_rate_hz)
    stroke_deg = np.where(wing["stroke_valid"].astype(bool), wing["stroke_deg"], np.nan)
    time_s = wing.sample_index / fs
    states = contents.messages(topics.CONTROLLER_STATE)
    if not states:
        raise AnalysisError(
            f"{bag}: no {topics.CONTROLLER_STATE} messages (was the controller running?)"
        )
    kr_time_s = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in states])
    record = TransitionRecord(
        time_s,
        stroke_deg,
        kr_time_s,
        np.array([m.k_r for m in states]),
        np.array([m.stroke_frequency_hz for m in states]),
        np.array([m.drive_v for m in states]),
        0,
    )
    result = tr.hilbert_analysis(
        stroke_deg, fs, hilbert_params_from_config(), start_time_s=float(time_s[0])
    )
    resonance_hz = load_model().plant.stroke_natural_frequency_hz
    end_s = float(time_s[-1])
    final = tr.window_stats(result.time_s, result.frequency_hz, end_s - final_window_s, end_s)
    final_amplitude = tr.window_stats(
        result.time_s, result.amplitude, end_s - final_window_s, end_s
    )
    dropped = record.kr < record.kr[0] - 1e-9
    ramp_start = float(kr_time_s[np.argmax(dropped)]) if dropped.any() else end_s
    initial = tr.window_stats(result.time_s, result.frequency_hz, float(time_s[0]), ramp_start)
    out = json_safe(
        {
            "resonance_hz": resonance_hz,
            "initial_frequency_hz": initial.mean,
            "final_frequency_hz": final.mean,
            "final_frequency_spread_hz": final.std,
            "final_amplitude_deg": final_amplitude.mean,
            "final_amplitude_spread_deg": final_amplitude.std,
            "final_k_r": float(record.kr[-1]),
        }
    )
    return out, (record, result, resonance_hz)
