"""`bin/flaair sweep`: Dask gives the in-process numbers
whatever the workers; physics of the studies; files.
"""

from __future__ import annotations

import csv
import json
import math
import re
import subprocess

import pytest
import yaml

from flaair_model.config import node_parameters
from flaair_model.model_io import load_model
from flaair_tools.sweeps import sweep

WING = {
    "inertia_factor": [0.6, 0.8, 1.0],
    "aero_damping_exponent": [0.0, 1.0],
    "setpoint_deg": 15.0,
    "duration_s": 0.8,
    "steady_s": 0.15,
    "start_stroke_deg": 1.0,
    "chunk_size": 4,
}


@pytest.fixture(scope="module")
def setup():
    return load_model(), node_parameters("flaair.yaml", "stroke_controller_node")


SIZING = sweep.TaskSizing(task_s=0.3, tasks_per_worker=2, core_robot_s_per_s=800.0)


def test_task_sizing_gives_about_task_s_of_compute_or_an_even_spread() -> None:
    rows = [{"duration_s": 1.5}] * 1200
    assert SIZING.chunk_size(rows, 2) == 160  # 0.3 s x 800 robot-s/s / 1.5 robot-s
    assert SIZING.chunk_size(rows[:186], 2) == 47  # a small sweep: 2 tasks per worker
    assert SIZING.chunk_size(rows[:186], 1) == 93 and SIZING.chunk_size(rows[:3], 8) == 1
    with pytest.raises(
        sweep.SweepError, match=re.escape("tasks.task_s must be a finite number > 0")
    ):
        sweep.TaskSizing(task_s=0.0, tasks_per_worker=2, core_robot_s_per_s=800.0)
    with pytest.raises(sweep.SweepError, match="tasks: missing key 'core_robot_s_per_s'"):
        sweep.TaskSizing.from_mapping({"task_s": 0.3, "tasks_per_worker": 2})


@pytest.mark.slow  # three Dask clusters
def test_one_worker_and_two_workers_give_the_in_process_numbers_bit_for_bit(setup) -> None:
    """Chunks sized for the workers found (here 9 and 5 simulations) and a single-threaded
    worker per core: the numbers stay those of the in-process run, bit for bit.
    """
    from dask.distributed import Client

    model, values = setup
    rows = sweep.wing_damage_rows(WING, values, model)
    local, timing = sweep.execute(rows, 4, model, in_process=True, show_progress=False)
    assert timing["chunk_size"] == 4 and timing["tasks"] == 5
    results = {}
    sizes = {workers: SIZING.chunk_size(rows, workers) for workers in (1, 2)}
    assert sizes == {1: 9, 2: 5}
    for workers in (1, 2):
        cluster = sweep.local_cluster(workers)
        try:
            assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
            with Client(cluster) as client:
                assert len(client.scheduler_info()["workers"]) == workers
                assert all(
                    w.startswith("tcp://127.0.0.1:") for w in client.scheduler_info()["workers"]
                )
                assert set(
                    client.run(lambda: __import__("os").environ["NUMBA_NUM_THREADS"]).values()
                ) == {"1"}
                sweep.prepare_workers(client, model, rows[0])
                results[workers] = [
                    r
                    for part in sweep.run_on_dask(client, sweep.chunks(rows, sizes[workers]), model)
                    for r in part
                ]
        finally:
            cluster.close()
    flat_local = [
        {
            k: r[k]
            for k in (
                "stroke_frequency_hz",
                "stroke_amplitude_deg",
                "pitch_amplitude_deg",
                "final_command",
                "peak_drive_v",
                "drive_clamped",
            )
        }
        for r in local
    ]
    assert results[1] == results[2] == flat_local


def test_wing_damage_physics_dsa_follows_the_resonance_and_the_controller_holds_the_amplitude(
    setup,
) -> None:
    model, values = setup
    rows = sweep.add_relative(
        sweep.execute(
            sweep.wing_damage_rows(WING, values, model),
            4,
            model,
            in_process=True,
            show_progress=False,
        )[0]
    )
    at = {(r["drive"], r["inertia_factor"], r["aero_damping_exponent"]): r for r in rows}
    for factor in (0.6, 0.8):
        dsa = at[("dsa", factor, 0.0)]
        # K / (f I): resonance moves
        assert dsa["frequency_rel"] == pytest.approx(math.sqrt(1 / factor), rel=0.03)
        sync = at[("sync_open_loop", factor, 0.0)]
        assert (
            sync["stroke_frequency_hz"] == pytest.approx(140.0, rel=1e-3)
            and sync["amplitude_rel"] < 0.8
        )
        held = at[("dsa_stroke_control", factor, 0.0)]
        assert held["stroke_amplitude_deg"] == pytest.approx(15.0, abs=0.3)
        assert held["lift_rel"] == pytest.approx(
            held["frequency_rel"] ** 2 * held["amplitude_rel"] ** 2, rel=1e-12
        )
    assert at[("sync_open_loop", 1.0, 0.0)]["stroke_amplitude_deg"] == pytest.approx(15.0, rel=0.03)


