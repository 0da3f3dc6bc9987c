"""The Dask sweeps' engine: grids from config/sweeps.yaml, chunked rows run on a cluster or in
process through the compiled batch (`flaair_analysis.closed_loop`), relative and theory columns,
strict JSON and CSV out. The command is `sweep_cli`; figures and readings are `sweep_report`.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from flaair_analysis.closed_loop import DSA, DSA_STROKE, MODE_NAMES, SYNC, run_rows, warm_up
from flaair_common.strictjson import json_safe
from flaair_control.core import hopf, stroke
from flaair_model.config import ConfigError, load_yaml

SUBCOMMANDS = ("wing-damage", "dsa-map", "stroke")


class SweepError(ValueError):
    """Bad sweep input; the message names the file and key."""


def _grid(value: Any, where: str) -> list[float]:
    if isinstance(value, dict):
        try:
            return [float(x) for x in np.linspace(value["start"], value["stop"], int(value["num"]))]
        except (KeyError, TypeError, ValueError) as exc:
            raise SweepError(f"{where}: needs start, stop, num ({exc})") from None
    if isinstance(value, list) and value:
        return [float(x) for x in value]
    raise SweepError(f"{where}: expected a list or {{start, stop, num}}, got {value!r}")


def load_section(path: Path, name: str) -> dict[str, Any]:
    """A section of the sweeps file, or SweepError naming file and key."""
    try:
        document = load_yaml(path)
    except (ConfigError, OSError) as exc:
        raise SweepError(f"{path}: {exc}") from None
    if not isinstance(document, dict) or not isinstance(document.get(name), dict):
        raise SweepError(f"{path}: no '{name}:' section")
    return document[name]


# --------------------------------------------------------------------------- grids (pure)


def _common_row(values: dict[str, Any], section: dict[str, Any]) -> dict[str, Any]:
    return {
        "sample_rate_hz": float(values["sample_rate_hz"]),
        "duration_s": float(section["duration_s"]),
        "steady_s": float(section["steady_s"]),
        "start_stroke_deg": float(section["start_stroke_deg"]),
        "drive_limit_v": float(values["drive_limit_v"]),
        "hysteresis_deg": float(values["crossing_hysteresis_deg"]),
        "min_wingbeat_hz": float(values["min_wingbeat_hz"]),
        "max_wingbeat_hz": float(values["max_wingbeat_hz"]),
        "r3_rad_s": float(values["r3_rad_s"]),
        "kappa": float(values["kappa"]),
        "drive_amplitude_v": 0.0,
        "frequency_hz": 0.0,
        "mu_nm_s_per_rad": 0.0,
        "track": [0.0] * 8,
    }


def wing_damage_rows(
    section: dict[str, Any], values: dict[str, Any], model
) -> list[dict[str, Any]]:
    """One row per (aero damping exponent, inertia
    factor, drive); drives set for the undamaged wing.
    """
    try:
        factors = _grid(section["inertia_factor"], "wing_damage.inertia_factor")
        exponents = _grid(section["aero_damping_exponent"], "wing_damage.aero_damping_exponent")
        setpoint = float(section["setpoint_deg"])
    except KeyError as exc:
        raise SweepError(f"config/sweeps.yaml: wing_damage: missing key {exc}") from None
    if 1.0 not in factors:
        factors.append(1.0)  # the reference
    design_plant = stroke.StrokePlant.from_model(model)
    resonance_hz = model.plant.stroke_natural_frequency_hz
    drive_v, _ = stroke.design(design_plant, "sync", setpoint, sync_frequency_hz=resonance_hz)
    ctrl = stroke.params_from_values(
        {**values, "mode": "dsa", "setpoint_deg": setpoint},
        design_plant,
        float(values["sample_rate_hz"]),
        0.5 / float(values["sample_rate_hz"]),
    )
    base = _common_row(values, section)
    rows = []
    for exponent in exponents:
        for factor in sorted(set(factors)):
            for mode in (SYNC, DSA, DSA_STROKE):
                row = {
                    **base,
                    "sweep": "wing-damage",
                    "mode": mode,
                    "drive": MODE_NAMES[mode],
                    "inertia_factor": factor,
                    "aero_damping_exponent": exponent,
                    "aero_damping_factor": factor**exponent,
                }
                if mode == SYNC:
                    row.update(drive_amplitude_v=drive_v, frequency_hz=resonance_hz)
                else:
                    row["mu_nm_s_per_rad"] = ctrl.command_nominal
                    if mode == DSA_STROKE:
                        row["track"] = stroke.tracker_constants(ctrl).tolist()
                rows.append(row)
    return rows


def dsa_map_rows(section: dict[str, Any], values: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per (r3, kappa, mu): the free dSA loop on the undamaged wing."""
    try:
        mus = _grid(section["mu_nm_s_per_rad"], "dsa_map.mu_nm_s_per_rad")
        kappas = _grid(section["kappa"], "dsa_map.kappa")
        r3s = _grid(section["r3_rad_s"], "dsa_map.r3_rad_s")
    except KeyError as exc:
        raise SweepError(f"config/sweeps.yaml: dsa_map: missing key {exc}") from None
    base = _common_row(values, section)
    return [
        {
            **base,
            "sweep": "dsa-map",
            "mode": DSA,
            "drive": MODE_NAMES[DSA],
            "inertia_factor": 1.0,
            "aero_damping_factor": 1.0,
            "r3_rad_s": r3,
            "kappa": kappa,
            "mu_nm_s_per_rad": mu,
        }
        for r3 in r3s
        for kappa in kappas
        for mu in mus
    ]


