"""stroke_controller_node: holds the per-wingbeat stroke amplitude at a setpoint (paper Fig. 1c).

Subscribes to the front end's estimate (/flaair/wing_state) and answers each block with one
drive block (/flaair/drive) and a ControllerState (/flaair/controller/state; amplitude_scale
= command / feed-forward). A thin shell over flaair_control.core.stroke (wingbeat tracker, integral
law, sync sine or dSA filter) and flaair_control.core.safety (non-finite -> 0, slew limit, clamp to
+-drive_limit_v, signal-time watchdog). mode sync adjusts the drive amplitude at
sync_frequency_hz; mode dsa adjusts the dSA gain mu, the frequency stays free.

Run time: `bin/flaair param set /stroke_controller_node setpoint_deg 18` retargets (feed-forward
from the plant's amplitude response, the learned correction kept). The watchdog trips when no
wing-state block arrives for watchdog_timeout_s of wall-clock time or no valid one for
invalid_timeout_s of signal time: the drive ramps to zero over ramp_down_s, then zero blocks.
Start: once the plant and front end are up (start_delay_s), blocks_in_flight blocks are sent.
close() (Ctrl-C, SIGTERM) publishes a zero block.

Usage:
  bin/flaair run flaair_control stroke_controller_node --ros-args -p mode:=sync -p setpoint_deg:=12
"""

from __future__ import annotations

import time

import numpy as np
from rcl_interfaces.msg import SetParametersResult

from flaair_common import topics
from flaair_common.blocks import stamp_from_time_s
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM, STATUS
from flaair_common.runtime import run_node
from flaair_control import stroke_io as io
from flaair_control.core import safety, stroke
from flaair_msgs.msg import ControllerState, DriveCommandBlock, WingStateBlock

NODE_NAME = "stroke_controller_node"
CONFIG_FILE = "flaair.yaml"
PARAMS = stroke.NODE_PARAMS


class StrokeControllerNode(FlaairNode):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.fs, self.n, self.in_flight = (
            p["sample_rate_hz"],
            p["block_size"],
            p["blocks_in_flight"],
        )
        self.setup = io.setup_from_values(p)
        self.params, self.guard = self.setup.params, self.setup.guard
        self.state, self.safety = (
            stroke.initial_state(self.params),
            safety.initial_state(self.guard),
        )
        self.next_index, self.mode, self.last_wall, self.peers_wall, self.answered = (
            0,
            "waiting",
            time.monotonic(),
            None,
            False,
        )
        self.drive_pub = self.create_publisher(DriveCommandBlock, topics.DRIVE, BLOCK_STREAM)
        self.state_pub = self.create_publisher(ControllerState, topics.CONTROLLER_STATE, STATUS)
        self.create_subscription(
            WingStateBlock, topics.WING_STATE, self.on_wing_state, BLOCK_STREAM
        )
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.create_timer(0.02, self.on_timer)
        self.get_logger().info(io.ready_text(self.params))

    def on_set_parameters(self, parameters) -> SetParametersResult:
        for param in parameters:
            if param.name == "setpoint_deg":
                try:
                    self.params = io.retargeted(self.setup, self.params, self.p, float(param.value))
                except ValueError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
                self.get_logger().info(
                    f"setpoint {param.value:g} deg: feed-forward {self.params.command_nominal:.4g}"
                )
        return SetParametersResult(successful=True)

    def on_wing_state(self, msg: WingStateBlock) -> None:
        if self.mode == "waiting" and self.drive_pub.get_subscription_count() > 0:
            self.mode = "loop"
        if self.mode != "loop":
            return
        self.last_wall, self.answered = time.monotonic(), True
        self.send(
            *io.wing_input(
                {
                    "stroke_deg": msg.stroke_deg,
                    "stroke_valid": msg.stroke_valid,
                    "stroke_velocity_deg_s": msg.stroke_velocity_deg_s,
                },
                self.n,
            )
        )

    def send(
        self, stroke_rad: np.ndarray, velocity: np.ndarray, valid: np.ndarray, ok: bool | None
    ) -> None:
        """Cores on one block; publish the guarded drive block and the controller state."""
        t = self.next_index / self.fs
        if stroke_rad.size != self.n:
            stroke_rad, velocity, valid, _ = io.empty_input(self.n)
        self.state, out = stroke.step(
            self.state,
            stroke.StrokeInputs(stroke_rad, velocity, valid, self.next_index),
            self.params,
        )
        self.safety, guarded = safety.step(
            self.safety, safety.SafetyInputs(out.drive_v, t, ok), self.guard
        )
        self.publish(
            guarded.drive_v,
            guarded.tripped,
            bool(np.abs(out.drive_v).max() > self.guard.drive_limit_v),
        )
        if self.p["run_time_s"] > 0 and self.next_index / self.fs >= self.p["run_time_s"]:
            self.mode = "done"
            self.publish(np.zeros(self.n), guarded.tripped, False)
            self.get_logger().info(io.complete_text(self.state))

    def publish(self, drive_v: np.ndarray, tripped: bool, clamped: bool) -> None:
        stamp = stamp_from_time_s(self.next_index / self.fs)
        block = DriveCommandBlock(
            sample_rate_hz=self.fs, first_sample_index=self.next_index, drive_v=drive_v.tolist()
        )
        block.header.stamp = stamp
        self.drive_pub.publish(block)
        watchdog = ControllerState.WATCHDOG_TRIPPED if tripped else ControllerState.WATCHDOG_OK
        state = ControllerState(
            **io.state_fields(self.params, self.state, drive_v, clamped),
            watchdog=watchdog,
            fault="watchdog" if tripped else "",
        )
        state.header.stamp = stamp
        self.state_pub.publish(state)
        self.next_index += self.n

    def on_timer(self) -> None:
        now = time.monotonic()
        if self.mode == "waiting":
            ready = (
                self.drive_pub.get_subscription_count() > 0
                and self.count_publishers(topics.WING_STATE) > 0
            )
            self.peers_wall = (self.peers_wall or now) if ready else None
            if ready and now - self.peers_wall >= self.p["start_delay_s"]:
                self.mode, self.last_wall = "loop", now
                for _ in range(self.in_flight):
                    self.send(*io.empty_input(self.n))
        elif (
            self.mode == "loop"
            and not self.answered
            and now - self.last_wall > self.p["start_retry_s"]
        ):
            self.last_wall = now  # no answer to the start yet (a lost first block): one more
            self.send(*io.empty_input(self.n))
        elif self.mode == "loop" and now - self.last_wall > self.p["watchdog_timeout_s"]:
            self.mode = "tripped"
            self.get_logger().error(
                "WATCHDOG TRIPPED: no wing-state block for "
                f"{now - self.last_wall:.2f} s; ramping to zero"
            )
            self.safety = safety.note_sensor_block(
                self.safety, self.next_index / self.fs, False, self.guard
            )
            while (
                self.next_index / self.fs
                < self.safety.trip_time_s + self.p["ramp_down_s"] + self.n / self.fs
            ):
                self.send(*io.empty_input(self.n))

    def close(self) -> None:
        """Shutdown: a zero-drive block so the actuator does not hold the last command."""
        self.publish(np.zeros(self.n), self.safety.status == safety.TRIPPED, False)
        time.sleep(0.1)


def main(args: list[str] | None = None) -> int:
    return run_node(StrokeControllerNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
