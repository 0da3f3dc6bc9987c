"""foxglove_node: the live graph over the Foxglove WebSocket protocol (Foxglove app, Lichtblick).

Serves on ws://HOST:PORT one message per sample of /flaair/wing_state, /wing_state/truth,
/sensor_v and /drive (on /flaair/live/..., flaair_tools.live_view) whose log time is the
sample's own signal time, so the Plot panel draws them as time series; /flaair/live/wingbeat
summarises each wingbeat (flaair_tools.wingbeat: amplitude, frequency, pitch amplitude,
collision score, K_r); /flaair/live/collision_status relays the monitor. The latest signal time
is broadcast (Time capability). Block streams are best effort: a viewer never holds the graph.
Foxglove: Open connection > ws://127.0.0.1:8765; Layout > Import config/foxglove_layout.json.
Usage:
  bin/flaair foxglove 127.0.0.1:8765
  bin/flaair run flaair_tools foxglove_node --ros-args -p port:=8765 -p sample_decimation:=4
"""
from __future__ import annotations

import math
import sys
import foxglove
import numpy as np
from foxglove.websocket import Capability
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from flaair_common import cdr, topics
from flaair_common.params import ParameterError, ParamSpec, declare_parameters
from flaair_common.qos import BLOCK_STREAM, STATUS
from flaair_common.runtime import run_node
from flaair_msgs.msg import CollisionStatus, ControllerState, DriveCommandBlock, SensorVoltageBlock, WingStateBlock
from flaair_tools import live_view, wingbeat

NODE_NAME = "foxglove_node"
CONFIG_FILE = "flaair.yaml"
PARAMS = [
    ParamSpec("sample_rate_hz", float, "Sample rate of the block streams [Hz]", 1000.0, 1.0e6, read_only=True),
    ParamSpec("block_size", int, "Samples per block", 1, 100000, read_only=True),
    ParamSpec("host", str, "Address the WebSocket server listens on", read_only=True),
    ParamSpec("port", int, "TCP port of the WebSocket server (0: any free port, logged)", 0, 65535, read_only=True),
    ParamSpec("sample_decimation", int, "Serve every Nth sample of each stream (1: every sample)", 1, 10000, read_only=True),
    ParamSpec("message_backlog", int, "Messages queued per client; the oldest drop when full", 16, 10**7, read_only=True),
    ParamSpec("reliable", bool, "Subscribe to block streams reliably (false: best effort)", read_only=True),
    ParamSpec("time_broadcast_period_s", float, "Broadcast the latest signal time this often [s]", 0.001, 10.0, read_only=True),
    ParamSpec("wingbeat_hysteresis_deg", float, "Stroke below -this arms the wingbeat trigger [deg]", 0.0, 90.0, read_only=True),
    ParamSpec("wingbeat_min_frequency_hz", float, "Longer wingbeats are dropped (idle) [Hz]", 0.1, 10000.0, read_only=True),
    ParamSpec("wingbeat_max_frequency_hz", float, "Shorter wingbeats are dropped [Hz]", 0.1, 10000.0, read_only=True),
]
STREAM_SOURCES = {  # live_view stream -> (ROS topic, message class, CDR layout)
    "wing_state": (topics.WING_STATE, WingStateBlock, cdr.WING_STATE_BLOCK),
    "wing_state_truth": (topics.WING_STATE_TRUTH, WingStateBlock, cdr.WING_STATE_BLOCK),
    "sensor_v": (topics.SENSOR_VOLTAGE, SensorVoltageBlock, cdr.SENSOR_VOLTAGE_BLOCK),
    "drive": (topics.DRIVE, DriveCommandBlock, cdr.DRIVE_COMMAND_BLOCK),
}


def foxglove_node_args(host_port: str) -> list[str]:
    """`bin/flaair` argv starting the live view on HOST:PORT (ValueError naming a bad HOST:PORT)."""
    host, port = live_view.parse_host_port(host_port)
    return ["run", "flaair_tools", NODE_NAME, "--ros-args", "-p", f"host:={host}", "-p", f"port:={port}"]


