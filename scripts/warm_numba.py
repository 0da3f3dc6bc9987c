"""Compile and cache every numba kernel once (run by scripts/setup_env.sh after a build).

Without this, the first node processes of a fresh checkout each spend 10-20 s compiling the
plant before their first block; with the cache written here they start in well under a second.
"""
from __future__ import annotations

import time

import numpy as np


def main() -> None:
    start = time.perf_counter()
    from flaair_sim.drive import DriveParams, drive_record
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model
    from flaair_sim.plant import PlantInputs, PlantStepParams, initial_state, simulate, simulate_batch, step

    fs_hz = 20000.0
    model = load_model()
    drive = drive_record(DriveParams(kind="sine", amplitude_v=100.0, frequency_hz=100.0), fs_hz, 400)
    for m in (model, with_effects(model, {"collision": {"stroke_limit_deg": 20.0}, "sensor_delay": {"delay_s": 1e-4},
                                          "charge_amp_highpass": {"corner_hz": 1.0}})):
        simulate(drive, fs_hz, m)
        step(initial_state(m, fs_hz), PlantInputs(drive[:10]), PlantStepParams(m, fs_hz))
    simulate_batch(drive, fs_hz, [model, model])
    try:
        from flaair_control import collision

        from flaair_control.control_io import monitor_windows_from_config, spectral_metric_params_from_config

        collision.spectral_metric(np.sin(np.arange(2000) / 20.0), fs_hz, 100.0, spectral_metric_params_from_config())
        params = monitor_windows_from_config(100.0)
        collision.run(np.zeros(400), np.zeros(400), params)
    except Exception as exc:  # noqa: BLE001 - warming is best effort; the real call compiles anyway
        print(f"[setup] numba warm-up of flaair_control skipped: {exc}")
    print(f"[setup] numba kernels compiled and cached in {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
