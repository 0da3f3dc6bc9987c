"""Compile and cache every numba kernel once (run by scripts/setup_env.sh after a build).

Two groups compile at once, one process each: the plant's simulation kernels, and the rest.

Without this, the first node processes of a fresh checkout each spend 10-20 s compiling the
plant before their first block; with the cache written here they start in well under a second.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np


def _inputs() -> tuple[float, object, np.ndarray]:
    """(rate, the nominal model, a 400-sample sine drive) every group warms on."""
    from flaair_model.model_io import load_model
    from flaair_sim.core.drive import DriveParams, drive_record

    fs_hz = 20000.0
    drive = drive_record(
        DriveParams(kind="sine", amplitude_v=100.0, frequency_hz=100.0), fs_hz, 400
    )
    return fs_hz, load_model(), drive


def warm_plant() -> None:
    """The plant's simulation kernels (`run_model`, `run_batch`): the costliest to compile."""
    from flaair_model.model import with_effects
    from flaair_sim.core.plant import (
        PlantInputs,
        PlantStepParams,
        initial_state,
        simulate,
        simulate_batch,
        simulate_batch_from,
        step,
    )

    fs_hz, model, drive = _inputs()
    for m in (
        model,
        with_effects(
            model,
            {
                "collision": {"stroke_limit_deg": 20.0},
                "sensor_delay": {"delay_s": 1e-4},
                "charge_amp_highpass": {"corner_hz": 1.0},
            },
        ),
    ):
        simulate(drive, fs_hz, m)
        step(
            initial_state(PlantStepParams(m, fs_hz)),
            PlantInputs(drive[:10]),
            PlantStepParams(m, fs_hz),
        )
    simulate_batch(drive, fs_hz, [model, model])
    # identification and the discrepancy search: many models from measured initial states (the
    # costliest kernel to compile, 10-30 s, and every test worker would otherwise compile it)
    simulate_batch_from(drive, fs_hz, [model, model], np.zeros((2, 4)))