def chunks(rows: list[dict[str, Any]], size: int) -> list[list[dict[str, Any]]]:
    """Fixed-size chunks in row order (a row's result does not depend on its chunk)."""
    if size < 1:
        raise SweepError(f"chunk_size must be >= 1, got {size}")
    return [rows[i : i + size] for i in range(0, len(rows), size)]


@dataclass(frozen=True)
class TaskSizing:
    """How many simulations one Dask task carries (config/sweeps.yaml, ``tasks:``).

    A task costs a few milliseconds to schedule (bench/bench_sweep.py), so it must compute for
    much longer: about ``task_s``. A small sweep is cut into ``tasks_per_worker`` tasks per
    worker instead, so every worker gets work and the last task leaves little idle time.
    """

    task_s: float  # target compute per task [s]
    tasks_per_worker: int  # a small sweep: this many tasks per worker [-]
    core_robot_s_per_s: float  # robot-seconds one core simulates per second (measured) [-]

    def __post_init__(self) -> None:
        for name in ("task_s", "tasks_per_worker", "core_robot_s_per_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise SweepError(
                    f"config/sweeps.yaml: tasks.{name} must be a finite number > 0, got {value!r}"
                )

    @classmethod
    def from_mapping(cls, section: dict[str, Any]) -> TaskSizing:
        try:
            return cls(
                float(section["task_s"]),
                int(section["tasks_per_worker"]),
                float(section["core_robot_s_per_s"]),
            )
        except KeyError as exc:
            raise SweepError(f"config/sweeps.yaml: tasks: missing key {exc}") from None
        except (TypeError, ValueError) as exc:
            raise SweepError(f"config/sweeps.yaml: tasks: {exc}") from None

    def chunk_size(self, rows: list[dict[str, Any]], workers: int) -> int:
        """Simulations per task for `rows` on `workers`
        workers: min(~task_s of compute, an even spread).
        """
        robot_s = max(float(r["duration_s"]) for r in rows)
        by_time = max(1, int(self.task_s * self.core_robot_s_per_s / robot_s))
        by_spread = max(1, math.ceil(len(rows) / (max(1, workers) * self.tasks_per_worker)))
        return min(by_time, by_spread)


# --------------------------------------------------------------------------- execution


def run_in_process(
    parts: list[list[dict[str, Any]]],
    model,
    progress: Callable[[int], None] = lambda n: None,
    parallel: bool = False,
) -> list[list[dict[str, Any]]]:
    """Every chunk here, one after the other (``parallel``: numba threads over each chunk)."""
    out = []
    for part in parts:
        out.append(run_rows(part, model, parallel))
        progress(1)
    return out


# One compute thread per worker process (one worker per core): numba, OpenMP and BLAS pools off.
WORKER_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


def local_cluster(workers: int | None = None):
    """A LocalCluster on 127.0.0.1: `workers` (default:
    the cores) single-threaded worker processes.
    """
    # deferred: dask.distributed (0.7 s) only for a cluster; --in-process and stroke need none
    from dask.distributed import LocalCluster

    return LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=logging.ERROR,
        worker_dashboard_address=None,
        env=dict(WORKER_ENV),
    )