class FoxgloveNode(Node):
    """Block streams -> per-sample Foxglove messages; wing state -> wingbeat summaries."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = declare_parameters(self, PARAMS, CONFIG_FILE)
        try:
            self.wingbeat_params = wingbeat.WingbeatParams(p["sample_rate_hz"], p["wingbeat_hysteresis_deg"],
                                                           p["wingbeat_min_frequency_hz"], p["wingbeat_max_frequency_hz"])
            self.server = foxglove.start_server(name="flaair", host=p["host"], port=p["port"], capabilities=[Capability.Time],
                                                message_backlog_size=p["message_backlog"])
        except (ValueError, RuntimeError) as exc:
            raise ParameterError(f"parameters 'host'/'port'/'wingbeat_*': {exc}") from exc
        self.decimation, self.period_s = p["sample_decimation"], p["time_broadcast_period_s"]
        self.channels = {key: foxglove.Channel(stream.topic, message_encoding="cdr", schema=foxglove.Schema(
            name=stream.schema_name, encoding="ros2msg", data=stream.definition.encode())) for key, stream in live_view.STREAMS.items()}
        self.wingbeat_channel, self.collision_channel = (foxglove.Channel(topic, schema=schema) for topic, schema in (
            (live_view.WINGBEAT_TOPIC, live_view.WINGBEAT_SCHEMA), (live_view.COLLISION_TOPIC, live_view.COLLISION_SCHEMA)))
        self.state, self.beats, self.score, self.k_r, self.colliding = wingbeat.initial_state(), 0, math.nan, math.nan, None
        self.latest_ns = self.broadcast_ns = 0
        self.create_timer(self.period_s, self.broadcast_time, clock=Clock(clock_type=ClockType.STEADY_TIME))
        qos = QoSProfile(depth=BLOCK_STREAM.depth, reliability=ReliabilityPolicy.RELIABLE if p["reliable"]
                         else ReliabilityPolicy.BEST_EFFORT)
        for key, (topic, cls, layout) in STREAM_SOURCES.items():
            self.create_subscription(cls, topic, self.block_callback(key, cdr.FixedCodec(layout, p["block_size"], topics.FRAME_ID)),
                                     qos, raw=True)
        self.create_subscription(CollisionStatus, topics.COLLISION_STATUS, self.on_status, STATUS)
        self.create_subscription(ControllerState, topics.CONTROLLER_STATE, self.on_controller, qos, raw=True)
        self.get_logger().info(f"Foxglove WebSocket server on ws://{p['host']}:{self.server.port} "
                               f"(every {self.decimation} sample(s); layout config/foxglove_layout.json)")

    def block_callback(self, key: str, codec: cdr.FixedCodec):
        stream, channel = live_view.STREAMS[key], self.channels[key]
        log = channel.base.log

        def on_block(data: bytes) -> None:
            try:
                message = codec.decode(data)
            except cdr.CdrError as exc:
                self.get_logger().warning(f"{stream.topic}: block dropped: {exc}", throttle_duration_sec=1.0)
                return
            first, rate, stamp_ns = int(message["first_sample_index"]), float(message["sample_rate_hz"]), cdr.stamp_ns(message)
            if key == "wing_state":
                self.summarize(message, first, rate, stamp_ns)
            if channel.has_sinks():
                for log_time, payload in zip(*live_view.block_samples(stream, message, stamp_ns, self.decimation)):
                    log(payload, log_time)
            self.latest_ns = max(self.latest_ns, stamp_ns + int(round(len(message[stream.fields[0][0]]) * 1e9 / rate)))

        return on_block

    def broadcast_time(self) -> None:
        """Tell clients the latest signal time (the end of the newest block), when it moved."""
        if self.latest_ns != self.broadcast_ns:
            self.server.broadcast_time(self.latest_ns)
            self.broadcast_ns = self.latest_ns

    def summarize(self, message, first: int, rate: float, stamp_ns: int) -> None:
        """Wingbeats ended by this wing-state block -> /flaair/live/wingbeat."""
        valid = np.logical_and(message["stroke_valid"], message["pitch_valid"])
        inputs = wingbeat.WingbeatInputs(first, message["stroke_deg"], message["pitch_deg"], valid, self.score, self.k_r)
        self.state, beats = wingbeat.step(self.state, inputs, self.wingbeat_params)
        for log_time, payload in live_view.wingbeat_messages(beats, self.beats, stamp_ns, first, rate, self.colliding):
            self.wingbeat_channel.log(payload, log_time=log_time)
        self.beats += beats.end_sample.size

    def on_status(self, status: CollisionStatus) -> None:
        self.score = wingbeat.collision_score(status.spectrum_rmse_deg, status.threshold_deg)
        self.colliding = bool(status.colliding)
        stamp_ns = status.header.stamp.sec * 1_000_000_000 + status.header.stamp.nanosec
        self.collision_channel.log(live_view.collision_message(status.wingbeat_index, self.colliding, status.spectrum_rmse_deg,
                                                               status.threshold_deg, stamp_ns), log_time=stamp_ns)

    def on_controller(self, data: bytes) -> None:
        try:
            self.k_r = float(cdr.decode(cdr.CONTROLLER_STATE, data)["k_r"])
        except cdr.CdrError:  # not worth a warning at 2000/s: K_r stays the last good one
            pass

    def close(self) -> None:
        self.server.stop()


def main(args: list[str] | None = None) -> int:
    return run_node(FoxgloveNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
