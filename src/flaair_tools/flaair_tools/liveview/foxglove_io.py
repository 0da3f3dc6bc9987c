"""foxglove_node's parameters (declared once), the `bin/flaair` argv that starts it, its server
and channels from those values, and its log lines.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray

from flaair_analysis import wingbeat
from flaair_common import cdr, topics
from flaair_common.msgdict import to_dict
from flaair_common.qos import EVENTS, STATUS
from flaair_model.schema import STREAM_PARAMS, ParameterError, ParamSpec
from flaair_msgs import msg as msgs
from flaair_tools.bagio.messages import leading_stamp_ns, message_definition
from flaair_tools.liveview import live_view

__all__ = [
    "CONFIG_FILE",
    "DIAGNOSTICS_TOPIC",
    "NODE_NAME",
    "PARAMS",
    "STREAM_SOURCES",
    "batch_blocks",
    "diagnostics_relay",
    "foxglove_node_args",
    "open_channels",
    "open_diagnostics_channel",
    "ready_text",
    "relay_channel",
    "start_server",
    "subscriptions",
    "wingbeat_params",
]

# live_view stream -> (ROS topic, message class, CDR layout)
STREAM_SOURCES: dict[str, tuple[str, Any, Any]] = {
    "wing_state": (topics.WING_STATE, msgs.WingStateBlock, cdr.WING_STATE_BLOCK),
    "wing_state_truth": (topics.WING_STATE_TRUTH, msgs.WingStateBlock, cdr.WING_STATE_BLOCK),
    "sensor_v": (topics.SENSOR_VOLTAGE, msgs.SensorVoltageBlock, cdr.SENSOR_VOLTAGE_BLOCK),
    "drive": (topics.DRIVE, msgs.DriveCommandBlock, cdr.DRIVE_COMMAND_BLOCK),
}

NODE_NAME = "foxglove_node"
CONFIG_FILE = "flaair.yaml"
PARAMS = [
    *STREAM_PARAMS,
    ParamSpec("host", str, "Address the WebSocket server listens on", read_only=True),
    ParamSpec(
        "port",
        int,
        "TCP port of the WebSocket server (0: any free port, logged)",
        0,
        65535,
        read_only=True,
    ),
    ParamSpec(
        "sample_decimation",
        int,
        "Serve every Nth sample of each stream (1: every sample)",
        1,
        10000,
        read_only=True,
    ),
    ParamSpec(
        "message_backlog",
        int,
        "Messages queued per client; the oldest drop when full",
        16,
        10**7,
        read_only=True,
    ),
    ParamSpec(
        "reliable", bool, "Subscribe to block streams reliably (false: best effort)", read_only=True
    ),
    ParamSpec(
        "serve_period_s",
        float,
        "Serve the blocks received this often, one batch per stream [s]",
        0.001,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "time_broadcast_period_s",
        float,
        "Broadcast the latest signal time this often [s]",
        0.001,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "wingbeat_hysteresis_deg",
        float,
        "Stroke below -this arms the wingbeat trigger [deg]",
        0.0,
        90.0,
        read_only=True,
    ),
    ParamSpec(
        "wingbeat_min_frequency_hz",
        float,
        "Longer wingbeats are dropped (idle) [Hz]",
        0.1,
        10000.0,
        read_only=True,
    ),
    ParamSpec(
        "wingbeat_max_frequency_hz",
        float,
        "Shorter wingbeats are dropped [Hz]",
        0.1,
        10000.0,
        read_only=True,
    ),
]


def foxglove_node_args(host_port: str) -> list[str]:
    """`bin/flaair` argv starting the live view on HOST:PORT (ValueError naming a bad HOST:PORT)."""
    host, port = live_view.parse_host_port(host_port)
    return [
        "run",
        "flaair_tools",
        NODE_NAME,
        "--ros-args",
        "-p",
        f"host:={host}",
        "-p",
        f"port:={port}",
    ]


def wingbeat_params(values: Mapping[str, Any]) -> wingbeat.WingbeatParams:
    """The wingbeat detector's parameters from foxglove_node's values."""
    return wingbeat.WingbeatParams(
        values["sample_rate_hz"],
        values["wingbeat_hysteresis_deg"],
        values["wingbeat_min_frequency_hz"],
        values["wingbeat_max_frequency_hz"],
    )


def start_server(foxglove: Any, time_capability: Any, values: Mapping[str, Any]) -> tuple[Any, Any]:
    """(wingbeat parameters, the WebSocket server) from foxglove_node's values; a ParameterError
    names the parameters a bad host, port or wingbeat setting came from.
    """
    try:
        params = wingbeat_params(values)
        server = foxglove.start_server(
            name="flaair",
            host=values["host"],
            port=values["port"],
            capabilities=[time_capability],
            message_backlog_size=values["message_backlog"],
        )
    except (ValueError, RuntimeError) as exc:
        raise ParameterError(f"parameters 'host'/'port'/'wingbeat_*': {exc}") from exc
    return params, server


def batch_blocks(values: Mapping[str, Any]) -> int:
    """Blocks of a stream served at once: a serve period's worth (at least one)."""
    return max(1, round(values["serve_period_s"] * values["sample_rate_hz"] / values["block_size"]))


