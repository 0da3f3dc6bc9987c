"""The health monitor's parameters (ParamSpec list, config section) and its core's params."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from flaair_common.diagnostics import OK, WARN, Health, health
from flaair_control.core import change_test
from flaair_control.core import health as hcore
from flaair_control.core.health import HealthParams
from flaair_model.config import ConfigError, load_yaml
from flaair_model.model import Model
from flaair_model.model_io import load_model
from flaair_model.schema import STREAM_PARAMS, ParameterError, ParamSpec
from flaair_model.settings import node_section
from flaair_sim.core.plant_params import prepare

CONFIG_FILE = "flaair.yaml"
NODE_NAME = "health_node"

HEALTH_PARAMS = [
    *STREAM_PARAMS,
    ParamSpec(
        "drive_topic",
        str,
        "The drive the films are compared with",
        choices=("/flaair/drive", "/flaair/drive/applied"),
        read_only=True,
    ),
    ParamSpec(
        "max_baseline_scatter",
        float,
        "A baseline scattered more than this (relative) is learned again",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "stroke_film_delay_s",
        float,
        "The stroke film's lag behind the motion (calibration's lag_s) [s]",
        0.0,
        0.01,
        read_only=True,
    ),
    ParamSpec(
        "pitch_film_delay_s",
        float,
        "The pitch film's lag behind the motion (calibration's lag_s) [s]",
        0.0,
        0.01,
        read_only=True,
    ),
    ParamSpec(
        "calibration_file",
        str,
        "A bin/flaair calibrate calibration.yaml: film lags and gains from it ('' = the "
        "*_film_delay_s and the model's films)",
        read_only=True,
    ),
    ParamSpec(
        "model_file",
        str,
        "Model the estimates are relative to ('' = config/model.yaml)",
        read_only=True,
    ),
    ParamSpec(
        "baseline_file",
        str,
        "A bin/flaair health health.json of a healthy run of this robot: its baseline judged "
        "against from the start ('' = learn one in the run)",
        read_only=True,
    ),
    ParamSpec(
        "hysteresis_rad",
        float,
        "Wingbeat trigger: Schmitt band on the stroke [rad]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "min_frequency_hz", float, "Slowest wingbeat estimated [Hz]", 1.0, 1000.0, read_only=True
    ),
    ParamSpec(
        "max_frequency_hz", float, "Fastest wingbeat estimated [Hz]", 1.0, 5000.0, read_only=True
    ),
    ParamSpec(
        "min_drive_v",
        float,
        "Quieter drive (fundamental amplitude) gives no estimate [V]",
        0.0,
        1000.0,
        read_only=True,
    ),
    ParamSpec(
        "min_stroke_rad",
        float,
        "Smaller stroke (fundamental) gives no estimate [rad]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "average_wingbeats",
        int,
        "Published estimate: mean of this many wingbeats",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "warmup_wingbeats",
        int,
        "Wingbeats skipped before (and after each event) the baseline is learned",
        0,
        100000,
        read_only=True,
    ),
    ParamSpec(
        "baseline_wingbeats",
        int,
        "Wingbeats the baseline is learned over",
        2,
        100000,
        read_only=True,
    ),
    ParamSpec(
        "detect_change",
        float,
        "Smallest relative change of a part the change test accumulates (its CUSUM drift)",
        0.001,
        0.5,
        read_only=True,
    ),
    ParamSpec(
        "false_alarms_per_hour",
        float,
        "False-alarm rate the CUSUM thresholds are derived for [1/h]",
        1e-6,
        3600.0,
        read_only=True,
    ),
    ParamSpec(
        "sigma_floor",
        float,
        "Least relative scatter a baseline pair of wingbeats is given",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "confirm_wingbeats",
        int,
        "Estimates after the change point an event averages",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "max_amplitude_change",
        float,
        "Wingbeat whose stroke or drive amplitude moved "
        "more than this fraction: transient, no estimate",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "event_significance",
        float,
        "An event's ratio must differ from 1 by more than this many of its standard errors",
        0.0,
        100.0,
        read_only=True,
    ),
]


def health_values() -> dict[str, Any]:
    """health_node's values in config/flaair.yaml, checked against its schema."""
    return node_section(HEALTH_PARAMS, NODE_NAME, CONFIG_FILE)