def warm_rest() -> None:
    """Every other kernel: the linearised plant, the describing functions, analysis and
    control.
    """
    fs_hz, model, drive = _inputs()
    # the plant's torques at the fundamental (the health regression, the harmonic-balance start),
    # for the nominal constants tuple and the one with discovered terms
    from dataclasses import replace

    from flaair_model.terms import DiscoveredTerm
    from flaair_sim.core.describing import stroke_dynamic_stiffness
    from flaair_sim.core.plant_params import prepare

    stiffened = replace(model, discovered=(DiscoveredTerm("cube_angle", "stroke_dynamics", -1e-5),))
    for m in (model, stiffened):
        stroke_dynamic_stiffness(prepare(m, fs_hz).params, 900.0, 0.5)
    # the discovery's ranking: the plant linearised about its motion, both constants tuples
    from flaair_sim.core.torque_response import torque_responses

    for m in (model, stiffened):
        torque_responses(
            m, drive, fs_hz, np.zeros(4), "stroke", np.zeros((drive.size, 2)), "stroke"
        )
    try:  # the offline analysis kernels
        from types import SimpleNamespace

        from flaair_analysis import wingbeat
        from flaair_analysis.discrepancy.fitting import Fold, ResidualProblem
        from flaair_model import lfilter

        # the ranking's columns of a truth channel (a stand-in run: only its channel is read)
        run = SimpleNamespace(channel=lambda _: np.zeros(20))
        ResidualProblem([run], [Fold(0, 0, 20, "all")], "stroke_deg", 1.0, False, 1).angle_columns(
            {0: np.zeros((20, 2))}
        )

        lfilter.lfilter(np.array([1.0, 0.0]), np.array([1.0, 0.0]), np.zeros(10), np.zeros(1))
        wingbeat.summarize(
            20.0 * np.sin(np.arange(2000) / 20.0),
            np.zeros(2000),
            np.ones(2000, dtype=bool),
            wingbeat.WingbeatParams(fs_hz, 2.0, 20.0, 400.0),
        )
    except Exception as exc:
        print(f"[setup] numba warm-up of the analysis kernels skipped: {exc}")
    try:
        from flaair_control.core import collision, spectral
        from flaair_control.monitor_io import (
            monitor_windows_from_config,
            spectral_metric_params_from_config,
        )

        spectral.spectral_metric(
            np.sin(np.arange(2000) / 20.0), fs_hz, 100.0, spectral_metric_params_from_config()
        )
        params = monitor_windows_from_config(100.0)
        collision.run(np.zeros(400), np.zeros(400), params)
        stroke_windows = monitor_windows_from_config(None)  # the Schmitt scan of the stroke
        wave = 20.0 * np.sin(2 * np.pi * 100.0 * np.arange(4000) / fs_hz)
        collision.run(np.radians(wave), np.zeros(4000), stroke_windows)
    except Exception as exc:
        print(f"[setup] numba warm-up of flaair_control skipped: {exc}")
    try:  # the closed loop's per-block kernels: front end, dSA filter, drive safety, supervisor
        from flaair_control.core import dsa, safety
        from flaair_control.core import supervisor as sv
        from flaair_control.dsa_io import supervisor_params_from_config
        from flaair_model.config import node_parameters
        from flaair_sensors.core import frontend
        from flaair_sensors.frontend_io import frontend_params_from_config

        fe = frontend_params_from_config(node_parameters("flaair.yaml", "frontend_node"), fs_hz)
        frontend.step(
            frontend.initial_state(fe), frontend.FrontendInputs(np.ones(10), np.ones(10)), fe
        )
        loop = supervisor_params_from_config(
            node_parameters("flaair.yaml", "dsa_controller_node"), model
        )
        dsa.step(dsa.initial_state(loop.dsa), dsa.DsaInputs(np.zeros(10), 0.0), loop.dsa)
        safety.step(
            safety.initial_state(loop.safety), safety.SafetyInputs(np.zeros(10), 0.0), loop.safety
        )
        sv.warm_up(loop)  # the drive block's one compiled call (the two cores' kernels inside)
    except Exception as exc:
        print(f"[setup] numba warm-up of the closed-loop cores skipped: {exc}")
    try:  # the health monitor's per-block kernels (the block's angles, the trigger's crossings)
        from flaair_control.core import health
        from flaair_control.health_io import health_params_from_config

        hp = health_params_from_config(model=model)
        vref = np.full(400, hp.reference_voltage_v)
        health.step(
            health.initial_state(hp),
            health.HealthInputs(vref + 0.5 * np.sin(np.arange(400) / 20.0), vref, drive),
            hp,
        )
    except Exception as exc:
        print(f"[setup] numba warm-up of the health monitor skipped: {exc}")
    try:  # the wing-damage sweep's batch kernels (the stroke tracker among them)
        from flaair_analysis import closed_loop
        from flaair_control.dsa_io import stroke_controller_values
        from flaair_model.config import config_dir
        from flaair_tools.sweeps import sweep

        rows = sweep.wing_damage_rows(
            sweep.load_section(config_dir() / "sweeps.yaml", "wing_damage"),
            stroke_controller_values(),
            model,
        )
        closed_loop.warm_up(model, rows[0])
    except Exception as exc:
        print(f"[setup] numba warm-up of the sweep kernels skipped: {exc}")


GROUPS = {"plant": warm_plant, "rest": warm_rest}


def main(argv: list[str]) -> int:
    """`--group NAME` warms one group here; with no argument both groups run at once, one process
    each (numba compiles on one core; its cache files are written atomically, so the two
    processes share the cache directory safely).
    """
    if argv[:1] == ["--group"] and len(argv) == 2 and argv[1] in GROUPS:
        GROUPS[argv[1]]()
        return 0
    if argv:
        print(f"usage: warm_numba.py [--group {'|'.join(GROUPS)}]", file=sys.stderr)
        return 2
    start = time.perf_counter()
    children = [subprocess.Popen([sys.executable, __file__, "--group", name]) for name in GROUPS]
    failed = [name for name, child in zip(GROUPS, children, strict=True) if child.wait() != 0]
    if failed:
        print(f"[setup] numba warm-up failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    print(f"[setup] numba kernels compiled and cached in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