def prepare_workers(client, model, row: dict[str, Any]) -> None:
    """Every worker runs one short task through the path the sweep's tasks take (kernels loaded
    from numba's cache, task machinery warmed: a worker's first task costs about a second more
    than the next).
    """
    client.gather(
        [
            client.submit(
                warm_up,
                model,
                row,
                workers=[address],
                allow_other_workers=False,
                pure=False,
                key=f"sweep-warm-up-{uuid.uuid4().hex[:8]}-{i}",
            )
            for i, address in enumerate(client.scheduler_info()["workers"])
        ]
    )


def run_on_dask(
    client,
    parts: list[list[dict[str, Any]]],
    model,
    progress: Callable[[int], None] = lambda n: None,
) -> list[list[dict[str, Any]]]:
    """Every chunk as one Dask task; results in chunk order.

    The model travels inside each task (about 1 kB pickled). Scattered once instead, it made
    every task depend on one piece of data, whose extra copies Dask's active memory manager
    removes: the scheduler then sent the tasks to the one worker holding it.
    """
    # deferred: dask.distributed (0.7 s) only for a cluster; --in-process and stroke need none
    from dask.distributed import as_completed

    # keys of this run's tasks: a later run on the same client never meets them
    run = uuid.uuid4().hex[:8]
    futures = [
        client.submit(run_rows, part, model, key=f"sweep-chunk-{run}-{i}", pure=False)
        for i, part in enumerate(parts)
    ]
    index = {f.key: i for i, f in enumerate(futures)}
    out: list[Any] = [None] * len(parts)
    try:
        for future in as_completed(futures):
            out[index[future.key]] = future.result()
            progress(1)
    finally:
        client.cancel(futures)
    return out


