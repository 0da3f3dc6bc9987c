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

from flaair_common import topics
from flaair_common.blocks import from_array, stamp_from_time_s
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import log_notes, run_node
from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock, WingStateBlock
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
        self.publisher = self.create_publisher(DriveCommandBlock, topics.DRIVE, BLOCK_STREAM)
        self.ack = None
        if self.params.pacing == pacing.LOCKSTEP:
            if self.p["pace_on_wing_state"]:
                self.ack = self.create_subscription(
                    WingStateBlock, topics.WING_STATE, self.on_wing_state, BLOCK_STREAM
                )
            else:
                self.ack = self.create_subscription(
                    SensorVoltageBlock, topics.SENSOR_VOLTAGE, self.on_sensor, BLOCK_STREAM
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
            self.publisher.get_subscription_count(),
            self.ack.get_publisher_count() if self.ack else 0,
        )

    def apply(self, inputs: pacing.Inputs) -> int:
        """Step the pacing core; publish its blocks and log its lines; return the block count."""
        self.state, out = pacing.step(self.state, inputs, self.params)
        fs = self.params.sample_rate_hz
        for block in out.blocks:
            message = DriveCommandBlock(
                sample_rate_hz=fs, first_sample_index=block.first_sample_index
            )
            message.header.stamp = stamp_from_time_s(block.first_sample_index / fs)
            message.drive_v = from_array(block.drive_v)
            self.publisher.publish(message)
        log_notes(self.get_logger(), out.notes)
        return len(out.blocks)

    def on_tick(self) -> None:
        self.apply(pacing.Tick(time.monotonic(), *self.peers(), self.limit_v()))

    def on_sensor(self, message: SensorVoltageBlock) -> None:
        end = message.first_sample_index + len(message.stroke_sensor_v)
        self.apply(pacing.Ack(time.monotonic(), end, *self.peers(), self.limit_v()))

    def on_wing_state(self, message: WingStateBlock) -> None:
        end = message.first_sample_index + len(message.stroke_deg)
        self.apply(pacing.Ack(time.monotonic(), end, *self.peers(), self.limit_v()))

    def close(self) -> None:
        """Shutdown: a zero block unless the last one already was (or nothing was sent)."""
        if self.apply(pacing.Close(self.limit_v())):
            time.sleep(0.1)  # let reliable delivery finish


def main(args: list[str] | None = None) -> int:
    return run_node(DriveNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