MAX_FILM_LAG_S = 0.01  # the range of *_film_delay_s (HEALTH_PARAMS)
MIN_GAIN_DEG_PER_V, MAX_GAIN_DEG_PER_V = 1e-6, 1e6  # a film gain beyond is a unit error


def _calibration_number(doc: Any, channel: str, key: str, where: str) -> float:
    """doc[channel][key] as a finite float, else a ParameterError naming the field."""
    try:
        section = doc[channel]
        value = section[key]
    except (KeyError, TypeError, IndexError):
        raise ParameterError(f"{where}: no {channel}.{key} in it") from None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{where}: {channel}.{key} is not a number ({value!r})") from None
    if isinstance(value, bool) or not math.isfinite(number):
        raise ParameterError(f"{where}: {channel}.{key} must be a finite number, got {value!r}")
    return number


def film_calibration(calibration: str | Path) -> dict[str, float]:
    """From a `bin/flaair calibrate` file: the films' lags (as *_film_delay_s) and, where it has
    them, their gains as volts per radian (the film gains are then ratios to the calibration's).

    Refused in one line naming the field (ParameterError): a lag that is not a finite number of
    at most `MAX_FILM_LAG_S` (a small negative lag is taken as 0), a gain outside
    `MIN_GAIN_DEG_PER_V` .. `MAX_GAIN_DEG_PER_V` (NaN and 0 among them), a polarity other than +1
    or -1.
    """
    path = Path(calibration)
    where = f"parameter 'calibration_file': {path}"
    try:
        doc = load_yaml(path)
    except (ConfigError, OSError) as exc:
        raise ParameterError(f"{where}: {exc}") from None
    if not isinstance(doc, Mapping):
        raise ParameterError(f"{where}: no stroke and pitch lag_s in it")
    out = {}
    for c in ("stroke", "pitch"):
        lag = _calibration_number(doc, c, "lag_s", where)
        if not -MAX_FILM_LAG_S <= lag <= MAX_FILM_LAG_S:
            raise ParameterError(
                f"{where}: {c}.lag_s = {lag:g} s is not a film lag (at most {MAX_FILM_LAG_S:g} s)"
            )
        out[f"{c}_film_delay_s"] = max(0.0, lag)
        if isinstance(doc[c], Mapping) and "gain_deg_per_v" in doc[c]:
            gain = _calibration_number(doc, c, "gain_deg_per_v", where)
            if not MIN_GAIN_DEG_PER_V <= gain <= MAX_GAIN_DEG_PER_V:
                raise ParameterError(
                    f"{where}: {c}.gain_deg_per_v must be a positive gain of "
                    f"{MIN_GAIN_DEG_PER_V:g} to {MAX_GAIN_DEG_PER_V:g} deg/V, got {gain:g}"
                )
            polarity = _calibration_number(doc, c, "polarity", where) if "polarity" in doc[c] else 1
            if polarity not in (1.0, -1.0):
                raise ParameterError(
                    f"{where}: {c}.polarity must be +1 or -1, got {doc[c]['polarity']!r}"
                )
            out[f"{c}_volts_per_rad"] = polarity / math.radians(gain)
    return out


def _model_digest(params: HealthParams) -> str:
    """What a baseline's ratios are relative to: the plant vector and the film gains."""
    films = np.array([params.stroke_volts_per_rad, params.pitch_volts_per_rad])
    return hashlib.sha256(params.plant.tobytes() + films.tobytes()).hexdigest()[:16]


def baseline_dict(baseline: change_test.Baseline, params: HealthParams) -> dict[str, Any]:
    """A learned baseline as health.json writes it (`read_baseline` reads it back)."""
    return {
        "watched": list(change_test.WATCHED),
        "mean": [float(x) for x in baseline.mean],
        "sigma": [float(x) for x in baseline.sigma],
        "frequency_hz": float(baseline.frequency_hz),
        "model_digest": _model_digest(params),
    }


