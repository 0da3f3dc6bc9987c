"""Collision monitor benchmark: detection latency, false-alarm sweep, paper metric, throughput.

Run: /tmp/probe-venv/bin/python bench/bench_collision.py [--quick]

Scenario (paper, section Applications): 100 Hz drive, 150 V bias -> 75 V amplitude about the
removed bias, obstacle at 20 deg against a 28.3 deg free stroke, struck on every wingbeat.
Latency: the obstacle appears during steady flapping (block loop, 0.5 ms blocks, sensor noise on,
sensor-derived angles by the linear inverse sensor model); latency = end of the block that
returned the onset event - first sample at or past the obstacle, in wingbeats. Baseline: the
paper's own metric (pitch FFT RMSE over a sliding 10-wingbeat record, 1 deg threshold),
evaluated at every wingbeat end.
False alarms: nominal plant, noise on, 10 s at each drive frequency 60-200 Hz (10 Hz steps) at
100 and 200 Vpp, from rest (abrupt start), both window sources; whole-record simulate + run.
Paper metric, steady state (last 10 wingbeats of 0.5 s): the pitch FFT RMSE with the obstacle
above the configured threshold (1 deg, the paper's) and without it at or below it, each its own
comparison (paper 3.23 / 0.53 deg); the time RMSE reported, with the obstacle over without it
> 1 (paper 15.81 / 3.34 deg).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import REPO_ROOT, Figure, best_time_s, compare, info, print_table, write_json

for _pkg in ("flaair_control", "flaair_sim", "flaair_sensors"):
    if str(REPO_ROOT / "src" / _pkg) not in sys.path:
        sys.path.insert(0, str(REPO_ROOT / "src" / _pkg))

from flaair_control.core import collision as col
from flaair_control.core import spectral
from flaair_control.monitor_io import (
    monitor_windows_from_config,
    spectral_metric_params_from_config,
)
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_sim.core import plant

FS = 20000.0
METRIC = spectral_metric_params_from_config()  # the paper metric as configured
BLOCK = 10
DRIVE_HZ = 100.0
AMPLITUDE_V = 75.0
LIMIT_DEG = 20.0


def sensor_angles(model, out):
    vref = model.sensors.reference_voltage_v
    return (
        (out.stroke_sensor_v - vref) / model.stroke_volts_per_rad,
        (out.pitch_sensor_v - vref) / model.pitch_volts_per_rad,
    )


def monitor_params(model, source: str, f: float) -> col.MonitorParams:
    return replace(
        monitor_windows_from_config(f),
        window_source=source,
        drive_frequency_hz=f if source == "drive" else None,
        stroke_noise_rms_rad=model.noise.sensor_noise_v_rms / abs(model.stroke_volts_per_rad),
        pitch_noise_rms_rad=model.noise.sensor_noise_v_rms / abs(model.pitch_volts_per_rad),
    )


def latency_trial(model, source: str, t_in: float, seed: int, duration: float = 0.6):
    """(monitor latency, paper-metric latency) in wingbeats for an obstacle appearing at ~t_in."""
    hit = with_effects(model, {"collision": {"stroke_limit_deg": LIMIT_DEG}})
    limit = math.radians(LIMIT_DEG)
    rng = np.random.default_rng(seed)
    prm = monitor_params(model, source, DRIVE_HZ)
    mon = col.initial_state(prm)
    state = plant.initial_state(plant.PlantStepParams(model, FS))
    present, strike, onset_t = False, None, None
    last_phi = 0.0
    pitch = []
    for k in range(int(duration * FS / BLOCK)):
        t0 = k * BLOCK / FS
        if not present and t0 >= t_in and last_phi < 0.5 * limit:
            present = True
        drive = AMPLITUDE_V * np.sin(2 * np.pi * DRIVE_HZ * (t0 + np.arange(BLOCK) / FS))
        state, out = plant.step(
            state,
            plant.PlantInputs(drive, rng),
            plant.PlantStepParams(hit if present else model, FS),
        )
        last_phi = out.stroke_rad[-1]
        if present and strike is None and np.any(out.stroke_rad >= limit):
            strike = t0 + np.argmax(out.stroke_rad >= limit) / FS
        s, p = sensor_angles(model, out)
        pitch.append(p)
        mon, (_, ev) = col.step(mon, col.MonitorInputs(s, p), prm)
        if onset_t is None and any(e.kind == col.ONSET for e in ev):
            onset_t = t0 + BLOCK / FS
    pitch_all = np.concatenate(pitch)
    # Baseline: paper metric on the last 10 wingbeats, evaluated at each wingbeat end.
    period = round(FS / DRIVE_HZ)
    paper_t = None
    for end in range(10 * period, pitch_all.size + 1, period):
        if end / FS <= strike:
            continue
        if spectral.spectral_metric(
            pitch_all[end - 10 * period : end], FS, DRIVE_HZ, METRIC
        ).collision:
            paper_t = end / FS
            break
    lat = (onset_t - strike) * DRIVE_HZ if onset_t is not None else math.inf
    paper_lat = (paper_t - strike) * DRIVE_HZ if paper_t is not None else math.inf
    return lat, paper_lat


def false_alarm_sweep(model, source: str, duration_s: float):
    t = np.arange(int(duration_s * FS)) / FS
    alarms, worst, wingbeats = 0, 0.0, 0
    worst_at = None
    for f in range(60, 201, 10):
        for amp in (50.0, 100.0):
            out = plant.simulate(
                amp * np.sin(2 * np.pi * f * t),
                FS,
                model,
                noise=True,
                rng=np.random.default_rng(1000 * f + int(amp)),
            )
            s, p = sensor_angles(model, out)
            _, rep, ev = col.run(
                s, p, replace(monitor_windows_from_config(float(f)), window_source=source)
            )
            armed = rep.status != col.ARMING
            alarms += sum(e.kind == col.ONSET for e in ev)
            wingbeats += int(np.count_nonzero(armed))
            score = float(rep.score[armed].max())
            if score > worst:
                worst, worst_at = score, (f, 2 * amp)
    return alarms, worst, worst_at, wingbeats


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="1 s false-alarm records instead of 10 s")
    ap.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench_collision.json")
    args = ap.parse_args()
    model = load_model()
    figures: list[Figure] = []

    # Paper metric, steady state (last 10 wingbeats of 0.5 s).
    t = np.arange(int(0.5 * FS)) / FS
    drive = AMPLITUDE_V * np.sin(2 * np.pi * DRIVE_HZ * t)
    hit = with_effects(model, {"collision": {"stroke_limit_deg": LIMIT_DEG}})
    free = spectral.spectral_metric(
        sensor_angles(
            model, plant.simulate(drive, FS, model, noise=True, rng=np.random.default_rng(1))
        )[1],
        FS,
        DRIVE_HZ,
        METRIC,
    )
    coll = spectral.spectral_metric(
        sensor_angles(
            model, plant.simulate(drive, FS, hit, noise=True, rng=np.random.default_rng(2))
        )[1],
        FS,
        DRIVE_HZ,
        METRIC,
    )
    # The metric's own rule (spectral_metric: colliding iff the spectral RMSE exceeds the
    # threshold, 1 deg as the paper's): the collision above it, the free stroke not.
    threshold = METRIC.threshold_deg
    figures += [
        compare(
            "paper metric: pitch FFT RMSE, collision",
            coll.spectral_rmse_deg,
            "deg",
            ">",
            threshold,
            "the collision threshold; paper 3.23 deg",
        ),
        compare(
            "paper metric: pitch FFT RMSE, no collision",
            free.spectral_rmse_deg,
            "deg",
            "<=",
            threshold,
            "the collision threshold; paper 0.53 deg",
        ),
        info(
            "paper metric: pitch time RMSE, collision",
            coll.time_rmse_deg,
            "deg",
            f"no collision {free.time_rmse_deg:.3f} deg; paper 15.81 vs 3.34 deg (no threshold)",
        ),
        compare(
            "paper metric: pitch time RMSE, collision / no collision",
            coll.time_rmse_deg / free.time_rmse_deg,
            "x",
            ">",
            1.0,
            f"{coll.time_rmse_deg:.3f} / {free.time_rmse_deg:.3f} deg; paper 15.81 / 3.34 = 4.73",
        ),
    ]

    # Detection latency.
    for source in ("drive", "stroke"):
        lats, paper = [], []
        for i, t_in in enumerate((0.300, 0.3025, 0.305, 0.3075, 0.31, 0.3125)):
            a, b = latency_trial(model, source, t_in, seed=100 + i)
            lats.append(a)
            paper.append(b)
        figures.append(
            compare(
                f"detection latency, worst of 6 ({source} windows)",
                max(lats),
                "wingbeats",
                "<=",
                2.0,
                f"mean {np.mean(lats):.2f}; paper metric (10-beat FFT, 1 deg) worst "
                f"{max(paper):.2f}",
            )
        )

    # False alarms.
    duration = 1.0 if args.quick else 10.0
    for source in ("drive", "stroke"):
        alarms, worst, at, beats = false_alarm_sweep(model, source, duration)
        figures.append(
            compare(
                f"false alarms, {duration:g} s x 15 freqs x 2 amps ({source})",
                alarms,
                "events",
                "==",
                0,
                f"{beats} armed wingbeats; worst "
                f"score {worst:.3f} (onset 1.0) "
                f"at {at[0]} Hz {at[1]:g} Vpp",
            )
        )

    # Throughput.
    t10 = np.arange(int(10.0 * FS)) / FS
    out = plant.simulate(
        50.0 * np.sin(2 * np.pi * 200.0 * t10), FS, model, noise=True, rng=np.random.default_rng(3)
    )
    s, p = sensor_angles(model, out)
    prm = monitor_windows_from_config(200.0)
    whole = best_time_s(lambda: col.run(s, p, prm))
    figures.append(
        compare(
            "monitor, whole record (10 s at 200 Hz)",
            10.0 / whole,
            "x realtime",
            ">",
            10.0,
            f"{whole * 1e3:.1f} ms",
        )
    )

    def live():
        st = col.initial_state(prm)
        for i in range(0, 20000, BLOCK):
            st, (_, _) = col.step(st, col.MonitorInputs(s[i : i + BLOCK], p[i : i + BLOCK]), prm)

    per_block = best_time_s(live) / (20000 / BLOCK)
    figures.append(
        compare(
            "monitor step per 0.5 ms block (live)",
            per_block * 1e6,
            "us",
            "<",
            500.0,
            f"{100 * per_block / 5e-4:.1f} % of the block period",
        )
    )

    print_table(figures)
    write_json(figures, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
