"""Plant simulation speed: numba RK4 vs a plain per-step Python RK4, and batch throughput.

Run: python bench/bench_sim.py [--json out.json]

Figures (1 s of robot time at 20 kHz, 1 s chirp 20-200 Hz at 100 V):
- numba compile time (fresh process, empty cache; with --cold-compile, `make bench-full`: about
  a minute of compiling for an `info` figure) and the first call here (usually a cache load),
  reported separately and excluded from the timings;
- nominal simulate() with numba vs `python_rk4` below (same model, same step), in the same run:
  the speedup (target >= 100x) and the largest difference of their angles (target <= 1e-6 deg:
  the same arithmetic, so rounding only);
- simulate_batch throughput in robot-seconds per second for 1, 100, 1000 parameter sets
  (outputs reused via out=, as in a fitting loop; and 1000 with fresh output arrays); target:
  1000 sets at least simulate()'s own rate (their ratio >= 1).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import Figure, best_time_s, compare, info, print_table, write_json
from flaair_model.model import Model, with_effects
from flaair_model.model_io import load_model
from flaair_sim.core import plant, plant_kernel
from flaair_sim.core.drive import chirp

FS_HZ = 20_000.0
DURATION_S = 1.0
SPEEDUP_TARGET = 100.0
# numba's kernel and `python_rk4` take the same RK4 step on the same samples: they differ only
# by rounding (measured 3.2e-14 deg over the 1 s chirp, angles up to 48 deg). The bound leaves
# eight orders of magnitude for another order of operations; a change to the integration is far
# above it (the drive one sample later moves the angles by 2.4 deg).
MAX_DIFF_DEG = 1e-6


def python_rk4(drive_v: np.ndarray, fs_hz: float, model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Plain-Python reference: nominal stroke/pitch dynamics, one RK4 step per sample, ZOH drive.

    Same sample convention as flaair_sim.core.plant (sample
    k = state at t_k). Returns (stroke_rad, pitch_rad).
    """
    pl = model.plant
    inertia, gamma, k, ga = (
        pl.stroke_inertia_kg_m2,
        pl.aero_damping_nm_s2,
        pl.stroke_stiffness_nm_per_rad,
        pl.actuator_gain_nm_per_v,
    )
    ip, cp, kh, jc, dp = (
        pl.pitch_inertia_kg_m2,
        pl.hinge_damping_nm_s_per_rad,
        pl.hinge_stiffness_nm_per_rad,
        pl.inertial_coupling_kg_m2,
        pl.aero_coupling_nm_s2,
    )

    def accel(phi: float, dphi: float, psi: float, dpsi: float, v: float) -> tuple[float, float]:
        ddphi = (ga * v - gamma * abs(dphi) * dphi - k * phi) / inertia
        return ddphi, (-cp * dpsi - kh * psi - jc * ddphi - dp * abs(dphi) * dphi) / ip

    h = 1.0 / fs_hz
    phi = dphi = psi = dpsi = 0.0
    stroke, pitch = [], []
    for v in drive_v.tolist():
        stroke.append(phi)
        pitch.append(psi)
        a1, b1 = accel(phi, dphi, psi, dpsi, v)
        a2, b2 = accel(
            phi + 0.5 * h * dphi, dphi + 0.5 * h * a1, psi + 0.5 * h * dpsi, dpsi + 0.5 * h * b1, v
        )
        a3, b3 = accel(
            phi + 0.5 * h * (dphi + 0.5 * h * a1),
            dphi + 0.5 * h * a2,
            psi + 0.5 * h * (dpsi + 0.5 * h * b1),
            dpsi + 0.5 * h * b2,
            v,
        )
        a4, b4 = accel(
            phi + h * (dphi + 0.5 * h * a2),
            dphi + h * a3,
            psi + h * (dpsi + 0.5 * h * b2),
            dpsi + h * b3,
            v,
        )
        phi += (
            h
            / 6.0
            * (dphi + 2.0 * (dphi + 0.5 * h * a1) + 2.0 * (dphi + 0.5 * h * a2) + (dphi + h * a3))
        )
        psi += (
            h
            / 6.0
            * (dpsi + 2.0 * (dpsi + 0.5 * h * b1) + 2.0 * (dpsi + 0.5 * h * b2) + (dpsi + h * b3))
        )
        dphi += h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        dpsi += h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
    return np.array(stroke), np.array(pitch)


def parameter_sets(model: Model, n: int, seed: int = 0) -> list[Model]:
    """`n` models with stroke/pitch natural frequencies and aero damping spread +-10 %."""
    rng = np.random.default_rng(seed)
    models = []
    for scale in rng.uniform(0.9, 1.1, size=(n, 3)):
        pl = dataclasses.replace(
            model.plant,
            stroke_natural_frequency_hz=model.plant.stroke_natural_frequency_hz * scale[0],
            pitch_natural_frequency_hz=model.plant.pitch_natural_frequency_hz * scale[1],
            aero_damping_nm_s2=model.plant.aero_damping_nm_s2 * scale[2],
        )
        models.append(dataclasses.replace(model, plant=pl))
    return models


