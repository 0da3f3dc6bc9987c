"""Stroke-controller experiments on the simulated robot:
closed loop, recorded as bags, analysed from the bags.

The loop is the one the ROS lockstep graph computes, block by block, with the pure cores:
plant.step -> frontend.step -> stroke.step -> safety.step -> plant (one block in flight: the
drive computed from wing-state block k is applied during block k + 1). Each run is written as
a rosbag2 (MCAP) bag with the recorder's topics and message types (/flaair/drive,
/flaair/sensor_v, /flaair/wing_state, /flaair/wing_state/truth, /flaair/controller/state,
/flaair/run_marker); the setpoint schedule and the event time travel in the bag's custom_data
("flaair.stroke_experiment"). ``analyse_bag`` reads everything it reports from the bag:
per-wingbeat amplitude of the estimated stroke, settling time in wingbeats after the event,
steady error in degrees.

Experiments (config/sweeps.yaml, stroke_experiments): a setpoint step, a wing that loses 30 % of
its inertia mid-run, an obstacle that clips the stroke.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from flaair_analysis import wingbeat
from flaair_common import topics
from flaair_common.qos import BLOCK_STREAM, STATUS
from flaair_control.core import safety, stroke
from flaair_control.core.dsa import loop_delay_s
from flaair_control.core.transition import CrossingFrequency
from flaair_model.model import Model
from flaair_sensors.core import frontend
from flaair_sensors.frontend_io import frontend_params_from_config as frontend_params
from flaair_sim.core import plant
from flaair_tools import bagio

CUSTOM_KEY = "flaair.stroke_experiment"
DRIVE_TYPE = "flaair_msgs/msg/DriveCommandBlock"
SENSOR_TYPE = "flaair_msgs/msg/SensorVoltageBlock"
WING_TYPE = "flaair_msgs/msg/WingStateBlock"
STATE_TYPE = "flaair_msgs/msg/ControllerState"


@dataclass(frozen=True)
class Experiment:
    """One run: setpoint before/after the event, and what happens to the robot at the event."""

    name: str
    description: str
    mode: str
    duration_s: float
    event_s: float
    setpoint_before_deg: float
    setpoint_after_deg: float
    inertia_factor: float | None = None
    obstacle_stroke_limit_deg: float | None = None


def experiments_from_config(
    section: dict[str, Any], modes: list[str] | None = None
) -> list[Experiment]:
    """The experiments of config/sweeps.yaml
    ``stroke_experiments`` (one per experiment and mode).
    """
    out = []
    for mode in modes or section["modes"]:
        for name, spec in section["experiments"].items():
            before, after = spec["setpoint_deg"]
            out.append(
                Experiment(
                    f"{name}_{mode}",
                    spec["description"],
                    mode,
                    float(section["duration_s"]),
                    float(section["event_s"]),
                    float(before),
                    float(after),
                    spec.get("inertia_factor"),
                    spec.get("obstacle_stroke_limit_deg"),
                )
            )
    return out


def _robot_after(model: Model, exp: Experiment) -> Model:
    effects = dict(model.effects)
    if exp.inertia_factor is not None:
        effects["wing_damage"] = {"inertia_factor": exp.inertia_factor}
    if exp.obstacle_stroke_limit_deg is not None:
        effects["collision"] = {"stroke_limit_deg": exp.obstacle_stroke_limit_deg}
    return replace(model, effects=effects)


def _design(
    design_plant: stroke.StrokePlant, mode: str, setpoint_deg: float, values: dict[str, Any]
) -> tuple[Any, Any]:
    """The stroke controller's feed-forward and gain for `setpoint_deg` (`stroke.design`)."""
    return stroke.design(
        design_plant,
        mode,
        setpoint_deg,
        sync_frequency_hz=values["sync_frequency_hz"],
        r3_rad_s=values["r3_rad_s"],
        kappa=values["kappa"],
    )


