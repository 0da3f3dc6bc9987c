"""drive_node: the synchronous (open-loop) drive generator, the paper's drive.

Publishes drive-command blocks (/flaair/drive): a sine, a linear chirp or a stepped sine,
with amplitude, bias and frequency parameters, clamped to +-drive_limit_v.

Pacing:
  realtime  blocks leave at the wall-clock rate of the signal.
  lockstep  as fast as the plant answers: at most lockstep_window_blocks command blocks
            ahead of the last sensor block received (deterministic, faster than real time).

Ending: after run_time_s, and on SIGINT/SIGTERM if the last block was not zero, one block of
zero drive follows, so the actuator is never left holding a voltage (a lockstep plant's drive
watchdog trips on a command source that falls silent while driving).

Usage: bin/flaair run flaair_sim drive_node --ros-args -p waveform:=chirp -p amplitude_v:=100.0
"""
from __future__ import annotations

import time

import numpy as np
from rclpy.node import Node

from flaair_common import topics
from flaair_common.blocks import from_array, stamp_from_time_s
from flaair_common.params import ParameterError, ParamSpec, declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import run_node
from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock, WingStateBlock
from flaair_sim import drive

NODE_NAME = "drive_node"
ACK_RETRY_S = 0.5  # lockstep: no acknowledgement for this long: one more block (< the plant's command_timeout_s)
CONFIG_FILE = "flaair.yaml"
PARAMS = [
    ParamSpec("sample_rate_hz", float, "Sample rate of the drive [Hz]", 1000.0, 1.0e6, read_only=True),
    ParamSpec("block_size", int, "Samples per command block", 1, 100000, read_only=True),
    ParamSpec("drive_limit_v", float, "Actuator safe range: drive clamped to +-this [V]", 0.0, 300.0),
    ParamSpec("waveform", str, "Drive waveform", choices=("sine", "chirp", "stepped_sine"), read_only=True),
    ParamSpec("amplitude_v", float, "Waveform amplitude (half of Vpp) [V]", 0.0, 300.0, read_only=True),
    ParamSpec("bias_v", float, "Offset added to the waveform [V]", -300.0, 300.0, read_only=True),
    ParamSpec("frequency_hz", float, "Sine frequency [Hz]", 0.0, 5000.0, read_only=True),
    ParamSpec("start_hz", float, "Chirp start / first stepped-sine frequency [Hz]", 0.0, 5000.0, read_only=True),
    ParamSpec("stop_hz", float, "Chirp stop / last stepped-sine frequency [Hz]", 0.0, 5000.0, read_only=True),
    ParamSpec("duration_s", float, "Chirp sweep duration [s]", 1e-3, 3600.0, read_only=True),
    ParamSpec("step_hz", float, "Stepped-sine frequency step [Hz]", 1e-3, 5000.0, read_only=True),
    ParamSpec("dwell_s", float, "Stepped-sine time at each frequency [s]", 1e-3, 3600.0, read_only=True),
    ParamSpec("lead_in_s", float, "Zero drive for this long before the waveform starts (a rest) [s]", 0.0, 3600.0, read_only=True),
    ParamSpec("run_time_s", float, "Stop after this much signal time, lead-in included (0: never) [s]", 0.0, 1e6, read_only=True),
    ParamSpec("pacing", str, "realtime or lockstep (paced by the plant's sensor blocks)", choices=("realtime", "lockstep"), read_only=True),
    ParamSpec("lockstep_window_blocks", int, "lockstep: command blocks allowed ahead of the plant", 1, 10000, read_only=True),
    ParamSpec("pace_on_wing_state", bool, "lockstep: pace on the front end's /flaair/wing_state (the whole chain) instead of the plant's sensor blocks", read_only=True),
    ParamSpec("min_subscribers", int, "Start only once this many subscribers listen (e.g. plant + recorder)", 1, 100, read_only=True),
    ParamSpec("first_sample_index", int, "Index of the first command sample (continue a plant's count)", 0, 2**62, read_only=True),
]


