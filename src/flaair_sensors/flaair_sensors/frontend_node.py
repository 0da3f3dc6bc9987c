r"""frontend_node: PVDF charge-amplifier voltages in, wing stroke and pitch out, live.

Subscribes to raw sensor-voltage blocks (/flaair/sensor_v) and publishes wing-state blocks
(/flaair/wing_state: stroke_deg, pitch_deg, stroke_velocity_deg_s, validity), through the
same core (flaair_sensors.core.frontend.step) that runs offline on bags.

Gains come from the model (paper Table 1 through the composite-beam charge model) or from a
calibration file written by `bin/flaair calibrate`. V_HREF and slow drift are removed, the
calibrated lag is compensated by a phase lead, samples near the charge-amplifier rails or
non-finite are marked invalid (never reported as angles), and the stroke velocity comes from
a low-pass differentiator (its phase at 140 Hz is logged at start).

Usage: bin/flaair run flaair_sensors frontend_node --ros-args -p gains_from:=calibration \
         -p calibration_file:=out/cal/calibration.yaml
"""

from __future__ import annotations

import time

import numpy as np

from flaair_common import cdr, intra, topics
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import INFO, log, run_node, warn_counted
from flaair_common.stream import check_block
from flaair_msgs.msg import WingStateBlock
from flaair_sensors import frontend_io as io
from flaair_sensors.core import frontend
from flaair_sensors.frontend_io import (
    CONFIG_FILE,
    FRONTEND_PARAMS,
    NODE_NAME,
    frontend_params_from_config,
)

PARAMS = FRONTEND_PARAMS
# a rosidl class constant costs a metaclass call per read
SENSOR_ESTIMATE = WingStateBlock.SOURCE_SENSOR_ESTIMATE
# processing times kept; logged this often (off the block path)
TIMED_BLOCKS, STATS_PERIOD_S = 20000, 10.0


class FrontendNode(FlaairNode):
    """Thin shell over flaair_sensors.core.frontend.step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        values = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.fs_hz = values["sample_rate_hz"]
        self.params = frontend_params_from_config(values, self.fs_hz)
        self.state = frontend.initial_state(self.params)
        frontend.warm_up(self.params, values["block_size"])
        self.expected_index: int | None = None
        self.rejected_blocks = 0
        # A store per block; the percentiles are taken by a timer: computed and logged inside the
        # block callback, they stalled a live loop for ~10 ms every 20,000 blocks.
        self.latencies_s, self.n_timed, self.n_reported = np.zeros(TIMED_BLOCKS), 0, 0
        self.create_timer(STATS_PERIOD_S, self.report_latency)
        self.block_size = values["block_size"]
        # CDR bytes in and out through flaair_common.cdr (rclpy's message conversion costs about
        # as much CPU as the transport at 2000 blocks/s), or in-process when composed (intra).
        self.publisher = intra.block_publisher(
            self, topics.WING_STATE, self.block_size, BLOCK_STREAM
        )
        on_sensor, on_bad = self.on_sensor, self.on_undecodable
        intra.subscribe_stream(
            self, topics.SENSOR_VOLTAGE, self.block_size, on_sensor, BLOCK_STREAM, on_bad
        )
        self.get_logger().info(io.ready_text(values["gains_from"], self.params))

    def on_undecodable(self, exc: Exception) -> None:
        self.rejected_blocks += 1
        text = f"sensor block dropped: {exc} [{self.rejected_blocks} so far]"
        warn_counted(self.get_logger(), self.rejected_blocks, text)

    def on_sensor(self, message) -> None:
        start = time.perf_counter()
        first = int(message["first_sample_index"])
        rate_hz = float(message["sample_rate_hz"])
        stroke_v, pitch_v = message["stroke_sensor_v"], message["pitch_sensor_v"]
        # Non-finite samples are the core's job (marked invalid); here only order, length and rate.
        if not (
            first == self.expected_index and rate_hz == self.fs_hz and len(stroke_v) == len(pitch_v)
        ):
            check = check_block(
                {
                    "stroke_sensor_v": np.nan_to_num(stroke_v),
                    "pitch_sensor_v": np.nan_to_num(pitch_v),
                },
                rate_hz,
                self.fs_hz,
                first,
                self.expected_index,
            )
            if not check.ok:
                self.rejected_blocks += 1
                text = f"sensor block {first}: {check.reason} [{self.rejected_blocks} so far]"
                warn_counted(self.get_logger(), self.rejected_blocks, text)
                if check.kind != "gap":
                    return
        self.expected_index = first + len(stroke_v)
        self.state, estimate = frontend.step(
            self.state, frontend.FrontendInputs(stroke_v, pitch_v), self.params
        )
        out = io.wing_state_fields(first, rate_hz, SENSOR_ESTIMATE, estimate)
        stamp_ns = cdr.stamp_ns(message)
        if len(stroke_v) == self.block_size:
            self.publisher.publish(stamp_ns, out)
        else:  # another block size: the general encoder, header carried over
            self.publisher.publisher.publish(
                cdr.encode(cdr.WING_STATE_BLOCK, stamp_ns, topics.FRAME_ID, out)
            )
        self.latencies_s[self.n_timed % TIMED_BLOCKS] = time.perf_counter() - start
        self.n_timed += 1

    def report_latency(self) -> None:
        """Log the block processing time over the last (up to) TIMED_BLOCKS blocks, if any came."""
        if self.n_timed == self.n_reported:
            return
        n = min(self.n_timed - self.n_reported, TIMED_BLOCKS)
        recent = self.latencies_s[(self.n_timed - 1 - np.arange(n)) % TIMED_BLOCKS]
        log(self.get_logger(), INFO, io.latency_text(recent))
        self.n_reported = self.n_timed


def main(args: list[str] | None = None) -> int:
    return run_node(FrontendNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