def _loop_params(
    exp: Experiment, model: Model, values: dict[str, Any], frontend_values: dict[str, Any]
) -> tuple[Any, stroke.StrokePlant, Any, safety.SafetyParams]:
    """The front end's, the stroke controller's (designed on the model, for the loop's delay)
    and the drive guard's parameters.
    """
    fs, n = float(values["sample_rate_hz"]), int(values["block_size"])
    fp = frontend_params(frontend_values, fs)
    design_plant = stroke.StrokePlant.from_model(model)
    velocity_delay = frontend.estimate_delay_s(fp, values["compensation_frequency_hz"])[
        "stroke_velocity_s"
    ]
    delay = loop_delay_s(n * int(values["blocks_in_flight"]), fs, velocity_delay * fs)
    params = stroke.params_from_values(
        {**values, "mode": exp.mode, "setpoint_deg": exp.setpoint_before_deg},
        design_plant,
        fs,
        delay,
    )
    guard = safety.SafetyParams(
        values["drive_limit_v"],
        values["slew_limit_v_per_s"],
        values["invalid_timeout_s"],
        values["ramp_down_s"],
        fs,
    )
    return fp, design_plant, params, guard


def _record_block(
    out: dict[str, np.ndarray], part: slice, drive: np.ndarray, sim: Any, est: Any
) -> None:
    """One block's drive, plant outputs and front-end estimates into the run's records."""
    out["drive_v"][part] = drive
    out["stroke_sensor_v"][part] = sim.stroke_sensor_v
    out["pitch_sensor_v"][part] = sim.pitch_sensor_v
    out["true_stroke_deg"][part] = np.degrees(sim.stroke_rad)
    out["true_pitch_deg"][part] = np.degrees(sim.pitch_rad)
    out["stroke_deg"][part] = np.degrees(est.stroke_rad)
    out["pitch_deg"][part] = np.degrees(est.pitch_rad)
    out["stroke_velocity_deg_s"][part] = np.degrees(est.stroke_velocity_rad_s)
    out["stroke_valid"][part], out["pitch_valid"][part] = est.stroke_valid, est.pitch_valid


def run_closed_loop(
    exp: Experiment, model: Model, values: dict[str, Any], frontend_values: dict[str, Any]
) -> dict[str, np.ndarray]:
    """Run one experiment in lockstep; per-sample signals and per-block controller state (pure).

    ``values``: the stroke_controller_node parameters (config/flaair.yaml, with the shared
    sample_rate_hz, block_size, drive_limit_v); ``frontend_values``: the frontend_node ones.
    """
    fs, n = float(values["sample_rate_hz"]), int(values["block_size"])
    fp, design_plant, params, guard = _loop_params(exp, model, values, frontend_values)
    blocks = round(exp.duration_s * fs / n)
    event_block = round(exp.event_s * fs / n)
    after = _robot_after(model, exp)
    p_state = plant.initial_state(plant.PlantStepParams(model, fs))
    f_state = frontend.initial_state(fp)
    c_state = stroke.initial_state(params)
    g_state = safety.initial_state(guard)
    frequency = CrossingFrequency(fs, values["crossing_hysteresis_deg"])
    keys = (
        "drive_v",
        "stroke_sensor_v",
        "pitch_sensor_v",
        "stroke_deg",
        "pitch_deg",
        "stroke_velocity_deg_s",
        "stroke_valid",
        "pitch_valid",
        "true_stroke_deg",
        "true_pitch_deg",
    )
    out = {k: np.empty(blocks * n, dtype=bool if k.endswith("valid") else float) for k in keys}
    per_block = {
        k: np.empty(blocks)
        for k in (
            "command",
            "setpoint_deg",
            "drive_last_v",
            "frequency_hz",
            "kr",
            "tripped",
            "clamped",
        )
    }
    drive = np.zeros(n)
    for k in range(blocks):
        robot = after if k >= event_block else model
        if k == event_block and exp.setpoint_after_deg != exp.setpoint_before_deg:
            u_ff, epsilon = _design(design_plant, exp.mode, exp.setpoint_after_deg, values)
            params = stroke.retarget(params, exp.setpoint_after_deg, u_ff, epsilon)
        p_state, sim = plant.step(
            p_state, plant.PlantInputs(drive), plant.PlantStepParams(robot, fs)
        )
        f_state, est = frontend.step(
            f_state, frontend.FrontendInputs(sim.stroke_sensor_v, sim.pitch_sensor_v), fp
        )
        part = slice(k * n, (k + 1) * n)
        _record_block(out, part, drive, sim, est)
        c_state, c_out = stroke.step(
            c_state,
            stroke.StrokeInputs(
                est.stroke_rad, est.stroke_velocity_rad_s, est.stroke_valid, (k + 1) * n
            ),
            params,
        )
        raw = c_out.drive_v
        g_state, guarded = safety.step(
            g_state, safety.SafetyInputs(raw, (k + 1) * n / fs, bool(est.stroke_valid.all())), guard
        )
        drive = guarded.drive_v
        t_next = (k + 1) * n / fs
        kr = (
            1.0
            if exp.mode == "sync"
            else float(params.dsa_params.kr_schedule.value(np.array([t_next]))[0])
        )
        for name, value in (
            ("command", stroke.command(c_state, params)),
            ("setpoint_deg", params.setpoint_deg),
            ("drive_last_v", drive[-1]),
            ("frequency_hz", frequency.update(out["stroke_deg"][part])),
            ("kr", kr),
            ("tripped", float(guarded.tripped)),
            ("clamped", float(np.abs(raw).max() > guard.drive_limit_v)),
        ):
            per_block[name][k] = value
    return {
        **out,
        **{f"block_{k}": v for k, v in per_block.items()},
        "sample_rate_hz": np.array(fs),
        "block_size": np.array(n),
        "command_nominal_before": np.array(
            _design(design_plant, exp.mode, exp.setpoint_before_deg, values)[0]
        ),
    }