def cold_compile_s() -> float:
    """Wall time of the first simulate() + simulate_batch()
    in a new process with an empty numba cache.
    """
    code = (
        "import time, numpy as np\n"
        "t = time.perf_counter()\n"
        "from flaair_sim.core import plant\n"
        "from flaair_model.model_io import load_model\n"
        "m = load_model()\n"
        "plant.simulate(np.zeros(10), 20000.0, m)\n"
        "plant.simulate_batch(np.zeros(10), 20000.0, [m, m])\n"
        "print(time.perf_counter() - t)\n"
    )
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        env["PYTHONPATH"] = os.pathsep.join(
            [p for p in sys.path if p] + [env.get("PYTHONPATH", "")]
        )
        result = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
    return float(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures as JSON here")
    parser.add_argument(
        "--cold-compile",
        action="store_true",
        help="also time a cold numba compile in a fresh process (about a minute)",
    )
    args = parser.parse_args()

    model = load_model()
    n = int(DURATION_S * FS_HZ)
    drive = chirp(np.arange(n) / FS_HZ, 100.0, 20.0, 200.0, DURATION_S)
    figures: list[Figure] = []

    if args.cold_compile:
        figures.append(info("numba compile, cold cache (fresh process)", cold_compile_s(), "s"))
    start = time.perf_counter()
    plant.simulate(drive[:10], FS_HZ, model)
    plant.simulate_batch(drive[:10], FS_HZ, [model, model])
    first = time.perf_counter() - start
    cached = plant_kernel.run_model.stats.cache_hits and plant_kernel.run_batch.stats.cache_hits
    how = "numba cache load" if cached else "numba compile"
    figures.append(info(f"first simulate() + simulate_batch() here ({how})", first, "s"))

    t_numba = best_time_s(lambda: plant.simulate(drive, FS_HZ, model), repeats=5)
    t_python = best_time_s(lambda: python_rk4(drive, FS_HZ, model), repeats=5)
    ref_stroke, ref_pitch = python_rk4(drive, FS_HZ, model)
    out = plant.simulate(drive, FS_HZ, model)
    assert plant.n_substeps(model, FS_HZ)[0] == 1, (
        "the Python reference takes one RK4 step per sample"
    )
    max_diff_deg = math.degrees(
        max(np.max(np.abs(out.stroke_rad - ref_stroke)), np.max(np.abs(out.pitch_rad - ref_pitch)))
    )
    speedup = t_python / t_numba
    figures.append(
        info(
            "simulate 1 s @ 20 kHz, nominal (numba)",
            t_numba * 1e3,
            "ms",
            f"python RK4 {t_python * 1e3:.0f} ms",
        )
    )
    figures.append(
        compare(
            "speedup numba / plain Python RK4",
            speedup,
            "x",
            ">=",
            SPEEDUP_TARGET,
            f"max |diff| {max_diff_deg:.1e} deg",
        )
    )
    figures.append(
        compare(
            "numba vs plain Python RK4: max |diff| of stroke and pitch",
            max_diff_deg,
            "deg",
            "<=",
            MAX_DIFF_DEG,
            "the same RK4 step on the same samples: only rounding may differ",
        )
    )
    all_effects = with_effects(
        model,
        {
            "sensor_delay": {"delay_s": 2.3e-4},
            "charge_amp_highpass": {"corner_hz": 3.0},
            "feedthrough": {"gain_v_per_v": 2e-3},
            "transmission_nonlinearity": {"cubic_per_rad2": 0.2},
            "hinge_stiffening": {"cubic_per_rad2": 1.5},
            "structural_damping": {"damping_ratio": 0.03},
            "strain_transfer_loss": {"efficiency": 0.23},
            "collision": {"stroke_limit_deg": 30.0},
            "wing_damage": {"inertia_factor": 0.85},
        },
    )
    t_effects = best_time_s(lambda: plant.simulate(drive, FS_HZ, all_effects), repeats=5)
    figures.append(
        info(
            "simulate 1 s @ 20 kHz, all nine effects",
            t_effects * 1e3,
            "ms",
            f"nominal {t_numba * 1e3:.2f} ms",
        )
    )

    single_rate = DURATION_S / t_numba
    for count in (1, 100, 1000):
        models = parameter_sets(model, count)
        out = plant.SimOutput(*(np.empty((count, n)) for _ in range(4)))
        t_batch = best_time_s(
            lambda models=models, out=out: plant.simulate_batch(drive, FS_HZ, models, out=out),
            repeats=3,
        )
        rate = count * DURATION_S / t_batch
        figures.append(
            info(
                f"simulate_batch, {count} parameter sets (out= reused)",
                rate,
                "robot-s/s",
                f"simulate() {single_rate:.0f} robot-s/s",
            )
        )
        if count == 1000:
            figures.append(
                compare(
                    "simulate_batch, 1000 parameter sets (out= reused) / simulate() rate",
                    rate / single_rate,
                    "x",
                    ">=",
                    1.0,
                    f"{rate:.0f} against {single_rate:.0f} robot-s/s",
                )
            )
        del out
    t_fresh = best_time_s(lambda: plant.simulate_batch(drive, FS_HZ, models), repeats=2)
    figures.append(
        info(
            "simulate_batch, 1000 parameter sets (fresh outputs)",
            1000 * DURATION_S / t_fresh,
            "robot-s/s",
            "allocates 640 MB per call",
        )
    )

    print_table(figures)
    if args.json:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
