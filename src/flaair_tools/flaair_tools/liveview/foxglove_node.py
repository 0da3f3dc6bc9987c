"""foxglove_node: the live graph over the Foxglove WebSocket protocol (Foxglove app, Lichtblick).

Serves on ws://HOST:PORT one message per sample of /flaair/wing_state, /wing_state/truth, /sensor_v
and /drive (on /flaair/live/..., flaair_tools.liveview.live_view) at the sample's own signal time,
so the Plot panel draws time series; /flaair/live/wingbeat summarises each wingbeat
(flaair_analysis.wingbeat); /flaair/live/collision_status relays the monitor, /diagnostics
every node's health, /flaair/health and /flaair/health/events the health monitor's estimates
and changes (as they are); the latest signal time is broadcast. Block streams are best effort
(a viewer never holds the graph), served in batches of serve_period_s (one numpy call each).
Foxglove: Open connection > ws://127.0.0.1:8765; Layout > Import config/foxglove_layout.json.
Usage: bin/flaair foxglove 127.0.0.1:8765, or
  bin/flaair run flaair_tools foxglove_node --ros-args -p port:=8765 -p sample_decimation:=4
"""

from __future__ import annotations

import contextlib
import math
import sys

import foxglove
from foxglove.websocket import Capability
from rclpy.clock import Clock, ClockType
from rclpy.qos import QoSProfile, ReliabilityPolicy

from flaair_analysis import wingbeat
from flaair_common import cdr, topics
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM, STATUS
from flaair_common.runtime import run_node
from flaair_msgs import msg as msgs
from flaair_tools.liveview import foxglove_io as io
from flaair_tools.liveview import live_view
from flaair_tools.liveview.foxglove_io import CONFIG_FILE, NODE_NAME, PARAMS

STREAM_SOURCES = io.STREAM_SOURCES


class FoxgloveNode(FlaairNode):
    """Block streams -> per-sample Foxglove messages; wing state -> wingbeat summaries."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.wingbeat_params, self.server = io.start_server(foxglove, Capability.Time, p)
        self.decimation = p["sample_decimation"]
        self.channels, self.wingbeat_channel, self.collision_channel = io.open_channels(foxglove)
        self.state = wingbeat.initial_state(self.wingbeat_params)
        self.beats, self.score, self.k_r, self.colliding = 0, math.nan, math.nan, None
        self.latest_ns = self.broadcast_ns = 0
        self.create_timer(
            p["time_broadcast_period_s"],
            self.broadcast_time,
            clock=(steady := Clock(clock_type=ClockType.STEADY_TIME)),
        )
        self.create_timer(p["serve_period_s"], self.serve, clock=steady)  # a stream that stopped
        self.pending: dict[str, list[bytes]] = {key: [] for key in STREAM_SOURCES}
        self.codecs: dict[str, dict] = {key: {} for key in STREAM_SOURCES}  # codecs by size
        reliability = ReliabilityPolicy.RELIABLE if p["reliable"] else ReliabilityPolicy.BEST_EFFORT
        qos = QoSProfile(depth=BLOCK_STREAM.depth, reliability=reliability)
        self.batch_blocks = io.batch_blocks(p)
        for key, (topic, cls, _) in STREAM_SOURCES.items():
            self.create_subscription(cls, topic, self.block_callback(key), qos, raw=True)
        self.create_subscription(
            msgs.CollisionStatus, topics.COLLISION_STATUS, self.on_status, STATUS
        )
        self.create_subscription(
            msgs.ControllerState, topics.CONTROLLER_STATE, self.on_controller, qos, raw=True
        )
        # every node's /diagnostics (JSON), the health monitor's /flaair/health[/events] as they are
        for cls, topic, callback, qos_profile, raw in io.subscriptions(foxglove):
            self.create_subscription(cls, topic, callback, qos_profile, raw=raw)
        self.get_logger().info(io.ready_text(p["host"], self.server.port, self.decimation))

    def block_callback(self, key: str):  # keeps a block; a serve period's worth is served at once
        def on_block(data: bytes) -> None:
            self.pending[key].append(data)
            if len(self.pending[key]) >= self.batch_blocks:
                self.serve_stream(key)

        return on_block

    def serve(self) -> None:
        """Every stream's blocks kept since they were last served."""
        for key in [key for key, pending in self.pending.items() if pending]:
            self.serve_stream(key)

    def serve_stream(self, key: str) -> None:
        """A stream's kept blocks: wingbeats, then all their samples in one numpy batch."""
        datas, stream, channel = (
            self.pending[key].copy(),
            live_view.STREAMS[key],
            self.channels[key],
        )
        self.pending[key].clear()
        batches, bad = live_view.fixed_blocks(STREAM_SOURCES[key][2], datas, self.codecs[key])
        if bad:
            text = f"{STREAM_SOURCES[key][0]}: {bad} block(s) dropped: bad CDR"
            self.get_logger().warning(text, throttle_duration_sec=1.0)
        for blocks in batches:
            end_ns = live_view.blocks_end_ns(blocks, stream.fields[0][0])
            self.latest_ns = max(self.latest_ns, end_ns)
            if key == "wing_state":
                context = (self.beats, self.score, self.k_r, self.colliding, self.wingbeat_params)
                self.state, beats = live_view.wingbeat_batch(self.state, blocks, *context)
                for log_time, payload in beats:
                    self.wingbeat_channel.log(payload, log_time=log_time)
                self.beats += len(beats)
            if channel.has_sinks():
                times, payloads = live_view.blocks_samples(stream, blocks, self.decimation)
                for log_time, payload in zip(times, payloads, strict=True):
                    channel.base.log(payload, log_time)

    def broadcast_time(self) -> None:
        """Tell clients the latest signal time (the end of the newest block), when it moved."""
        if self.latest_ns != self.broadcast_ns:
            self.server.broadcast_time(self.latest_ns)
            self.broadcast_ns = self.latest_ns

    def on_status(self, status: msgs.CollisionStatus) -> None:
        self.score = wingbeat.collision_score(status.spectrum_rmse_deg, status.threshold_deg)
        self.colliding = bool(status.colliding)
        stamp_ns = status.header.stamp.sec * 1_000_000_000 + status.header.stamp.nanosec
        payload = live_view.collision_message(
            status.wingbeat_index,
            self.colliding,
            status.spectrum_rmse_deg,
            status.threshold_deg,
            stamp_ns,
        )
        self.collision_channel.log(payload, log_time=stamp_ns)

    def on_controller(self, data: bytes) -> None:
        # not worth a warning at 2000/s: K_r stays the last good one
        with contextlib.suppress(cdr.CdrError):
            self.k_r = float(cdr.decode(cdr.CONTROLLER_STATE, data)["k_r"])

    def close(self) -> None:
        self.server.stop()


def main(args: list[str] | None = None) -> int:
    return run_node(FoxgloveNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
