"""Benchmark of the sensor front-end core (flaair_sensors.core.frontend).

Figures:
- step() on 10-sample blocks (0.5 ms of data at 20 kHz): throughput in samples/s and per-block
  latency p50/p99 (target p99 < 1 ms), wall clock and thread CPU time (on a loaded shared
  machine the wall-clock p99 is dominated by preemption, the CPU-time p99 is the core's own);
- estimate() on a whole 10 s record: throughput in samples/s;
- calibrate() and characterize_run() on a 1 s chirp: wall time (offline tools).
Baselines (same run): the bare scipy.signal.lfilter calls the step makes, without the front
end's bookkeeping.

Usage: python bench/bench_frontend_core.py [--json PATH]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy import signal

from benchlib import best_time_s, compare, print_table, write_json
from flaair_model.model_io import load_model
from flaair_sensors.analysis_io import analysis_bands_from_config
from flaair_sensors.core import calibration, characterization, frontend_params
from flaair_sensors.core import frontend as fe
from flaair_sensors.frontend_io import frontend_tuning_from_config
from flaair_sim.core.drive import chirp
from flaair_sim.core.plant import simulate

FS = 20000.0
BLOCK = 10


def _record(model, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, object]:
    t = np.arange(int(seconds * FS)) / FS
    drive = chirp(t, 100.0, 20.0, 200.0, seconds)
    out = simulate(drive, FS, model)
    return drive, out.stroke_sensor_v, out.pitch_sensor_v, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON here")
    args = ap.parse_args()

    model = load_model()
    # Realistic configuration: drift removal, lag compensation on both channels, rails.
    tuning = frontend_tuning_from_config()
    params = frontend_params.params_from_model(
        model,
        FS,
        **{
            **tuning,
            "stroke_lag_s": 2e-4,
            "pitch_lag_s": 3e-4,
            "rail_low_v": -5.0,
            "rail_high_v": 5.0,
            "rail_margin_v": 0.01,
        },
    )
    _drive, sv, pv, _out = _record(model, 10.0)
    n = sv.size
    blocks_s = sv[: n - n % BLOCK].reshape(-1, BLOCK)
    blocks_p = pv[: n - n % BLOCK].reshape(-1, BLOCK)

    # --- step() on 10-sample blocks: latency distribution over 2 s of data (4000 blocks).
    state = fe.initial_state(params, first_stroke_v=sv[0], first_pitch_v=pv[0])
    # warm the filter-design cache
    fe.step(state, fe.FrontendInputs(blocks_s[0], blocks_p[0]), params)
    lat = np.empty(4000)
    cpu = np.empty(4000)
    for i in range(lat.size):
        c0 = time.thread_time()
        t0 = time.perf_counter()
        state, _ = fe.step(state, fe.FrontendInputs(blocks_s[i], blocks_p[i]), params)
        lat[i] = time.perf_counter() - t0
        cpu[i] = time.thread_time() - c0
    p50, p99 = np.percentile(lat, [50, 99])
    cpu50, cpu99 = np.percentile(cpu, [50, 99])

    def run_blocks() -> None:
        st = fe.initial_state(params, first_stroke_v=sv[0], first_pitch_v=pv[0])
        for i in range(2000):
            st, _ = fe.step(st, fe.FrontendInputs(blocks_s[i], blocks_p[i]), params)

    t_blocks = best_time_s(run_blocks)
    step_rate = 2000 * BLOCK / t_blocks

    # Baseline: the five bare lfilter calls per block (drift x2, lead x2, velocity).
    flt = fe.filters(params)
    zd = np.zeros(1)
    zl = np.zeros(2)

    def bare_blocks() -> None:
        for i in range(2000):
            x = blocks_s[i]
            signal.lfilter(flt.drift_b, flt.drift_a, x, zi=zd)
            signal.lfilter(flt.drift_b, flt.drift_a, x, zi=zd)
            signal.lfilter(flt.stroke_lead[0], flt.stroke_lead[1], x, zi=zl)
            signal.lfilter(flt.pitch_lead[0], flt.pitch_lead[1], x, zi=zl)
            signal.lfilter(flt.vel_b, flt.vel_a, x, zi=zl)

    bare_rate = 2000 * BLOCK / best_time_s(bare_blocks)

    # --- whole record.
    t_whole = best_time_s(lambda: fe.estimate(sv, pv, params))
    whole_rate = n / t_whole

    def bare_whole() -> None:
        for x in (sv, pv):
            signal.lfilter(flt.drift_b, flt.drift_a, x)
            signal.lfilter(flt.stroke_lead[0], flt.stroke_lead[1], x)
        signal.lfilter(flt.vel_b, flt.vel_a, sv)

    bare_whole_rate = n / best_time_s(bare_whole)

    # --- offline tools on the paper's 1 s chirp.
    d1, s1, p1, o1 = _record(model, 1.0)
    run = {
        "time_s": np.arange(d1.size) / FS,
        "drive_v": d1,
        "stroke_sensor_v": s1,
        "pitch_sensor_v": p1,
        "stroke_deg": np.degrees(o1.stroke_rad),
        "pitch_deg": np.degrees(o1.pitch_rad),
    }
    vref = model.sensors.reference_voltage_v
    bands = analysis_bands_from_config()
    t_cal = best_time_s(
        lambda: calibration.calibrate(run, vref, amplitude_band_hz=bands.amplitude_band_hz),
        repeats=2,
    )
    track = 20.0 + 180.0 * run["time_s"]
    p0 = frontend_params.params_from_model(model, FS, **tuning)
    t_char = best_time_s(
        lambda: characterization.characterize_run(
            run,
            p0,
            "chirp",
            track,
            amplitude_band_hz=bands.amplitude_band_hz,
            time_band_hz=bands.time_band_hz,
        ),
        repeats=2,
    )

    realtime = FS
    figures = [
        compare(
            "frontend step, 10-sample blocks: throughput",
            step_rate,
            "samples/s",
            ">=",
            realtime,
            f"real time is {realtime:.0f} samples/s; bare lfilter calls: {bare_rate:.3g} samples/s",
        ),
        compare(
            "frontend step, 10-sample block latency p50",
            p50 * 1e3,
            "ms",
            "<",
            BLOCK / FS * 1e3,
            f"the bound is the block length: {BLOCK / FS * 1e3:.2f} ms of data",
        ),
        compare(
            "frontend step, 10-sample block latency p99",
            p99 * 1e3,
            "ms",
            "<",
            1.0,
            f"max {lat.max() * 1e3:.3f} ms over {lat.size} blocks (wall clock)",
        ),
        compare(
            "frontend step, 10-sample block CPU time p99",
            cpu99 * 1e3,
            "ms",
            "<",
            1.0,
            f"p50 {cpu50 * 1e3:.3f} ms (thread CPU time: excludes preemption)",
        ),
        compare(
            "frontend estimate, whole 10 s record: throughput",
            whole_rate,
            "samples/s",
            ">=",
            100 * realtime,
            f"100x real time; bare lfilter chain: {bare_whole_rate:.3g} samples/s",
        ),
        compare("calibrate, 1 s chirp (2 channels)", t_cal, "s", "<", 2.0),
        compare("characterize_run chirp, 1 s chirp", t_char, "s", "<", 2.0),
    ]
    print_table(figures)
    if args.json is not None:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
