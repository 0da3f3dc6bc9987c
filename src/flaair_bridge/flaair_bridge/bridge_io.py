"""The bridge node's parameters (their values: config/flaair.yaml, section bridge_node) and its
mapping between the core's blocks and settings and the node's messages and log lines.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from flaair_bridge import udp
from flaair_bridge.core import bridge_params, bridge_state
from flaair_common.diagnostics import ERROR, OK, WARN, Health, health, loss_percent
from flaair_model.schema import STREAM_PARAMS, ParameterError, ParamSpec

__all__ = [
    "PARAMS",
    "applied_fields",
    "bridge_health",
    "drive_input",
    "open_endpoint",
    "params_from_values",
    "ready_text",
    "save_timing",
    "sensor_fields",
    "start_reading",
]


PARAMS = [
    *(p for p in STREAM_PARAMS if p.name != "block_size"),
    # the protocol's packets hold 1..1000 samples (realtime-target-protocol.md)
    ParamSpec("block_size", int, "Samples per published block", 1, 1000, read_only=True),
    ParamSpec(
        "drive_limit_v",
        float,
        "Drive clamped to +-this before it is sent [V]",
        0.0,
        300.0,
        read_only=True,
    ),
    ParamSpec("listen_host", str, "Address the target's sensor packets arrive at", read_only=True),
    ParamSpec(
        "listen_port",
        int,
        "UDP port the target's sensor packets arrive at",
        1,
        65535,
        read_only=True,
    ),
    ParamSpec(
        "target_host",
        str,
        "Where drive packets go (empty: the sender of the sensor packets)",
        read_only=True,
    ),
    ParamSpec(
        "target_port",
        int,
        "UDP port drive packets go to (0: the sender's port)",
        0,
        65535,
        read_only=True,
    ),
    ParamSpec(
        "lead_samples",
        int,
        "Drive sent this many samples ahead of the target's clock",
        0,
        100000,
        read_only=True,
    ),
    ParamSpec(
        "max_ahead_samples",
        int,
        "Drive never sent more than this beyond clock + lead",
        0,
        1000000,
        read_only=True,
    ),
    ParamSpec(
        "max_fill_samples",
        int,
        "Lost samples up to this many are published as NaN; longer gaps jump",
        0,
        10000000,
        read_only=True,
    ),
    ParamSpec(
        "resync_packets",
        int,
        "Stale packets in a row that mean the target restarted",
        1,
        1000000,
        read_only=True,
    ),
    ParamSpec(
        "drive_timeout_s",
        float,
        "Non-zero drive stream silent this long: stop packet [s]",
        1e-4,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "sensor_timeout_s",
        float,
        "Target silent this long: stop packet, samples published as lost [s]",
        1e-4,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "tick_period_s",
        float,
        "Wall-clock period of the timeout checks [s]",
        1e-4,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "receive_buffer_bytes",
        int,
        "UDP receive buffer (absorbs the bridge's stalls)",
        65536,
        1 << 30,
        read_only=True,
    ),
    ParamSpec(
        "realtime_priority",
        int,
        "SCHED_FIFO priority of the UDP reader thread (0: normal scheduling)",
        0,
        99,
        read_only=True,
    ),
    ParamSpec(
        "publish_applied",
        bool,
        "Publish the applied drive on /flaair/drive/applied",
        read_only=True,
    ),
    ParamSpec(
        "timing_file", str, "Event times (.npz) at exit for benchmarks (empty: off)", read_only=True
    ),
]


def params_from_values(values: Mapping[str, Any]) -> bridge_params.BridgeParams:
    """The core's parameters from the node's values; a refused one is a ParameterError naming it."""
    values = dict(values)
    if values["target_host"]:  # as the sender of its packets reads: an address
        try:
            values["target_host"] = socket.gethostbyname(values["target_host"])
        except OSError as exc:
            raise ParameterError(
                f"parameter 'target_host' = {values['target_host']!r}: not an address ({exc})"
            ) from exc
    try:
        return bridge_params.BridgeParams(
            **{name: values[name] for name in bridge_params.BridgeParams.__dataclass_fields__}
        )
    except bridge_params.BridgeParameterError as exc:
        raise ParameterError(str(exc)) from exc


def open_endpoint(
    values: Mapping[str, Any], on_datagram: Callable[..., None]
) -> udp.DatagramEndpoint:
    """The UDP endpoint bound on listen_host:listen_port, not reading yet (`start_reading`); a
    taken or invalid address is a parameter error.
    """
    try:
        return udp.DatagramEndpoint(
            values["listen_host"],
            values["listen_port"],
            values["receive_buffer_bytes"],
            on_datagram,
            values["realtime_priority"],
        )
    except OSError as exc:
        raise ParameterError(
            "parameters 'listen_host'/'listen_port' = "
            f"{values['listen_host']}:{values['listen_port']}: {exc}"
        ) from exc


def start_reading(endpoint: udp.DatagramEndpoint, logger: Any) -> None:
    """Start `endpoint`'s reader thread (a real-time priority refused: a warning, the bridge
    still runs).
    """
    endpoint.start()
    endpoint.priority_set.wait(1.0)
    if error := endpoint.priority_error:  # not root, no CAP_SYS_NICE
        logger.warning(f"UDP reader runs WITHOUT its real-time priority ({error})")


def ready_text(values: Mapping[str, Any]) -> str:
    """The node's start-up log line: where it listens, where it sends, lead and limit."""
    lead = values["lead_samples"]
    return (
        f"bridge ready: sensor packets on udp {values['listen_host']}:{values['listen_port']}, "
        "drive to "
        f"{values['target_host'] or '<sender>'}:{values['target_port'] or '<sender port>'}, "
        f"lead {lead} samples ({1e3 * lead / values['sample_rate_hz']:g} ms), limit "
        f"+-{values['drive_limit_v']:g} V"
    )