def _write_block(
    writer: Any, store: Any, run: dict[str, np.ndarray], k: int, qos: tuple[list[Any], list[Any]]
) -> None:
    """Block k of the run on the recorder's topics: drive, sensors, both wing states (estimate
    and truth) and the controller's state.
    """
    fs, n = float(run["sample_rate_hz"]), int(run["block_size"])
    stream, status = qos
    wing = store.types[WING_TYPE]
    part = slice(k * n, (k + 1) * n)
    stamp = round(k * n * 1e9 / fs)

    def header(frame: str) -> Any:
        return bagio.new_message(
            "std_msgs/msg/Header", store, stamp=bagio.time_msg(stamp, store), frame_id=frame
        )

    def write(topic: str, kind: str, frame: str, qos_of: list[Any], **fields: Any) -> None:
        message = bagio.new_message(kind, store, header=header(frame), **fields)
        writer.write_message(topic, stamp, message, qos_of)

    common = dict(sample_rate_hz=fs, first_sample_index=k * n)
    write(topics.DRIVE, DRIVE_TYPE, "", stream, drive_v=run["drive_v"][part].copy(), **common)
    write(
        topics.SENSOR_VOLTAGE,
        SENSOR_TYPE,
        topics.FRAME_ID,
        stream,
        stroke_sensor_v=run["stroke_sensor_v"][part].copy(),
        pitch_sensor_v=run["pitch_sensor_v"][part].copy(),
        **common,
    )
    for topic, source, prefix in (
        (topics.WING_STATE, wing.SOURCE_SENSOR_ESTIMATE, ""),
        (topics.WING_STATE_TRUTH, wing.SOURCE_GROUND_TRUTH, "true_"),
    ):
        estimate = not prefix
        write(
            topic,
            WING_TYPE,
            topics.FRAME_ID,
            stream,
            source=source,
            stroke_deg=run[f"{prefix}stroke_deg"][part].copy(),
            pitch_deg=run[f"{prefix}pitch_deg"][part].copy(),
            stroke_velocity_deg_s=(
                run["stroke_velocity_deg_s"][part].copy() if estimate else np.full(n, np.nan)
            ),
            stroke_valid=run["stroke_valid"][part].copy() if estimate else np.ones(n, bool),
            pitch_valid=run["pitch_valid"][part].copy() if estimate else np.ones(n, bool),
            **common,
        )
    write(
        topics.CONTROLLER_STATE,
        STATE_TYPE,
        "",
        status,
        k_r=float(run["block_kr"][k]),
        async_drive_v=0.0,
        sync_drive_v=0.0,
        drive_v=float(run["block_drive_last_v"][k]),
        drive_clamped=bool(run["block_clamped"][k]),
        watchdog=int(run["block_tripped"][k]),
        fault="",
        amplitude_scale=float(run["block_command"][k] / run["command_nominal_before"]),
        stroke_frequency_hz=float(run["block_frequency_hz"][k]),
    )


