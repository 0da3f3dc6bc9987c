"""What the Foxglove live view publishes: per-sample messages, the wingbeat summary, the layout.

The Foxglove Plot panel draws a time series from one number per message, placed at the
message's log time (`timestampMethod: receiveTime`, the WebSocket message timestamp for a
live connection) or at a time field inside it (`headerStamp` / `customField`). A 10-sample
block would show up as the array elements `stroke_deg[0..9]`, so every block is split into
one message per sample whose log time, and whose ``stamp`` field, is that sample's own
signal time: header stamp + k / sample_rate_hz.

Per-sample messages are ROS 2 CDR with a ``ros2msg`` schema (what foxglove_bridge serves, so
Foxglove and Lichtblick decode them natively); the blocks received in one serve period are
decoded and encoded in one numpy call per stream (`fixed_blocks`, `blocks_samples`): per block,
numpy's call overhead cost more than the data (60 us a block, 0.5 CPU-s/s at 8,000 blocks/s). The
wingbeat summary and the collision status are JSON (a few messages per wingbeat).

Pure module: numpy and the SDK's layout types, no rclpy.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from flaair_analysis.wingbeat import (
    WingbeatInputs,
    WingbeatParams,
    Wingbeats,
    WingbeatState,
    step,
)
from flaair_common import cdr, topics

LIVE_PREFIX = "/flaair/live"
TIME_DEFINITION = "=" * 80 + "\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"


@dataclass(frozen=True)
class SampleStream:
    """One per-sample channel: its topic, ros2msg schema and the CDR record of one sample."""

    topic: str
    schema_name: str
    fields: tuple[tuple[str, str], ...]  # (name, "float64" | "bool") after the leading stamp

    @property
    def definition(self) -> str:
        """The ros2msg text (with the Time dependency) Foxglove decodes the CDR with."""
        lines = ["builtin_interfaces/Time stamp"] + [f"{kind} {name}" for name, kind in self.fields]
        return "\n".join(lines) + "\n" + TIME_DEFINITION

    @property
    def dtype(self) -> np.dtype:
        """Structured dtype of one encoded sample: encapsulation, stamp, fields (CDR alignment)."""
        names, formats, offsets = (
            ["encapsulation", "sec", "nanosec"],
            [("u1", 4), "<i4", "<u4"],
            [0, 4, 8],
        )
        offset = 12
        for name, kind in self.fields:
            size = 8 if kind == "float64" else 1
            offset += (-(offset - 4)) % size
            (
                names.append(name),
                formats.append("<f8" if kind == "float64" else "?"),
                offsets.append(offset),
            )
            offset += size
        return np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": offset}
        )


WING_SAMPLE = (
    "flaair_live/msg/WingSample",
    (
        ("stroke_deg", "float64"),
        ("pitch_deg", "float64"),
        ("stroke_velocity_deg_s", "float64"),
        ("stroke_valid", "bool"),
        ("pitch_valid", "bool"),
    ),
)
STREAMS = {
    "wing_state": SampleStream(f"{LIVE_PREFIX}/wing_state", *WING_SAMPLE),
    "wing_state_truth": SampleStream(f"{LIVE_PREFIX}/wing_state/truth", *WING_SAMPLE),
    "sensor_v": SampleStream(
        f"{LIVE_PREFIX}/sensor_v",
        "flaair_live/msg/SensorSample",
        (("stroke_sensor_v", "float64"), ("pitch_sensor_v", "float64")),
    ),
    "drive": SampleStream(
        f"{LIVE_PREFIX}/drive", "flaair_live/msg/DriveSample", (("drive_v", "float64"),)
    ),
}
WINGBEAT_TOPIC = f"{LIVE_PREFIX}/wingbeat"
COLLISION_TOPIC = f"{LIVE_PREFIX}/collision_status"
# ROS topics served as they are, under their own names: each message's CDR bytes with its
# type's ros2msg definition (Foxglove decodes them natively), at its header stamp
RELAYED = {
    topics.HEALTH_STATUS: "flaair_msgs/msg/HealthStatus",  # one per wingbeat
    topics.HEALTH_EVENTS: "flaair_msgs/msg/HealthEvent",  # each change the monitor detected
}
DIAGNOSTICS_TOPIC = "/diagnostics"
WINGBEAT_SCHEMA = {
    "title": "flaair_live.Wingbeat",
    "type": "object",
    "properties": {
        "stamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
            "description": "signal time of the wingbeat's end",
        },
        "wingbeat_index": {
            "type": "integer",
            "description": "wingbeats summarised since the live view started",
        },
        "duration_s": {"type": "number"},
        "frequency_hz": {"type": "number"},
        "amplitude_deg": {"type": "number", "description": "stroke amplitude, half peak-to-peak"},
        "pitch_amplitude_deg": {
            "type": "number",
            "description": "pitch amplitude, half peak-to-peak",
        },
        "collision_score": {
            "type": ["number", "null"],
            "description": "spectral RMSE / threshold: >= 1 colliding",
        },
        "colliding": {"type": ["boolean", "null"]},
        "k_r": {
            "type": ["number", "null"],
            "description": "dSA blend: 1 synchronous, 0 asynchronous",
        },
    },
}

COLLISION_SCHEMA = {
    "title": "flaair_live.CollisionStatus",
    "type": "object",
    "properties": {
        "stamp": {"type": "object"},
        "wingbeat_index": {"type": "integer"},
        "colliding": {"type": "boolean"},
        "spectrum_rmse_deg": {"type": ["number", "null"]},
        "threshold_deg": {"type": ["number", "null"]},
        "collision_score": {"type": ["number", "null"]},
    },
}


def served_topics() -> list[str]:
    """Every channel the live view serves."""
    per_sample = [stream.topic for stream in STREAMS.values()]
    return [*per_sample, WINGBEAT_TOPIC, COLLISION_TOPIC, *RELAYED, DIAGNOSTICS_TOPIC]


def sample_indices(first_sample_index: int, length: int, decimation: int) -> np.ndarray:
    """Positions within a block of the samples to publish: those whose stream index is a multiple
    of `decimation` (so the kept samples are evenly spaced across blocks).
    """
    return np.arange((-first_sample_index) % decimation, length, decimation)


def sample_times_ns(stamp_ns: int, positions: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Signal time of each chosen sample: the block's header stamp + k / sample_rate_hz."""
    return stamp_ns + np.round(positions * (1e9 / sample_rate_hz)).astype(np.int64)


