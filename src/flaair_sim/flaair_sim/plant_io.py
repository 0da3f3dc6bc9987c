"""The plant node's parameters: their one declaration,
and config values -> the model and the driver.

`PLANT_PARAMS` declares the plant_node parameters (config/flaair.yaml); `plant_models` loads
the robot's model (and its obstacle variant), `actuator_params_from_config` the pacing and
watchdog of `flaair_sim.core.actuator`, for the node and offline tools alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import lru_cache
from typing import Any

import numpy as np

from flaair_model.model import Model, with_effects
from flaair_model.model_io import load_model
from flaair_model.schema import STREAM_PARAMS, ParameterError, ParamSpec
from flaair_model.validation import ModelError
from flaair_sim.core.actuator import ActuatorParams, Command
from flaair_sim.core.damage import DamagedModels, DamageParams, damaged_models
from flaair_sim.core.scene import CameraParams, tracked_angles, tracking_generator

__all__ = [
    "ARM_S",
    "CLOCK_DEPTH",
    "CONFIG_FILE",
    "NODE_NAME",
    "PLANT_PARAMS",
    "actuator_params_from_config",
    "applied_fields",
    "camera_from_config",
    "command_of",
    "generators_from_config",
    "matched_text",
    "obstacle_windows",
    "plant_damage",
    "plant_models",
    "ready_text",
    "rejected_text",
    "sensor_fields",
    "truth_fields",
]


CONFIG_FILE = "flaair.yaml"
NODE_NAME = "plant_node"
CLOCK_DEPTH = 1000  # /clock publisher history (KEEP_LAST, reliable): 0.5 s of blocks
ARM_S = 0.05  # drive watchdog: armed after this much commanded signal time
PLANT_PARAMS = [
    *STREAM_PARAMS,
    ParamSpec(
        "drive_limit_v", float, "Actuator safe range: drive clamped to +-this [V]", 0.0, 300.0
    ),
    ParamSpec("model_file", str, "Model YAML (empty: config/model.yaml)", read_only=True),
    ParamSpec(
        "mode",
        str,
        "lockstep: one block per command block; realtime: wall clock",
        choices=("lockstep", "realtime"),
        read_only=True,
    ),
    ParamSpec("noise", bool, "Add the model's sensor-voltage noise", read_only=True),
    ParamSpec(
        "noise_seed", int, "Seed of the sensor-noise generator", 0, 2**31 - 1, read_only=True
    ),
    ParamSpec("publish_clock", bool, "Publish /clock with the simulation time", read_only=True),
    ParamSpec(
        "obstacle_windows_s",
        list,
        "Obstacle in place over these [start, end) sim-time pairs [s]",
        read_only=True,
    ),
    ParamSpec(
        "command_timeout_s",
        float,
        "lockstep: no command for this long (wall clock) while "
        "driven: zero drive, ring down (0: off) [s]",
        0.0,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "ring_down_s",
        float,
        "Signal time stepped with zero drive after a drive-watchdog trip [s]",
        0.0,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "min_sensor_subscribers",
        int,
        "Subscribe to the drive only once the sensor stream "
        "has this many matched listeners (the front end, a "
        "recorder: a lockstep source then starts no earlier) "
        "[0: at once]",
        0,
        100,
        read_only=True,
    ),
    ParamSpec(
        "min_truth_subscribers",
        int,
        "... and the ground-truth stream this many (a recorder) [0: at once]",
        0,
        100,
        read_only=True,
    ),
    ParamSpec(
        "min_clock_subscribers",
        int,
        "... and /clock this many (a recorder that records it; no /clock published: ignored) "
        "[0: at once]",
        0,
        100,
        read_only=True,
    ),
    ParamSpec(
        "truth_frame_every",
        int,
        "Ground truth as a camera sees it: one valid frame every "
        "this many samples (with the model's tracking noise when "
        "noise is on) [1: every sample]",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "damage_time_s",
        float,
        "Sim time from which the robot is damaged (the damage_* factors) [s] (< 0: never)",
        -1.0,
        1.0e6,
        read_only=True,
    ),
    ParamSpec(
        "damage_inertia_factor",
        float,
        "Wing inertia after the damage [x]",
        0.01,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "damage_stiffness_factor",
        float,
        "Stroke stiffness after the damage [x]",
        0.01,
        100.0,
        read_only=True,
    ),
    ParamSpec(
        "damage_stroke_film_gain",
        float,
        "Stroke film's V/rad after the damage [x]",
        0.01,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "damage_pitch_film_gain",
        float,
        "Pitch film's V/rad after the damage [x]",
        0.01,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "damage_actuator_gain",
        float,
        "Actuator torque per volt after the damage [x]",
        0.01,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "obstacle_stroke_limit_deg",
        float,
        "Stroke angle at which the wing strikes the obstacle [deg]",
        0.0,
        90.0,
        read_only=True,
    ),
]


def obstacle_windows(flat_s: list[float]) -> list[tuple[float, float]]:
    """[start, end) pairs from a flat list; empty pairs (end <= start) are dropped."""
    if len(flat_s) % 2:
        raise ParameterError(
            f"parameter 'obstacle_windows_s' needs start/end pairs, got {len(flat_s)} values"
        )
    return [(a, b) for a, b in zip(flat_s[0::2], flat_s[1::2], strict=True) if b > a]


def plant_models(values: Mapping[str, Any]) -> tuple[Model, Model, list[tuple[float, float]]]:
    """(model, model with the obstacle, obstacle windows) from plant_node values."""
    try:
        model = load_model(values["model_file"] or None)
    except (ModelError, OSError) as exc:
        raise ParameterError(f"parameter 'model_file': {exc}") from exc
    windows = obstacle_windows(values["obstacle_windows_s"])
    try:
        obstacle = with_effects(
            model, {"collision": {"stroke_limit_deg": values["obstacle_stroke_limit_deg"]}}
        )
    except ModelError as exc:
        raise ParameterError(f"parameter 'obstacle_stroke_limit_deg': {exc}") from exc
    return model, obstacle, windows


def actuator_params_from_config(values: Mapping[str, Any]) -> ActuatorParams:
    """The simulated driver's pacing and watchdog from plant_node values."""
    return ActuatorParams(
        values["sample_rate_hz"],
        values["block_size"],
        values["mode"],
        values["command_timeout_s"],
        values["ring_down_s"],
        ARM_S,
    )