def ready_text(host: str, port: int, decimation: int) -> str:
    """The node's start-up line."""
    return (
        f"Foxglove WebSocket server on ws://{host}:{port} (every {decimation} sample(s); layout "
        "config/foxglove_layout.json)"
    )


DIAGNOSTICS_TOPIC = live_view.DIAGNOSTICS_TOPIC
# ROS's DiagnosticArray as JSON, under its ROS type name: Foxglove's Diagnostics panels read it
_DIAGNOSTICS_SCHEMA = {
    "type": "object",
    "properties": {
        "header": {"type": "object"},
        "status": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "level": {"type": "integer"},
                    "name": {"type": "string"},
                    "message": {"type": "string"},
                    "hardware_id": {"type": "string"},
                    "values": {
                        "type": "array",
                        "items": {
                            "type": "object",
                            "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                        },
                    },
                },
            },
        },
    },
}


def open_diagnostics_channel(foxglove: Any) -> Any:
    """The /diagnostics channel (JSON, schema named diagnostic_msgs/msg/DiagnosticArray)."""
    return foxglove.Channel(
        DIAGNOSTICS_TOPIC,
        message_encoding="json",
        schema=foxglove.Schema(
            name="diagnostic_msgs/msg/DiagnosticArray",
            encoding="jsonschema",
            data=json.dumps(_DIAGNOSTICS_SCHEMA).encode(),
        ),
    )


def open_channels(foxglove: Any) -> tuple[dict[str, Any], Any, Any]:
    """The server's channels (`foxglove`: the SDK module): one per block stream (CDR,
    ros2msg schema), the wingbeat summaries and the collision status (JSON).
    """
    streams = {
        key: foxglove.Channel(
            stream.topic,
            message_encoding="cdr",
            schema=foxglove.Schema(
                name=stream.schema_name, encoding="ros2msg", data=stream.definition.encode()
            ),
        )
        for key, stream in live_view.STREAMS.items()
    }
    return (
        streams,
        foxglove.Channel(live_view.WINGBEAT_TOPIC, schema=live_view.WINGBEAT_SCHEMA),
        foxglove.Channel(live_view.COLLISION_TOPIC, schema=live_view.COLLISION_SCHEMA),
    )


def diagnostics_relay(foxglove: Any) -> Callable[[Any], None]:
    """The /diagnostics callback: each DiagnosticArray onto the diagnostics channel, as JSON."""
    channel = open_diagnostics_channel(foxglove)
    return lambda message: channel.log(json.dumps(to_dict(message), allow_nan=False))


def relay_channel(foxglove: Any, topic: str) -> Callable[[bytes], None]:
    """A callback serving each CDR message of `topic` (live_view.RELAYED) as it is, on a channel
    of the same name with its type's ros2msg definition, at its header stamp.
    """
    msgtype = live_view.RELAYED[topic]
    text, _ = message_definition(msgtype)
    channel = foxglove.Channel(
        topic,
        message_encoding="cdr",
        schema=foxglove.Schema(name=msgtype, encoding="ros2msg", data=text.encode()),
    )
    return lambda data: channel.log(data, log_time=leading_stamp_ns(data))


def subscriptions(foxglove: Any) -> list[tuple[Any, str, Callable[[Any], None], Any, bool]]:
    """What the node relays besides the block streams: (message class, topic, callback, QoS,
    raw) for /diagnostics (as JSON) and each live_view.RELAYED topic (as it is).
    """
    relayed = [
        (getattr(msgs, msgtype.rsplit("/", 1)[1]), topic, relay_channel(foxglove, topic))
        for topic, msgtype in live_view.RELAYED.items()
    ]
    return [
        (DiagnosticArray, DIAGNOSTICS_TOPIC, diagnostics_relay(foxglove), 10, False),
        *(
            (cls, topic, callback, EVENTS if "events" in topic else STATUS, True)
            for cls, topic, callback in relayed
        ),
    ]