def encode_samples(
    stream: SampleStream, times_ns: np.ndarray, values: dict[str, np.ndarray]
) -> bytes:
    """All chosen samples of a block as consecutive CDR
    messages (each ``stream.dtype.itemsize`` bytes).
    """
    records = np.zeros(times_ns.size, dtype=stream.dtype)
    records["encapsulation"] = (0, 1, 0, 0)
    records["sec"], records["nanosec"] = np.divmod(times_ns, 1_000_000_000)
    for name, _ in stream.fields:
        records[name] = values[name]
    return records.tobytes()


def block_samples(
    stream: SampleStream, message, stamp_ns: int, decimation: int
) -> tuple[list[int], list[bytes]]:
    """(log times ns, one CDR message each) of the chosen samples of a decoded block message."""
    first, rate = int(message["first_sample_index"]), float(message["sample_rate_hz"])
    positions = sample_indices(first, len(message[stream.fields[0][0]]), decimation)
    times = sample_times_ns(stamp_ns, positions, rate)
    return _split(
        stream,
        times,
        encode_samples(
            stream, times, {name: message[name][positions] for name, _ in stream.fields}
        ),
    )


def blocks_samples(
    stream: SampleStream, blocks: np.ndarray, decimation: int
) -> tuple[list[int], list[bytes]]:
    """`block_samples` of many blocks at once, in their order: `blocks` are the records of a
    `flaair_common.cdr.FixedCodec` (``sec``, ``nanosec``, ``first_sample_index``,
    ``sample_rate_hz``, the stream's fields as (blocks, block size) arrays); one numpy pass
    encodes them all, so a batch costs about what one block did.
    """
    first = blocks["first_sample_index"].astype(np.int64)[:, None]
    position = np.arange(blocks[stream.fields[0][0]].shape[1])
    chosen = (first + position) % decimation == 0
    stamp_ns = blocks["sec"].astype(np.int64) * 1_000_000_000 + blocks["nanosec"].astype(np.int64)
    times = (
        stamp_ns[:, None]
        + np.round(position * (1e9 / blocks["sample_rate_hz"][:, None])).astype(np.int64)
    )[chosen]
    return _split(
        stream,
        times,
        encode_samples(stream, times, {name: blocks[name][chosen] for name, _ in stream.fields}),
    )