def ready_text(
    values: Mapping[str, Any], model: Model, windows_s: list[tuple[float, float]]
) -> str:
    """The plant node's start-up log line: mode, rate, block size, effects, obstacle windows."""
    obstacle = (
        f", obstacle at {values['obstacle_stroke_limit_deg']:g} deg over {windows_s} s"
        if windows_s
        else ""
    )
    return (
        f"plant ready: {values['mode']}, {values['sample_rate_hz']:g} Hz, "
        f"{values['block_size']}-sample blocks, effects: "
        f"{', '.join(name for name, _ in model.effects) or 'none'}{obstacle}"
    )


def command_of(m: Any, t_wall: float) -> Command:
    """A /flaair/drive block's fields as the driver core's `Command`, arrived at `t_wall`."""
    return Command(t_wall, int(m["first_sample_index"]), float(m["sample_rate_hz"]), m["drive_v"])


def rejected_text(exc: Exception, count: int) -> str:
    """The warning for an undecodable command block (`count` so far)."""
    return f"rejected command block ({exc}); ignored [{count} undecodable so far]"


def matched_text(sensors: int, truths: int) -> str:
    """The log line once the outputs' listeners are matched and the drive is subscribed."""
    return f"outputs matched (sensor {sensors}, truth {truths} listener(s)): taking drive commands"


def plant_damage(values: Mapping[str, Any], model: Model, obstacle_model: Model) -> DamagedModels:
    """The damage schedule of plant_node values (damage_*), its models built once."""
    try:
        params = DamageParams(
            values["damage_time_s"],
            values["damage_inertia_factor"],
            values["damage_stiffness_factor"],
            values["damage_stroke_film_gain"],
            values["damage_pitch_film_gain"],
            values["damage_actuator_gain"],
        )
    except ValueError as exc:
        raise ParameterError(str(exc).replace("damage parameter '", "parameter 'damage_")) from exc
    return damaged_models(params, model, obstacle_model)


def applied_fields(index: int, fs_hz: float, drive_v: np.ndarray) -> dict[str, Any]:
    """A DriveCommandBlock's fields of the drive applied from the plant's sample `index`."""
    return {"sample_rate_hz": fs_hz, "first_sample_index": index, "drive_v": drive_v}


def sensor_fields(index: int, fs_hz: float, out: Any) -> dict[str, Any]:
    """A SensorVoltageBlock's fields for the plant's output `out` from sample `index`."""
    return {
        "sample_rate_hz": fs_hz,
        "first_sample_index": index,
        "stroke_sensor_v": out.stroke_sensor_v,
        "pitch_sensor_v": out.pitch_sensor_v,
    }


def truth_fields(
    index: int,
    fs_hz: float,
    out: Any,
    source: int,
    camera: CameraParams,
    tracking_rng: np.random.Generator | None,
) -> dict[str, Any]:
    """A ground-truth WingStateBlock's fields (degrees, no velocity) of the plant's output `out`
    from sample `index`, as `camera` sees them (`flaair_sim.core.scene.tracked_angles`).
    """
    every, no_velocity = _truth_constants(out.stroke_rad.size)
    stroke, pitch, valid = tracked_angles(
        index, out.stroke_rad, out.pitch_rad, camera, tracking_rng
    )
    valid = every if valid is None else valid
    return {
        "sample_rate_hz": fs_hz,
        "first_sample_index": index,
        "source": source,
        "stroke_deg": stroke,
        "pitch_deg": pitch,
        "stroke_velocity_deg_s": no_velocity,
        "stroke_valid": valid,
        "pitch_valid": valid,
    }


def camera_from_config(values: Mapping[str, Any], model: Model) -> CameraParams:
    """How the plant node's ground truth is seen, from plant_node values and the model."""
    return CameraParams(values["truth_frame_every"], model.noise.tracking_noise_deg_rms)


def generators_from_config(
    values: Mapping[str, Any],
) -> tuple[np.random.Generator | None, np.random.Generator | None]:
    """(sensor noise, tracking noise) generators of plant_node values (None: no such noise)."""
    seed = values["noise_seed"]
    sensor = np.random.default_rng(seed) if values["noise"] else None
    return sensor, tracking_generator(values["noise"], seed, values["truth_frame_every"])


@lru_cache(maxsize=8)
def _truth_constants(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every sample valid, no velocity: built once per block size, not on every block (2000/s)."""
    return np.ones(n, dtype=bool), np.full(n, np.nan)