def write_bag(path: Path, exp: Experiment, run: dict[str, np.ndarray]) -> Path:
    """Record one run as a rosbag2 MCAP bag (the
    recorder's topics and types; see module docstring).
    """
    store = bagio.typestore()
    fs, n = float(run["sample_rate_hz"]), int(run["block_size"])
    blocks = run["drive_v"].size // n
    qos = ([bagio.qos_from_rclpy(BLOCK_STREAM)], [bagio.qos_from_rclpy(STATUS)])
    marker = bagio.RunMarker(
        run=exp.name,
        first_sample_index=0,
        n_samples=blocks * n,
        source_file="",
        sample_rate_hz=fs,
        start_ns=0,
    )
    described = {
        "experiment": exp.name,
        "description": exp.description,
        "mode": exp.mode,
        "event_s": exp.event_s,
        "setpoint_before_deg": exp.setpoint_before_deg,
        "setpoint_after_deg": exp.setpoint_after_deg,
        "inertia_factor": exp.inertia_factor,
        "obstacle_stroke_limit_deg": exp.obstacle_stroke_limit_deg,
    }
    with bagio.BagWriter(path, store=store) as writer:
        writer.set_custom_data(CUSTOM_KEY, json.dumps(described, allow_nan=False))
        writer.set_custom_data(bagio.RUNS_CUSTOM_KEY, json.dumps([json.loads(marker.to_json())]))
        writer.write_message(
            bagio.RUN_MARKER_TOPIC,
            0,
            bagio.new_message(bagio.RUN_MARKER_TYPE, store, data=marker.to_json()),
        )
        for k in range(blocks):
            _write_block(writer, store, run, k, qos)
    return path


def analyse_bag(
    bag: Path, band_deg: float, steady_wingbeats: int, beats: wingbeat.WingbeatParams
) -> dict[str, Any]:
    """Settling time (wingbeats after the event until every later amplitude stays within
    ``band_deg`` of the setpoint) and steady error (mean amplitude - setpoint over the last
    ``steady_wingbeats``), for the estimate (what the controller holds) and the truth.
    """
    info = bagio.bag_info(bag)
    spec = json.loads(info.custom_data[CUSTOM_KEY])
    result: dict[str, Any] = {"bag": str(bag), **spec}
    for key, topic in (("estimate", topics.WING_STATE), ("truth", topics.WING_STATE_TRUTH)):
        blocks = bagio.read_blocks(bag, topic)
        valid = blocks["stroke_valid"] & blocks["pitch_valid"]
        summary = wingbeat.summarize(
            blocks["stroke_deg"], blocks["pitch_deg"], valid, beats, blocks.first_sample_index
        )
        t_end = summary.end_sample / blocks.sample_rate_hz
        amp, freq = summary.amplitude_deg, summary.frequency_hz
        after = t_end > spec["event_s"]
        err = amp - np.where(after, spec["setpoint_after_deg"], spec["setpoint_before_deg"])
        outside = np.nonzero(after & (np.abs(err) > band_deg))[0]
        first_after = int(np.argmax(after)) if after.any() else len(amp)
        settle = 0 if outside.size == 0 else int(outside[-1] + 1 - first_after)
        settled = outside.size == 0 or outside[-1] < len(amp) - steady_wingbeats
        tail = slice(len(amp) - steady_wingbeats, len(amp))
        result[key] = {
            "settling_wingbeats": settle if settled else None,
            "steady_error_deg": float(np.mean(err[tail])),
            "steady_amplitude_deg": float(np.mean(amp[tail])),
            "steady_frequency_hz": float(np.mean(freq[tail])),
            "wingbeat_time_s": t_end.tolist(),
            "wingbeat_amplitude_deg": amp.tolist(),
        }
    clamped = sum(
        bool(m.drive_clamped) for _, _, m in bagio.iter_messages(bag, [topics.CONTROLLER_STATE])
    )
    drive = bagio.read_blocks(bag, topics.DRIVE)["drive_v"]
    result["max_abs_drive_v"] = float(np.abs(drive).max())
    result["clamped_blocks"] = int(clamped)
    return result
