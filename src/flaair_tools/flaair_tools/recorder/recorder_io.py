"""The recorder's parameters: their one declaration, and `bin/flaair record` options -> ROS args."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from flaair_common.cli_help import HelpFormatter
from flaair_common.msgdict import message_class
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import help_text
from flaair_common.topics import BLOCK_STREAM_TYPES
from flaair_model.schema import ParameterError, ParamSpec
from flaair_tools import bagio
from flaair_tools.recorder import recording
from flaair_tools.recorder.recording import RecordingParams

RECORDER_HELP = """\
recorder_node: record FLAAIR topics into a rosbag2 (MCAP) bag, like `ros2 bag record`.

Subscribes to every /flaair topic (or the `topics` chosen), /diagnostics and /clock (where the
graph publishes them: a run's health and sim time stay in its bag) as raw serialized messages, looks
for new topics every `discovery_period_s`, and writes each message straight into the bag
without deserializing it, at its signal time (the leading header's stamp, the
/clock value, or for a header-less run marker the latest stamp: flaair_tools.recorder.recording
decides), so `play`, PlotJuggler and Foxglove show the signal's own timeline.
Subscriptions match what the publishers offer (reliable / transient-local only if every
publisher offers it); the offered QoS profiles are recorded with each topic, as rosbag2 does.

Throughput: each callback also drains the messages already queued on its subscription
(recording.drain); the subscription queue is `queue_depth` deep, slack for CPU starvation.
Composed beside the loop (`container --background`, as `flaair live` runs it), it records the
in-process block streams from the bus, with no DDS round trip.

Durability: chunks are closed and handed to the OS when they reach `chunk_size_bytes` or
every `flush_period_s`, so after a kill -9 everything older than that stays readable
(`bin/flaair bag reindex BAG` restores the summary and metadata.yaml). SIGINT / SIGTERM close
the bag completely.

Usage:
  bin/flaair record [-o BAG] [--topics /flaair/sensor_v ...] [--clock] [--no-compression]
                    [--use-sim-time]
  bin/flaair run flaair_tools recorder_node --ros-args -p output_path:=out/bags/run1
"""
NODE_NAME = "recorder_node"
CONFIG_FILE = "flaair.yaml"
# At most one block stream's QoS depth per callback, so other topics get their turn.
RECORDING = RecordingParams(drain_limit=BLOCK_STREAM.depth)
RECORDER_PARAMS = [
    ParamSpec(
        "output_path",
        str,
        "Bag directory to create (empty: out/bags/flaair_<date>_<time>)",
        read_only=True,
    ),
    ParamSpec(
        "topics",
        str,
        "Comma-separated topics to record (empty: every /flaair/* topic)",
        read_only=True,
    ),
    ParamSpec("record_clock", bool, "Also record /clock", read_only=True),
    ParamSpec("compression", bool, "zstd-compress each MCAP chunk", read_only=True),
    ParamSpec(
        "chunk_size_bytes",
        int,
        "Close an MCAP chunk at this size [bytes]",
        1024,
        2**31 - 1,
        read_only=True,
    ),
    ParamSpec(
        "flush_period_s",
        float,
        "Close the open chunk and flush this often; older data survives kill -9 [s]",
        0.01,
        3600.0,
        read_only=True,
    ),
    ParamSpec(
        "discovery_period_s",
        float,
        "Look for new topics this often [s]",
        0.01,
        3600.0,
        read_only=True,
    ),
    ParamSpec(
        "queue_depth",
        int,
        "Subscription queue per topic (KEEP_LAST): slack while the recorder is starved",
        1,
        10**7,
        read_only=True,
    ),
]


def cli_to_ros_args(argv: list[str], description: str, prog: str = "flaair record") -> list[str]:
    """`bin/flaair record` options as the node's --ros-args
    (anything after --ros-args passes through).
    """
    parser = argparse.ArgumentParser(
        prog=prog,
        description=description,
        formatter_class=HelpFormatter,
        epilog=help_text("", RECORDER_PARAMS, CONFIG_FILE, NODE_NAME),
    )
    parser.add_argument(
        "-o",
        "--output",
        help="bag directory to create (default: out/bags/flaair_<date>_<time>, "
        "config/flaair.yaml recorder_node.output_path)",
    )
    parser.add_argument(
        "--topics",
        nargs="+",
        default=None,
        help="topics to record (default: every /flaair topic); /diagnostics and "
        "/flaair/time_anchor are always kept",
    )
    parser.add_argument(
        "--clock", action="store_true", help="record /clock (config/flaair.yaml's default)"
    )
    parser.add_argument("--no-compression", action="store_true", help="store chunks uncompressed")
    parser.add_argument(
        "--use-sim-time",
        action="store_true",
        help="run the node on sim time (log times are signal times with or without it)",
    )
    ros_args: list[str] = []
    if "--ros-args" in argv:
        cut = argv.index("--ros-args")
        argv, ros_args = argv[:cut], argv[cut + 1 :]
    args = parser.parse_args(argv)

    def param(name: str, value: str) -> list[str]:
        return ["-p", f"{name}:={value}"]

    def quoted(text: str) -> str:
        return "'" + text.replace("'", "''") + "'"

    out = [prog, "--ros-args"]
    if args.output:
        out += param("output_path", quoted(args.output))
    if args.topics:
        out += param("topics", quoted(",".join(args.topics)))
    if args.clock:
        out += param("record_clock", "true")
    if args.no_compression:
        out += param("compression", "false")
    if args.use_sim_time:
        out += param("use_sim_time", "true")
    return out + ros_args


class SkipTopic(ValueError):
    """A discovered topic the recorder cannot record (the message says why)."""


def topic_to_record(
    topic: str, types: list[str], publishers: list[Any], writer: bagio.BagWriter, depth: int
) -> tuple[str, type, QoSProfile] | None:
    """(type, message class, subscription QoS) of a discovered topic, its offered QoS added to the
    bag; None while it has no publisher (whose QoS
    decides ours); SkipTopic if it cannot be recorded.
    """
    if len(types) != 1:
        raise SkipTopic(f"published with several types ({', '.join(types)})")
    if not publishers:
        return None
    msgtype = types[0]
    try:
        cls = message_class(msgtype)
        offered = [bagio.qos_from_rclpy(info.qos_profile) for info in publishers]
        writer.add_topic(topic, msgtype, offered)
    except (ValueError, bagio.BagError) as exc:
        raise SkipTopic(str(exc)) from None
    qos = recording.adapt_qos(offered)
    return (
        msgtype,
        cls,
        QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=depth,
            reliability=ReliabilityPolicy.RELIABLE
            if qos.reliable
            else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.TRANSIENT_LOCAL
            if qos.transient_local
            else DurabilityPolicy.VOLATILE,
        ),
    )


def open_writer(values: dict[str, Any], store: Any) -> bagio.BagWriter:
    """The bag writer the recorder's parameters ask
    for (`output_path` empty: a timestamped name).
    """
    path = (
        Path(values["output_path"])
        if values["output_path"]
        else recording.default_output_path(time.time())
    )
    try:
        return bagio.BagWriter(
            path,
            compression=values["compression"],
            chunk_size_bytes=values["chunk_size_bytes"],
            store=store,
        )
    except bagio.BagError as exc:
        raise ParameterError(f"parameter 'output_path': {exc}") from exc


def take_all(takers: dict[str, tuple], warn: Callable[[str], None]) -> int:
    """Hand every message DDS has delivered but no callback has handled yet to its handler.

    `takers`: topic -> (take, on_message) of its subscription; a failing take is warned about
    (a dying middleware must not cost the bag). Returns how many were handled.
    """
    taken = 0
    for topic, (take, on_message) in takers.items():
        try:
            while (item := take()) is not None:
                on_message(*item)
                taken += 1
        except Exception as exc:
            warn(f"{topic}: could not take the last messages ({exc})")
    return taken


def closed_text(path: object, counts: dict[str, int]) -> str:
    """The recorder's last log line: the bag and how many messages of each topic it holds."""
    listed = ", ".join(f"{topic} {count}" for topic, count in sorted(counts.items())) or "nothing"
    return f"closed {path}: {listed}"


def recording_settings(composed: bool) -> RecordingParams:
    """The recording settings: composed (an EventsExecutor), no take() in a callback, so no
    draining beyond the message itself; the block streams come in-process there.
    """
    return replace(RECORDING, drain_limit=1) if composed else RECORDING


def in_process_streams(
    bus: Any, chosen: Sequence[str], record_clock: bool
) -> list[tuple[str, str]]:
    """(topic, message type) of the wanted block streams on the composed nodes' bus (None: not
    composed, none), in topic order.
    """
    local = sorted(bus.local_topics) if bus is not None else []
    return [
        (topic, BLOCK_STREAM_TYPES[topic])
        for topic in local
        if recording.wanted(topic, chosen, record_clock) and topic in BLOCK_STREAM_TYPES
    ]