def test_dsa_map_finds_the_hopf_onset_and_the_describing_function_limit_cycle(setup) -> None:
    model, values = setup
    section = {
        "mu_nm_s_per_rad": [1.0e-8, 5.0e-8, 1.0e-7, 3.0e-7],
        "kappa": [0.5],
        "r3_rad_s": [1400.0],
        "duration_s": 1.2,
        "steady_s": 0.2,
        "start_stroke_deg": 1.0,
        "oscillating_deg": 0.5,
        "chunk_size": 4,
    }
    rows, _ = sweep.execute(
        sweep.dsa_map_rows(section, values), 4, model, in_process=True, show_progress=False
    )
    rows, onsets = sweep.add_theory(rows, model, 0.5)
    (onset,) = onsets
    # sqrt(kappa) r3 = 990 rad/s > w_n = 880 rad/s: mu* = (1 + kappa) I (w*^2 - w_n^2) / (kappa r3)
    i, wn, w = 6.5e-11, 2 * math.pi * 140.0, math.sqrt(0.5) * 1400.0
    assert onset["theory_onset_mu_nm_s_per_rad"] == pytest.approx(
        1.5 * i * (w**2 - wn**2) / (0.5 * 1400.0), rel=1e-9
    )
    assert onset["simulated_onset_between"] == [1.0e-8, 5.0e-8] and onset["onset_consistent"]
    # 3e-7: the 150 V clamp acts
    assert [r["drive_clamped"] for r in rows] == [False, False, False, True]
    for r in rows:
        if r["oscillating"] and not r["drive_clamped"]:
            assert abs(r["frequency_error_rel"]) < 0.02 and abs(r["amplitude_error_rel"]) < 0.1


@pytest.mark.slow  # the sweep command end to end (simulations, figure) and its refusals
def test_cli_writes_strict_json_csv_figure_and_reading_and_names_bad_input(tmp_path, setup) -> None:
    config = tmp_path / "sweeps.yaml"
    config.write_text(
        yaml.safe_dump(
            {"wing_damage": {**WING, "inertia_factor": [0.7, 1.0], "aero_damping_exponent": [0.0]}}
        )
    )
    out = tmp_path / "out"
    result = subprocess.run(
        [
            "bin/flaair",
            "sweep",
            "wing-damage",
            "--out",
            str(out),
            "--config",
            str(config),
            "--in-process",
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    document = json.loads(
        (out / "sweep.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-strict {c}")
    )
    assert len(document["rows"]) == 6
    with open(out / "sweep.csv") as handle:
        lines = list(csv.DictReader(handle))
    assert [float(r["lift_rel"]) for r in lines] == [r["lift_rel"] for r in document["rows"]]
    assert (out / "wing_damage.png").stat().st_size > 10000 and "robust" in (
        out / "reading.md"
    ).read_text()
    bad = subprocess.run(
        ["bin/flaair", "sweep", "dsa-map", "--out", str(out), "--config", str(config)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (
        bad.returncode == 2
        and bad.stderr.count("\n") == 1
        and "no 'dsa_map:' section" in bad.stderr
    )


def test_the_batch_engine_refuses_a_model_with_a_collision_stop(setup) -> None:
    """The compiled batch has no contact model and no actuator hysteresis: a robot with either
    effect is refused by name, not simulated without it.
    """
    from flaair_analysis import closed_loop
    from flaair_model.model import with_effects

    model, values = setup
    row = {**sweep.wing_damage_rows(WING, values, model)[0], "duration_s": 0.02, "steady_s": 0.01}
    stopped = with_effects(model, {"collision": {"stroke_limit_deg": 20.0}})
    with pytest.raises(ValueError, match="the sweep batch has no collision stop"):
        closed_loop.run_rows([row], stopped)
    lagging = with_effects(
        model, {"actuator_hysteresis": {"loop_fraction": 0.3, "saturation_v": 10.0}}
    )
    with pytest.raises(ValueError, match="the sweep batch has no actuator hysteresis"):
        closed_loop.run_rows([row], lagging)
    assert len(closed_loop.run_rows([row], model)) == 1