def read_baseline(path: str | Path, params: HealthParams) -> change_test.Baseline:
    """The baseline of a `bin/flaair health` health.json (its one bag with a baseline), checked
    against `params` (the same model and film gains).

    Refused in one line naming what is wrong (ParameterError): a file that is not such a JSON,
    none or several bags with a baseline, a field missing or not finite, a baseline learned
    against another model or calibration.
    """
    where = f"parameter 'baseline_file': {path}"
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ParameterError(f"{where}: not a readable health.json ({exc})") from None
    bags = doc.get("bags") if isinstance(doc, dict) else None
    found = [b["baseline"] for b in bags or () if isinstance(b, dict) and b.get("baseline")]
    if len(found) != 1:
        raise ParameterError(
            f"{where}: {len(found)} bag(s) with a learned baseline in it; give the health.json "
            "of one healthy run (bin/flaair health BAG --out DIR)"
        )
    b = found[0]
    try:
        mean, sigma = (np.asarray(b[k], dtype=float) for k in ("mean", "sigma"))
        frequency_hz, watched = float(b["frequency_hz"]), tuple(b["watched"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ParameterError(f"{where}: baseline field missing or not a number ({exc})") from None
    n = len(change_test.WATCHED)
    if watched != change_test.WATCHED or mean.shape != (n,) or sigma.shape != (n,):
        raise ParameterError(f"{where}: baseline watches {list(watched)}, not this monitor's")
    if not (np.isfinite(mean).all() and (sigma > 0).all() and frequency_hz > 0):
        raise ParameterError(f"{where}: baseline mean, sigma > 0 and frequency_hz > 0 needed")
    if b.get("model_digest") != _model_digest(params):
        raise ParameterError(
            f"{where}: the baseline was learned against another model or film calibration "
            "(its ratios are relative to that one); give the same model_file and calibration"
        )
    return change_test.Baseline(mean, sigma, frequency_hz)


def health_params_from_config(
    values: Mapping[str, Any] | None = None, model: Model | None = None
) -> HealthParams:
    """The health core's parameters: tunables from health_node values (default: config),
    plant and film constants from `model` (default: the values' model_file).
    """
    values = health_values() if values is None else values
    if model is None:
        model = load_model(values["model_file"] or None)
    if values.get("calibration_file"):
        values = {**values, **film_calibration(values["calibration_file"])}
    params = HealthParams(
        sample_rate_hz=values["sample_rate_hz"],
        plant=prepare(model, values["sample_rate_hz"]).params,
        stroke_volts_per_rad=values.get("stroke_volts_per_rad", model.stroke_volts_per_rad),
        pitch_volts_per_rad=values.get("pitch_volts_per_rad", model.pitch_volts_per_rad),
        reference_voltage_v=model.sensors.reference_voltage_v,
        **{
            name: values[name]
            for name in (
                "hysteresis_rad",
                "min_frequency_hz",
                "max_frequency_hz",
                "min_drive_v",
                "min_stroke_rad",
                "average_wingbeats",
                "warmup_wingbeats",
                "baseline_wingbeats",
                "detect_change",
                "false_alarms_per_hour",
                "sigma_floor",
                "confirm_wingbeats",
                "event_significance",
                "max_amplitude_change",
                "max_baseline_scatter",
                "stroke_film_delay_s",
                "pitch_film_delay_s",
            )
        },
    )
    if values.get("baseline_file"):
        params = replace(params, baseline=read_baseline(values["baseline_file"], params))
    return params


def check_baseline_file(baseline_file: str | Path, calibration_file: str | Path | None) -> None:
    """Refuse, before a graph starts, a baseline the health node would refuse with the
    configured model and `calibration_file` (ParameterError or OSError naming what is wrong).
    """
    values = health_values()
    values["baseline_file"] = str(baseline_file)
    if calibration_file is not None:
        values["calibration_file"] = str(calibration_file)
    health_params_from_config(values)


class JoinState(NamedTuple):
    """Film and drive samples not yet handed to the core, each from its first sample index."""

    films: np.ndarray  # (2, m) stroke, pitch volts
    films_start: int
    drive: np.ndarray  # (k,) volts
    drive_start: int


def initial_join() -> JoinState:
    """Nothing received."""
    return JoinState(np.zeros((2, 0)), -1, np.zeros(0), -1)


def join_block(
    state: JoinState, first_index: int, films: np.ndarray | None, drive_v: np.ndarray | None
) -> tuple[JoinState, int, hcore.HealthInputs | None]:
    """Add a film block ((2, n) volts) or a drive block at `first_index`; return the samples both
    streams now hold (their first index and the core's inputs), as `bin/flaair health` joins a
    bag's streams by sample index. A block that does not continue its stream restarts it there.
    """
    if films is not None:
        if state.films_start < 0 or first_index != state.films_start + state.films.shape[1]:
            state = state._replace(films=films, films_start=first_index)
        else:
            state = state._replace(films=np.concatenate([state.films, films], axis=1))
    if drive_v is not None:
        if state.drive_start < 0 or first_index != state.drive_start + state.drive.size:
            state = state._replace(drive=drive_v, drive_start=first_index)
        else:
            state = state._replace(drive=np.concatenate([state.drive, drive_v]))
    if state.films_start < 0 or state.drive_start < 0:
        return state, -1, None
    start = max(state.films_start, state.drive_start)
    end = min(state.films_start + state.films.shape[1], state.drive_start + state.drive.size)
    if end <= start:
        # drop what the other stream has passed already
        f0 = max(0, min(state.drive_start - state.films_start, state.films.shape[1]))
        d0 = max(0, min(state.films_start - state.drive_start, state.drive.size))
        state = JoinState(
            state.films[:, f0:], state.films_start + f0, state.drive[d0:], state.drive_start + d0
        )
        return state, -1, None
    f = state.films[:, start - state.films_start : end - state.films_start]
    d = state.drive[start - state.drive_start : end - state.drive_start]
    out = JoinState(
        state.films[:, end - state.films_start :], end, state.drive[end - state.drive_start :], end
    )
    return out, start, hcore.HealthInputs(f[0], f[1], d)


def status_fields(beat: hcore.Wingbeat, offset: int) -> dict[str, Any]:
    """A HealthStatus's fields for the wingbeat `beat` (sample indices shifted by `offset`: the
    film stream's index of the monitor's first sample).
    """
    fields: dict[str, Any] = {
        "wingbeat_index": beat.wingbeat,
        "sample_index": beat.sample_index + offset,
        "wingbeat_frequency_hz": float(beat.frequency_hz),
        "valid": beat.valid,
    }
    values, errors = beat.estimate.tolist(), beat.stderr.tolist()
    for name, value, err in zip(hcore.PARAMETERS, values, errors, strict=True):
        fields[f"{name}_ratio"], fields[f"{name}_stderr"] = value, err
    return fields


def health_diagnostics(
    now: tuple[int, int, list[str], bool], before: tuple[int, int, list[str], bool] | None
) -> Health:
    """/diagnostics of the health monitor: WARN once a change was detected (naming it). A
    stretch it cannot estimate (the drive off, the wing stalled, a chirp or the K_r ramp) is
    said in the OK message, not warned: every run starts and ends with the drive off.
    """
    wingbeats, estimated, events, quiet = now
    problems = [(WARN, f"changed: {'; '.join(events)}") if events else (OK, "")]
    if quiet and wingbeats:
        calm = "no estimate now: drive off, wing stalled or transient"
    else:
        calm = "unchanged" if estimated else "waiting for the first estimate"
    return health(
        "health monitor",
        problems,
        calm,
        {"wingbeats": wingbeats, "estimated_wingbeats": estimated, "events": len(events)},
    )