def sensor_fields(block: bridge_state.SensorBlock, fs_hz: float) -> dict[str, Any]:
    """A published SensorVoltageBlock's fields (for `intra.BlockPublisher.publish`)."""
    return {
        "sample_rate_hz": fs_hz,
        "first_sample_index": block.first_sample_index,
        "stroke_sensor_v": block.stroke_sensor_v,
        "pitch_sensor_v": block.pitch_sensor_v,
    }


def applied_fields(block: bridge_state.SensorBlock, fs_hz: float) -> dict[str, Any]:
    """The DriveCommandBlock of the drive the target applied over `block`."""
    return {
        "sample_rate_hz": fs_hz,
        "first_sample_index": block.first_sample_index,
        "drive_v": block.drive_v,
    }


def bridge_health(now: bridge_state.BridgeState, before: bridge_state.BridgeState | None) -> Health:
    """/diagnostics of the bridge: the target link (silence, packet loss), late drive and both
    watchdogs (the target's flag, the bridge's own stop). Losses: in the period since `before`.
    """
    c, b = now.counters, (before.counters if before is not None else bridge_state.Counters())
    packets, lost = c.sensor_packets - b.sensor_packets, c.lost_packets - b.lost_packets
    problems = [(ERROR, "target silent: no sensor packet") if now.silent else (OK, "")]
    if lost:
        problems.append(
            (
                WARN,
                f"{lost} sensor packet(s) lost "
                f"({loss_percent(lost, lost + packets):.2f} % of the period)",
            )
        )
    if c.drive_late_blocks > b.drive_late_blocks:
        problems.append(
            (
                WARN,
                f"{c.drive_late_blocks - b.drive_late_blocks} drive block(s) "
                "late for the target: dropped",
            )
        )
    if c.target_watchdog_packets > b.target_watchdog_packets:
        problems.append((ERROR, "the target's watchdog is tripped"))
    if c.watchdog_stops > b.watchdog_stops:
        problems.append((ERROR, "the drive stream fell silent: stop packet sent"))
    ok = "streaming" if c.sensor_packets else "waiting for the target's first packet"
    return health(
        "UDP bridge",
        problems,
        ok,
        {
            "sensor_packets": c.sensor_packets,
            "lost_packets": c.lost_packets,
            "loss_percent": loss_percent(c.lost_packets, c.lost_packets + c.sensor_packets),
            "malformed_packets": c.malformed,
            "foreign_packets": c.foreign_packets,
            "jump_packets": c.jump_packets,
            "drive_packets": c.drive_packets,
            "drive_late_blocks": c.drive_late_blocks,
            "clamped_samples": c.clamped_samples,
            "target_watchdog_packets": c.target_watchdog_packets,
            "watchdog_stops": c.watchdog_stops,
            "target_silent": now.silent,
        },
    )


def drive_input(fields: Mapping[str, Any], now_s: float) -> bridge_state.DriveBlock:
    """A /flaair/drive block's fields as the bridge core's input, received at `now_s`."""
    return bridge_state.DriveBlock(
        int(fields["first_sample_index"]), np.array(fields["drive_v"]), now_s
    )


def save_timing(path: str, timing: list[tuple[int, float, float]], events: Any) -> None:
    """The run's latency pairs and raw event times (`bridge_report.EventLog`) as .npz."""
    np.savez(path, timing=np.array(timing).reshape(-1, 3), **events.arrays())
