"""drive_node: the synchronous (open-loop) drive generator, the paper's drive.

Publishes drive-command blocks (/flaair/drive): a sine, a linear chirp, a stepped sine or a
multisine (lines and phases from `flaair multisine design`), with amplitude, bias and frequency
parameters, clamped to +-drive_limit_v.

Pacing:
  realtime  blocks leave at the wall-clock rate of the signal.
  lockstep  as fast as the plant answers: at most lockstep_window_blocks command blocks
            ahead of the last sensor block received (deterministic, faster than real time).

Ending: after run_time_s, and on SIGINT/SIGTERM if the last block was not zero, one block of
zero drive follows, so the actuator is never left holding a voltage (a lockstep plant's drive
watchdog trips on a command source that falls silent while driving).

The decisions (pacing, retries, the closing zero block) are flaair_sim.core.drive_pacing's; the
parameters are declared in flaair_sim.drive_io.

Usage: bin/flaair run flaair_sim drive_node --ros-args -p waveform:=chirp -p amplitude_v:=100.0
"""

from __future__ import annotations

import time

from flaair_common import intra, topics
from flaair_common.blocks import stamp_ns_of_sample
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import log_notes, run_node, warn_counted
from flaair_sim.core import drive_pacing as pacing
from flaair_sim.drive_io import CONFIG_FILE, DRIVE_NODE_PARAMS, NODE_NAME, pacing_params_from_config

PARAMS = DRIVE_NODE_PARAMS


class DriveNode(FlaairNode):
    """Thin shell over flaair_sim.core.drive_pacing.step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.params = pacing_params_from_config(self.p)
        self.live = self.live_parameters("drive_limit_v")
        self.state = pacing.initial_state(self.params, t_wall=time.monotonic())
        # CDR bytes out and in through flaair_common.cdr, as every block node: rclpy's message
        # conversion of each block costs about as much CPU as the transport
        block_size = self.params.block_size
        self.publisher = intra.block_publisher(self, topics.DRIVE, block_size, BLOCK_STREAM)
        self.ack, self.rejected_acks = None, 0
        if self.params.pacing == pacing.LOCKSTEP:
            on_wing = self.p["pace_on_wing_state"]
            ack_topic = topics.WING_STATE if on_wing else topics.SENSOR_VOLTAGE
            self.ack_samples = "stroke_deg" if on_wing else "stroke_sensor_v"
            self.ack = intra.subscribe_stream(
                self, ack_topic, block_size, self.on_ack, BLOCK_STREAM, self.on_undecodable
            )
        # lockstep: starts the stream once the plant subscribes; realtime: the wall-clock pace
        self.create_timer(0.002 if self.ack else 0.005, self.on_tick)
        self.get_logger().info(
            f"drive: {self.params.drive.kind}, amplitude "
            f"{self.params.drive.amplitude_v:g} V, pacing {self.params.pacing}"
        )

    def limit_v(self) -> float:
        return self.live["drive_limit_v"]

    def peers(self) -> tuple[int, int]:
        return (
            self.publisher.subscription_count(),
            self.ack.get_publisher_count() if self.ack else 0,
        )

    def apply(self, inputs: pacing.Inputs) -> int:
        """Step the pacing core; publish its blocks and log its lines; return the block count."""
        self.state, out = pacing.step(self.state, inputs, self.params)
        fs = self.params.sample_rate_hz
        for block in out.blocks:
            self.publisher.publish(
                stamp_ns_of_sample(block.first_sample_index, fs),
                {
                    "sample_rate_hz": fs,
                    "first_sample_index": block.first_sample_index,
                    "drive_v": block.drive_v,
                },
            )
        log_notes(self.get_logger(), out.notes)
        return len(out.blocks)

    def on_tick(self) -> None:
        self.apply(pacing.Tick(time.monotonic(), *self.peers(), self.limit_v()))

    def on_ack(self, fields) -> None:
        """A sensor (or wing-state) block: the samples up to its end are answered."""
        end = int(fields["first_sample_index"]) + len(fields[self.ack_samples])
        self.apply(pacing.Ack(time.monotonic(), end, *self.peers(), self.limit_v()))

    def on_undecodable(self, exc: Exception) -> None:
        self.rejected_acks += 1
        text = f"acknowledging block dropped: {exc} [{self.rejected_acks} so far]"
        warn_counted(self.get_logger(), self.rejected_acks, text)

    def close(self) -> None:
        """Shutdown: a zero block unless the last one already was (or nothing was sent)."""
        if self.apply(pacing.Close(self.limit_v())):
            time.sleep(0.1)  # let reliable delivery finish


def main(args: list[str] | None = None) -> int:
    return run_node(DriveNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