def fixed_blocks(
    layout: cdr.Layout, datas: list[bytes], codecs: dict
) -> tuple[list[np.ndarray], int]:
    """Block messages as records of a `flaair_common.cdr.FixedCodec`, one array per message size
    (in arrival order within each), decoded in one call each (`cdr.decode_batch`, `codecs` its
    cache); and how many are no CDR of the layout's fixed size.
    """
    groups, unfit = cdr.decode_batch(layout, datas, codecs)
    return [records for _, records in groups], len(unfit)


def blocks_end_ns(blocks: np.ndarray, field: str) -> int:
    """Signal time just after the last sample of the
    latest of `blocks` (records with `field` samples).
    """
    stamp_ns = blocks["sec"].astype(np.int64) * 1_000_000_000 + blocks["nanosec"].astype(np.int64)
    return int(
        np.max(
            stamp_ns
            + np.round(blocks[field].shape[1] * 1e9 / blocks["sample_rate_hz"]).astype(np.int64)
        )
    )


def contiguous_runs(blocks: np.ndarray, field: str) -> list[slice]:
    """Runs of `blocks` each continuing the previous
    one's samples (split where the stream skips).
    """
    first = blocks["first_sample_index"].astype(np.int64)
    breaks = np.flatnonzero(first[1:] != first[:-1] + blocks[field].shape[1]) + 1
    edges = [0, *breaks.tolist(), len(blocks)]
    return [slice(a, b) for a, b in itertools.pairwise(edges)]


def _split(
    stream: SampleStream, times_ns: np.ndarray, payload: bytes
) -> tuple[list[int], list[bytes]]:
    size = stream.dtype.itemsize
    return times_ns.tolist(), [payload[i : i + size] for i in range(0, len(payload), size)]


def decode_sample(stream: SampleStream, data: bytes) -> dict[str, float | bool | int]:
    """One per-sample message back to a dict with ``stamp_ns`` (for tests and tools)."""
    record = np.frombuffer(data, dtype=stream.dtype, count=1)[0]
    out: dict[str, float | bool | int] = {
        "stamp_ns": int(record["sec"]) * 1_000_000_000 + int(record["nanosec"])
    }
    out.update({name: record[name].item() for name, _ in stream.fields})
    return out