def execute(
    rows: list[dict[str, Any]],
    chunk_size: int | TaskSizing,
    model,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    in_process: bool = False,
    show_progress: bool = True,
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Run the rows; (rows with their results, timing).
    The cluster (if started here) is closed on return.

    `chunk_size`: simulations per task, or a `TaskSizing` that sizes them for the workers found
    (the results do not depend on it). Timing: `startup_s` (cluster, kernels, model to the
    workers) apart from `wall_s` (the tasks).
    """

    def sized(n_workers: int) -> list[list[dict[str, Any]]]:
        size = (
            chunk_size.chunk_size(rows, n_workers)
            if isinstance(chunk_size, TaskSizing)
            else int(chunk_size)
        )
        timing["chunk_size"] = size
        parts = chunks(rows, size)
        timing["tasks"] = len(parts)
        bar.total = len(parts)
        bar.refresh()
        return parts

    timing: dict[str, Any] = {
        "simulations": len(rows),
        "robot_seconds": float(sum(r["duration_s"] for r in rows)),
    }
    bar = tqdm(total=None, desc="sweep", unit="task", file=sys.stderr, disable=not show_progress)
    t0 = time.perf_counter()
    try:
        if in_process:
            timing["engine"] = "in-process"
            parts = sized(1)
            timing["startup_s"] = warm_up(model, rows[0])
            t0 = time.perf_counter()
            results = run_in_process(parts, model, bar.update)
        else:
            # deferred: dask.distributed (0.7 s) only for a cluster, not for --in-process
            from dask.distributed import Client

            cluster = None if scheduler else local_cluster(workers)
            try:
                with Client(scheduler or cluster, timeout="30s") as client:
                    timing["engine"] = f"dask {scheduler or 'LocalCluster'}"
                    timing["workers"] = len(client.scheduler_info()["workers"])
                    parts = sized(timing["workers"])
                    prepare_workers(client, model, rows[0])
                    timing["startup_s"] = time.perf_counter() - t0
                    t0 = time.perf_counter()
                    results = run_on_dask(client, parts, model, bar.update)
            finally:
                if cluster is not None:
                    cluster.close()
    finally:
        bar.close()
    timing["wall_s"] = time.perf_counter() - t0
    timing["robot_seconds_per_s"] = timing["robot_seconds"] / timing["wall_s"]
    merged = []
    for part, result in zip(parts, results, strict=True):
        for row, figures in zip(part, result, strict=True):
            merged.append({**{k: v for k, v in row.items() if k != "track"}, **figures})
    return merged, timing


# --------------------------------------------------------------------------- analysis (pure)


def add_relative(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each wing-damage row's four figures relative to the
    undamaged wing of the same drive and damping axis.
    """
    ref = {(r["drive"], r["aero_damping_exponent"]): r for r in rows if r["inertia_factor"] == 1.0}
    out = []
    for r in rows:
        base = ref[(r["drive"], r["aero_damping_exponent"])]
        lift = (r["stroke_amplitude_deg"] * r["stroke_frequency_hz"]) ** 2
        lift0 = (base["stroke_amplitude_deg"] * base["stroke_frequency_hz"]) ** 2
        out.append(
            {
                **r,
                "lift_proxy": lift,
                "frequency_rel": r["stroke_frequency_hz"] / base["stroke_frequency_hz"],
                "amplitude_rel": r["stroke_amplitude_deg"] / base["stroke_amplitude_deg"],
                "pitch_amplitude_rel": r["pitch_amplitude_deg"] / base["pitch_amplitude_deg"],
                "lift_rel": lift / lift0,
            }
        )
    return out


def add_theory(
    rows: list[dict[str, Any]], model, oscillating_deg: float
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """dsa-map rows with the Hopf/describing-function
    prediction; per (r3, kappa) the onset check.
    """
    pl = model.plant
    linear = hopf.LinearStrokePlant(pl.stroke_inertia_kg_m2, pl.stroke_stiffness_nm_per_rad)
    out, onsets = [], []
    for r in rows:
        cycle = hopf.limit_cycle(
            linear, pl.aero_damping_nm_s2, r["r3_rad_s"], r["kappa"], r["mu_nm_s_per_rad"]
        )
        oscillating = r["stroke_amplitude_deg"] > oscillating_deg and r["stroke_frequency_hz"] > 0
        theory_amp = math.degrees(cycle.amplitude_rad)
        # the theory has no drive clamp
        applies = oscillating and theory_amp > 0 and not r["drive_clamped"]
        out.append(
            {
                **r,
                "oscillating": oscillating,
                "theory_amplitude_deg": theory_amp,
                "theory_frequency_hz": cycle.frequency_hz if theory_amp > 0 else None,
                "amplitude_error_rel": (r["stroke_amplitude_deg"] / theory_amp - 1)
                if applies
                else None,
                "frequency_error_rel": (r["stroke_frequency_hz"] / cycle.frequency_hz - 1)
                if applies
                else None,
            }
        )
    for key in sorted({(r["r3_rad_s"], r["kappa"]) for r in out}):
        group = sorted(
            (r for r in out if (r["r3_rad_s"], r["kappa"]) == key),
            key=lambda r: r["mu_nm_s_per_rad"],
        )
        onset = hopf.hopf_onset(linear, key[0], key[1])
        first = next((r["mu_nm_s_per_rad"] for r in group if r["oscillating"]), None)
        last_quiet = max(
            (
                r["mu_nm_s_per_rad"]
                for r in group
                if not r["oscillating"] and (first is None or r["mu_nm_s_per_rad"] < first)
            ),
            default=None,
        )
        degenerate = math.sqrt(key[1]) * key[0] <= linear.natural_frequency_rad_s
        # degenerate (mu* = 0): small gains oscillate with small amplitudes that grow slowly;
        # the onset check applies where the Hopf threshold is positive
        consistent = (
            None
            if degenerate
            else (
                (first is None or onset.mu_nm_s_per_rad <= first)
                and (last_quiet is None or onset.mu_nm_s_per_rad >= last_quiet)
            )
        )
        onsets.append(
            {
                "r3_rad_s": key[0],
                "kappa": key[1],
                "theory_onset_mu_nm_s_per_rad": onset.mu_nm_s_per_rad,
                "theory_onset_frequency_hz": onset.frequency_hz,
                "degenerate": degenerate,
                "simulated_onset_between": [last_quiet, first],
                "onset_consistent": consistent,
            }
        )
    return out, onsets


# --------------------------------------------------------------------------- output


def write_json(path: Path, document: dict[str, Any]) -> None:
    """Strict JSON (NaN/inf -> null)."""
    path.write_text(json.dumps(json_safe(document), indent=1, allow_nan=False) + "\n")


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """One line per row, the union of the keys as columns."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, columns)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if v is None else v) for k, v in json_safe(r).items()})
