"""collision_monitor_node: per-wingbeat wing-collision verdicts from the sensor-derived wing state.

Subscribes to the estimated wing state (/flaair/wing_state) and, for drive windows with an
estimated frequency, to the drive (/flaair/drive). Publishes a CollisionStatus for every
wingbeat (/flaair/collision/status) and a CollisionEvent at each onset and clearance
(/flaair/collision/events, reliable + transient-local). A thin shell over the pure core
`flaair_control.core.monitor` (windows, drive-frequency lock, the paper metric, the decision),
which `analyze` also runs on bags: read its docstring for what is decided and how.

Windows (window_source): drive (locked to the drive phase; drive_frequency_hz 0 estimates the
frequency from /flaair/drive and re-locks when it moves) or stroke (between upward crossings
of the measured stroke: asynchronous flapping). Decision (decision): distortion (the
per-wingbeat score; about one wingbeat to detect) or paper (the paper's 10-wingbeat pitch FFT
against a pure sine, 1 deg threshold).

Usage: bin/flaair run flaair_control collision_monitor_node
[--ros-args -p drive_frequency_hz:=100.0]
"""

from __future__ import annotations

import numpy as np

from flaair_common import intra, topics
from flaair_common.blocks import stamp_from_ns
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM, EVENTS
from flaair_common.runtime import INFO, WARN, log, log_notes, run_node, warn_counted
from flaair_common.stream import check_block
from flaair_control import monitor_io as io
from flaair_control.core import monitor
from flaair_control.monitor_io import (
    COLLISION_MONITOR_PARAMS,
    CONFIG_FILE,
    collision_monitor_params_from_config,
    describe_monitor,
    monitor_drive_input,
    monitor_health,
    monitor_wing_input,
)
from flaair_msgs.msg import CollisionEvent, CollisionStatus

NODE_NAME = "collision_monitor_node"
PARAMS = COLLISION_MONITOR_PARAMS
EVENT_KINDS = {monitor.ONSET: CollisionEvent.ONSET, monitor.CLEARANCE: CollisionEvent.CLEARANCE}


class CollisionMonitorNode(FlaairNode):
    """Thin shell over flaair_control.core.monitor.step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.params = collision_monitor_params_from_config(p)
        self.state = monitor.initial_state(self.params)
        self.fs_hz = p["sample_rate_hz"]
        self.drive_expected: int | None = None
        self.wing_expected: int | None = None
        self.rejected = self.undecodable = 0
        self.status_pub = self.create_publisher(
            CollisionStatus, topics.COLLISION_STATUS, BLOCK_STREAM
        )  # one per wingbeat: a stream
        self.event_pub = self.create_publisher(CollisionEvent, topics.COLLISION_EVENTS, EVENTS)
        # Block streams as CDR bytes, or in-process when
        # composed beside the loop (flaair_common.intra)
        block = p["block_size"]
        intra.subscribe_stream(
            self, topics.WING_STATE, block, self.on_wing_state, BLOCK_STREAM, self.on_undecodable
        )
        if self.params.estimates_frequency:
            intra.subscribe_stream(
                self, topics.DRIVE, block, self.on_drive, BLOCK_STREAM, self.on_undecodable
            )
        self.publish_health(lambda: (self.state, self.rejected, self.undecodable), monitor_health)
        self.get_logger().info(describe_monitor(p, self.params.estimates_frequency))

    def on_undecodable(self, exc: Exception) -> None:
        self.undecodable += 1
        warn_counted(self.get_logger(), self.undecodable, io.dropped_text(exc, self.undecodable))

    def on_drive(self, m) -> None:
        drive_v = np.asarray(m["drive_v"], dtype=np.float64)
        first = int(m["first_sample_index"])
        check = check_block(
            {"drive_v": drive_v}, float(m["sample_rate_hz"]), self.fs_hz, first, self.drive_expected
        )
        if not check.ok and check.kind != "gap":
            return
        self.drive_expected = first + len(drive_v)
        self.advance(monitor_drive_input(m))

    def on_wing_state(self, m) -> None:
        n, first = len(m["stroke_deg"]), int(m["first_sample_index"])
        check = check_block(
            {"stroke_deg": np.zeros(n), "pitch_deg": np.zeros(len(m["pitch_deg"]))},
            float(m["sample_rate_hz"]),
            self.fs_hz,
            first,
            self.wing_expected,
        )
        if not check.ok and check.kind != "gap":
            self.rejected += 1
            text = f"wing-state block {first}: {check.reason} [{self.rejected} rejected so far]"
            warn_counted(self.get_logger(), self.rejected, text)
            return
        self.wing_expected = first + n
        self.follow_sample_clock(m, self.fs_hz)  # verdict stamps: the wing state's clock
        self.advance(monitor_wing_input(m))

    def advance(self, inputs: monitor.DriveBlock | monitor.WingBlock) -> None:
        """Run the core on one block; log its notes, publish its verdicts."""
        self.state, out = monitor.step(self.state, inputs, self.params)
        log_notes(self.get_logger(), out.notes)
        for verdict in out.verdicts:
            self.publish(verdict)

    def publish(self, v: monitor.Verdict) -> None:
        stamp = stamp_from_ns(self.stamp_ns_of(v.end_index, self.fs_hz))
        threshold = self.p["threshold_deg"]
        if v.event is not None:
            event = CollisionEvent(kind=EVENT_KINDS[v.event], **io.event_fields(v))
            event.header.stamp = stamp
            self.event_pub.publish(event)
            log(
                self.get_logger(),
                WARN if v.colliding else INFO,
                io.verdict_text(v, self.fs_hz, threshold),
            )
        out = CollisionStatus(**io.status_fields(v, threshold))
        out.header.stamp = stamp
        self.status_pub.publish(out)


def main(args: list[str] | None = None) -> int:
    return run_node(CollisionMonitorNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