def _number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def wingbeat_messages(
    beats: Wingbeats,
    first_index: int,
    stamp0_ns: int,
    first_sample0: int,
    sample_rate_hz: float,
    colliding: bool | None,
) -> list[tuple[int, bytes]]:
    """(log time ns, strict JSON bytes) per completed wingbeat; its time is the wingbeat's end.

    stamp0_ns / first_sample0: a block's header stamp and first sample index (signal time of
    sample i = stamp0 + (i - first_sample0) / fs).
    """
    out = []
    for k in range(beats.end_sample.size):
        end_ns = stamp0_ns + round((beats.end_sample[k] - first_sample0) * 1e9 / sample_rate_hz)
        message = {
            "stamp": {"sec": end_ns // 1_000_000_000, "nsec": end_ns % 1_000_000_000},
            "wingbeat_index": first_index + k,
            "duration_s": float((beats.end_sample[k] - beats.start_sample[k]) / sample_rate_hz),
            "frequency_hz": _number(beats.frequency_hz[k]),
            "amplitude_deg": _number(beats.amplitude_deg[k]),
            "pitch_amplitude_deg": _number(beats.pitch_amplitude_deg[k]),
            "collision_score": _number(beats.collision_score[k]),
            "colliding": colliding,
            "k_r": _number(beats.k_r[k]),
        }
        out.append((end_ns, json.dumps(message, allow_nan=False).encode()))
    return out


def wingbeat_batch(
    state: WingbeatState,
    blocks: np.ndarray,
    first_index: int,
    collision_score: float,
    k_r: float,
    colliding: bool | None,
    params: WingbeatParams,
) -> tuple[WingbeatState, list[tuple[int, bytes]]]:
    """`wingbeat.step` over wing-state block records (one step per run of contiguous blocks, so the
    same wingbeats as block by block) and their `wingbeat_messages`, numbered from `first_index`.
    """
    out: list[tuple[int, bytes]] = []
    for run in contiguous_runs(blocks, "stroke_deg"):
        part = blocks[run]
        first, rate = int(part["first_sample_index"][0]), float(part["sample_rate_hz"][0])
        stamp_ns = int(part["sec"][0]) * 1_000_000_000 + int(part["nanosec"][0])
        valid = np.logical_and(part["stroke_valid"], part["pitch_valid"]).ravel()
        state, beats = step(
            state,
            WingbeatInputs(
                first,
                part["stroke_deg"].ravel(),
                part["pitch_deg"].ravel(),
                valid,
                collision_score,
                k_r,
            ),
            params,
        )
        out += wingbeat_messages(beats, first_index + len(out), stamp_ns, first, rate, colliding)
    return state, out


def collision_message(
    wingbeat_index: int,
    colliding: bool,
    spectrum_rmse_deg: float,
    threshold_deg: float,
    stamp_ns: int,
) -> bytes:
    """A CollisionStatus as strict JSON for /flaair/live/collision_status."""
    score = spectrum_rmse_deg / threshold_deg if threshold_deg > 0 else math.nan
    return json.dumps(
        {
            "stamp": {"sec": stamp_ns // 1_000_000_000, "nsec": stamp_ns % 1_000_000_000},
            "wingbeat_index": int(wingbeat_index),
            "colliding": bool(colliding),
            "spectrum_rmse_deg": _number(spectrum_rmse_deg),
            "threshold_deg": _number(threshold_deg),
            "collision_score": _number(score),
        },
        allow_nan=False,
    ).encode()


def parse_host_port(text: str) -> tuple[str, int]:
    """'HOST:PORT' (or '[v6]:PORT') -> (host, port); ValueError naming the bad part."""
    host, sep, port = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host:
        raise ValueError(f"expected HOST:PORT (e.g. 127.0.0.1:8765), got {text!r}")
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"port {port!r} of {text!r} is not a number") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"port {number} of {text!r} is outside 0..65535")
    return host, number


def _plot(fl: Any, title: str, series: list[tuple[str, str]], y_label: str, window_s: float) -> Any:
    """A sliding-window plot panel of `series` ((message path, label); truth dashed)."""
    return fl.PlotPanel(
        title=title,
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(
                    value=value,
                    label=label,
                    timestamp_method="receiveTime",
                    line_style="dashed" if "truth" in label else "solid",
                )
                for value, label in series
            ],
            x_axis_val="timestamp",
            time_window_mode="sliding",
            following_view_width=window_s,
            y_axis_label=y_label,
            show_legend=True,
            legend_display="top",
        ),
    )


