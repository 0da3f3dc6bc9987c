"""health_node: the robot's proprioceptive health, live, from the two films and the drive.

Subscribes to the film voltages (/flaair/sensor_v) and the drive (drive_topic: /flaair/drive,
or /flaair/drive/applied against a target), joins them by sample index and runs the pure core
`flaair_control.core.health` (read its docstring for the estimator and the change test), the
same function `bin/flaair health` runs on a bag. Publishes a HealthStatus for every wingbeat
(/flaair/health: wing inertia, film gains and actuator gain as ratios to the model, with their
standard errors), a HealthEvent at each detected change (/flaair/health/events, reliable +
transient-local) and a /diagnostics entry (WARN once a change was detected).

Usage: bin/flaair run flaair_control health_node
"""

from __future__ import annotations

import numpy as np

from flaair_common import cdr, intra, topics
from flaair_common.blocks import stamp_from_ns
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM, EVENTS
from flaair_common.runtime import WARN, log, log_notes, run_node
from flaair_control import health_io as io
from flaair_control.core import health
from flaair_msgs.msg import HealthEvent, HealthStatus

NODE_NAME = io.NODE_NAME
PARAMS = io.HEALTH_PARAMS
CONFIG_FILE = io.CONFIG_FILE


class HealthNode(FlaairNode):
    """Thin shell over flaair_control.core.health.step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.params = io.health_params_from_config(p)
        self.state = health.initial_state(self.params)
        health.warm_up(self.params)  # the kernels load now, not on the first live blocks
        self.join = io.initial_join()
        self.fs_hz = p["sample_rate_hz"]
        self.estimated, self.events, self.undecodable, self.offset = 0, [], 0, 0
        # CDR bytes (flaair_common.cdr), as the block nodes publish: no rclpy message is built
        # field by field every wingbeat
        self.status_pub = intra.BlockPublisher(
            self,
            HealthStatus,
            topics.HEALTH_STATUS,
            cdr.FixedCodec(cdr.HEALTH_STATUS, 0),
            BLOCK_STREAM,
        )
        self.event_pub = self.create_publisher(HealthEvent, topics.HEALTH_EVENTS, EVENTS)
        block = p["block_size"]
        intra.subscribe_stream(
            self, topics.SENSOR_VOLTAGE, block, self.on_films, BLOCK_STREAM, self.on_undecodable
        )
        intra.subscribe_stream(
            self, p["drive_topic"], block, self.on_drive, BLOCK_STREAM, self.on_undecodable
        )
        self.publish_health(
            lambda: (self.state.wingbeat, self.estimated, list(self.events), self.state.quiet),
            io.health_diagnostics,
        )
        self.get_logger().info(
            f"health monitor ready: films /flaair/sensor_v, drive {p['drive_topic']}, "
            f"changes from {100 * p['detect_change']:g} %, "
            f"{p['false_alarms_per_hour']:g} false alarm(s) an hour, baseline "
            + (f"from {p['baseline_file']}" if p["baseline_file"] else "learned in the run")
        )

    def on_undecodable(self, exc: Exception) -> None:
        self.undecodable += 1

    def on_films(self, m) -> None:
        films = np.vstack(
            [np.asarray(m["stroke_sensor_v"], float), np.asarray(m["pitch_sensor_v"], float)]
        )
        self.follow_sample_clock(m, self.fs_hz)
        self.advance(int(m["first_sample_index"]), films, None)

    def on_drive(self, m) -> None:
        self.advance(int(m["first_sample_index"]), None, np.asarray(m["drive_v"], float))

    def advance(self, first: int, films: np.ndarray | None, drive_v: np.ndarray | None) -> None:
        """Join the block with the other stream; run the core on what both hold."""
        self.join, start, inputs = io.join_block(self.join, first, films, drive_v)
        if inputs is None:
            return
        if self.state.sample_index == 0 and start > 0:  # the first samples seen: index from here
            self.offset = start
        self.state, out = health.step(self.state, inputs, self.params)
        log_notes(self.get_logger(), out.notes)
        offset = self.offset
        for b in out.wingbeats:
            self.estimated += b.valid
            stamp_ns = self.stamp_ns_of(b.sample_index + offset, self.fs_hz)
            self.status_pub.publish(stamp_ns, io.status_fields(b, offset))
        for e in out.events:
            index = e.sample_index + offset
            event = HealthEvent(
                parameter=e.parameter,
                ratio=e.ratio,
                stderr=e.stderr,
                sample_index=index,
                time_s=index / self.fs_hz,
                wingbeat_index=e.wingbeat,
                alternatives=list(e.alternatives),
                offset_deg=e.offset_deg,
            )
            event.header.stamp = stamp_from_ns(self.stamp_ns_of(index, self.fs_hz))
            self.event_pub.publish(event)
            self.events.append(health.event_text(e._replace(time_s=index / self.fs_hz)))
            log(self.get_logger(), WARN, f"health: {self.events[-1]}")


def main(args: list[str] | None = None) -> int:
    return run_node(HealthNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