class DriveNode(Node):
    """Thin shell over flaair_sim.drive.drive_step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.fs_hz = self.p["sample_rate_hz"]
        self.block_size = self.p["block_size"]
        try:
            self.params = drive.DriveParams(
                kind=self.p["waveform"], amplitude_v=self.p["amplitude_v"], bias_v=self.p["bias_v"],
                frequency_hz=self.p["frequency_hz"], start_hz=self.p["start_hz"], stop_hz=self.p["stop_hz"],
                duration_s=self.p["duration_s"], step_hz=self.p["step_hz"], dwell_s=self.p["dwell_s"],
                lead_in_s=self.p["lead_in_s"],
            )
        except drive.DriveError as exc:
            raise ParameterError(str(exc)) from exc
        self.state = drive.DriveState()
        self.next_index = self.p["first_sample_index"]
        run_samples = int(round(self.p["run_time_s"] * self.fs_hz))
        self.total_samples = self.next_index + run_samples if run_samples else None
        self.last_block_zero = True
        self.last_ack_index, self.last_ack_wall, self.retries = -1, time.monotonic(), 0
        self.acknowledged_index = self.next_index
        self.publisher = self.create_publisher(DriveCommandBlock, topics.DRIVE, BLOCK_STREAM)
        if self.p["pacing"] == "lockstep":
            if self.p["pace_on_wing_state"]:
                self.ack = self.create_subscription(WingStateBlock, topics.WING_STATE, self.on_wing_state, BLOCK_STREAM)
            else:
                self.ack = self.create_subscription(SensorVoltageBlock, topics.SENSOR_VOLTAGE, self.on_sensor, BLOCK_STREAM)
            self.create_timer(0.002, self.publish_window)  # starts the stream once the plant subscribes
        else:
            self.wall_start_s: float | None = None
            self.create_timer(0.005, self.on_realtime_tick)
        self.get_logger().info(
            f"drive: {self.params.kind}, amplitude {self.params.amplitude_v:g} V, pacing {self.p['pacing']}"
        )

    def finished(self) -> bool:
        return self.total_samples is not None and self.next_index >= self.total_samples

    def publish_block(self, zero: bool = False) -> None:
        if zero:
            drive_v = np.zeros(self.block_size)
        else:
            self.state, drive_v = drive.drive_step(self.state, self.block_size, self.fs_hz, self.params)
        limit = self.get_parameter("drive_limit_v").value
        message = DriveCommandBlock(sample_rate_hz=self.fs_hz, first_sample_index=self.next_index)
        message.header.stamp = stamp_from_time_s(self.next_index / self.fs_hz)
        message.drive_v = from_array(np.clip(drive_v, -limit, limit))
        self.publisher.publish(message)
        self.next_index += self.block_size
        self.last_block_zero = not np.any(drive_v)
        if self.finished() and not self.last_block_zero:
            self.publish_block(zero=True)   # end of the run: leave the actuator at zero
            self.get_logger().info(f"run complete at sample {self.next_index - self.block_size}; zero drive sent")

    def close(self) -> None:
        """Shutdown: a zero block unless the last one already was (or nothing was sent)."""
        if self.next_index > self.p["first_sample_index"] and not self.last_block_zero:
            self.publish_block(zero=True)
            time.sleep(0.1)  # let reliable delivery finish

    def on_sensor(self, message: SensorVoltageBlock) -> None:
        self.acknowledged_index = message.first_sample_index + len(message.stroke_sensor_v)
        self.publish_window()

    def on_wing_state(self, message: WingStateBlock) -> None:
        self.acknowledged_index = message.first_sample_index + len(message.stroke_deg)
        self.publish_window()

    def publish_window(self) -> None:
        # Lockstep needs both ends matched before the first window: the command subscribers,
        # and our acknowledgement stream (missed acknowledgements would stall the run forever).
        if self.publisher.get_subscription_count() < self.p["min_subscribers"] or self.ack.get_publisher_count() == 0:
            return
        window = self.p["lockstep_window_blocks"] * self.block_size
        if self.acknowledged_index != self.last_ack_index:
            self.last_ack_index, self.last_ack_wall = self.acknowledged_index, time.monotonic()
        while not self.finished() and self.next_index < self.acknowledged_index + window:
            self.publish_block()
        # The plant's writer may match our acknowledgement reader a moment after we see it: the
        # first acknowledgements can be lost and the window never reopens. One more block makes
        # the plant step and answer again (harmless when the plant is merely slow).
        if not self.finished() and time.monotonic() - self.last_ack_wall > ACK_RETRY_S:
            self.retries += 1
            self.get_logger().warning(f"no acknowledgement for {ACK_RETRY_S:g} s at block {self.next_index}; "
                                      f"sending one more block ({self.retries})")
            self.last_ack_wall = time.monotonic()
            self.publish_block()

    def on_realtime_tick(self) -> None:
        if self.wall_start_s is None:
            if self.publisher.get_subscription_count() < self.p["min_subscribers"]:
                return
            self.wall_start_s = time.monotonic()
        due = int((time.monotonic() - self.wall_start_s) * self.fs_hz)
        while not self.finished() and self.next_index + self.block_size <= due:
            self.publish_block()


def main(args: list[str] | None = None) -> int:
    return run_node(DriveNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