def _signal_panels(fl: Any) -> tuple[Any, Any, Any]:
    """The block streams: wing angles (with the truth), sensor voltages, drive."""
    ws, truth, sensor = (
        STREAMS["wing_state"].topic,
        STREAMS["wing_state_truth"].topic,
        STREAMS["sensor_v"].topic,
    )
    wing = _plot(
        fl,
        "Wing angles (front end; dashed: simulator truth)",
        [
            (f"{ws}.stroke_deg", "stroke [deg]"),
            (f"{ws}.pitch_deg", "pitch [deg]"),
            (f"{truth}.stroke_deg", "stroke truth [deg]"),
            (f"{truth}.pitch_deg", "pitch truth [deg]"),
        ],
        "angle [deg]",
        0.1,
    )
    volts = _plot(
        fl,
        "PVDF charge-amplifier outputs",
        [
            (f"{sensor}.stroke_sensor_v", "stroke sensor [V]"),
            (f"{sensor}.pitch_sensor_v", "pitch sensor [V]"),
        ],
        "voltage [V]",
        0.1,
    )
    drive = _plot(
        fl,
        "Actuator drive",
        [(f"{STREAMS['drive'].topic}.drive_v", "drive [V]")],
        "drive [V]",
        0.1,
    )
    return wing, volts, drive


def _wingbeat_panels(fl: Any) -> tuple[Any, Any, Any, Any]:
    """Per wingbeat: amplitudes, score and K_r; frequency; the monitor's state; the last one."""
    series = [
        (f"{WINGBEAT_TOPIC}.{name}", label)
        for name, label in (
            ("amplitude_deg", "stroke amplitude [deg]"),
            ("pitch_amplitude_deg", "pitch amplitude [deg]"),
            ("collision_score", "collision score (>= 1: colliding)"),
            ("k_r", "K_r (1 sync, 0 dSA)"),
        )
    ]
    beat = _plot(fl, "Per wingbeat", series, "", 5.0)
    frequency = _plot(
        fl,
        "Wingbeat frequency",
        [(f"{WINGBEAT_TOPIC}.frequency_hz", "frequency [Hz]")],
        "[Hz]",
        5.0,
    )
    states = fl.StateTransitionsPanel(
        title="Collision monitor",
        config=fl.StateTransitionsConfig(
            paths=[
                fl.StateTransitionsSeries(
                    value=f"{COLLISION_TOPIC}.colliding",
                    label="colliding",
                    timestamp_method="receiveTime",
                )
            ],
            time_window_mode="sliding",
            x_axis_range=5.0,
            show_points=True,
        ),
    )
    last = fl.RawMessagesPanel(
        title="Last wingbeat",
        config=fl.RawMessagesConfig(topic_path=WINGBEAT_TOPIC, expansion="all"),
    )
    return beat, frequency, states, last


def _health_panels(fl: Any) -> tuple[Any, Any]:
    """The health monitor's estimates with its detected changes, and its last event."""
    status, events = topics.HEALTH_STATUS, topics.HEALTH_EVENTS
    health = _plot(
        fl,
        "Health monitor: estimates (x model) and detected changes",
        [
            (f"{status}.{name}_ratio", label)
            for name, label in (
                ("wing_inertia", "wing inertia"),
                ("stroke_film_gain", "stroke film gain"),
                ("pitch_film_gain", "pitch film gain"),
            )
        ]
        + [(f"{events}.ratio", "change detected (its ratio)")],
        "ratio to the model",
        30.0,
    )
    health.config.paths[-1].show_line = False  # an event is a point, not a line
    changes = fl.RawMessagesPanel(
        title="Last health event (parameter, ratio, time)",
        config=fl.RawMessagesConfig(topic_path=events, expansion="all"),
    )
    return health, changes


def layout_json() -> str:
    """The Foxglove app layout of config/foxglove_layout.json (import it with Layout > Import)."""
    # deferred: foxglove.layouts (0.13 s) only to write the app layout; the node never needs it
    import foxglove.layouts as fl

    wing, volts, drive = _signal_panels(fl)
    beat, frequency, states, last = _wingbeat_panels(fl)
    health, changes = _health_panels(fl)

    def split(direction: str, *items: tuple[float, object]) -> Any:
        return fl.SplitContainer(
            direction=direction, items=[fl.SplitItem(proportion=p, content=c) for p, c in items]
        )

    layout = fl.Layout(
        content=split(
            "row",
            (3, split("column", (3, wing), (2, volts), (1, drive), (2, health))),
            (2, split("column", (3, beat), (2, frequency), (1, states), (2, last), (1, changes))),
        )
    )
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"
