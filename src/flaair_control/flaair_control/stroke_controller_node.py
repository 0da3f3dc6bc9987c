"""stroke_controller_node: holds the per-wingbeat stroke amplitude at a setpoint (paper Fig. 1c).

Subscribes to the front end's estimate (/flaair/wing_state) and answers each block with one
drive block (/flaair/drive) and a ControllerState (/flaair/controller/state; amplitude_scale
= command / feed-forward). A thin shell over flaair_control.core.stroke (wingbeat tracker, integral
law, sync sine or dSA filter) and flaair_control.core.safety (non-finite -> 0, slew limit, clamp to
+-drive_limit_v, signal-time watchdog). mode sync adjusts the drive amplitude at
sync_frequency_hz; mode dsa adjusts the dSA gain mu, the frequency stays free.

Run time: `bin/flaair param set /stroke_controller_node setpoint_deg 18` retargets (feed-forward
from the plant's amplitude response, the learned correction kept). Start, start retry and the
wall-clock watchdog: `flaair_control.core.stroke_loop`; after a trip the drive ramps to zero
over ramp_down_s, then zero blocks. close() (Ctrl-C, SIGTERM) publishes a zero block.

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
from flaair_control.core import safety, stroke, stroke_loop
from flaair_msgs.msg import ControllerState, DriveCommandBlock, WingStateBlock

NODE_NAME = "stroke_controller_node"
CONFIG_FILE = "flaair.yaml"
PARAMS = stroke.NODE_PARAMS


class StrokeControllerNode(FlaairNode):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.fs, self.n = p["sample_rate_hz"], p["block_size"]
        self.in_flight = p["blocks_in_flight"]
        self.setup = io.setup_from_values(p)
        self.params, self.guard = self.setup.params, self.setup.guard
        self.state = stroke.initial_state(self.params)
        self.safety = safety.initial_state(self.guard)
        self.timing_params = io.timing_params(p)
        self.loop = stroke_loop.initial_state(self.timing_params, t_wall=time.monotonic())
        self.next_index = 0
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
        subscribed = self.drive_pub.get_subscription_count() > 0
        self.loop, answer = stroke_loop.on_wing_state(self.loop, time.monotonic(), subscribed)
        if answer:
            self.send(*io.wing_input(io.wing_fields(msg), self.n))

    def send(
        self, stroke_rad: np.ndarray, velocity: np.ndarray, valid: np.ndarray, ok: bool | None
    ) -> None:
        """Cores on one block; publish the guarded drive block and the controller state."""
        t = self.next_index / self.fs
        if stroke_rad.size != self.n:
            stroke_rad, velocity, valid, _ = io.empty_input(self.n)
        inputs = stroke.StrokeInputs(stroke_rad, velocity, valid, self.next_index)
        self.state, out = stroke.step(self.state, inputs, self.params)
        guard = safety.SafetyInputs(out.drive_v, t, ok)
        self.safety, guarded = safety.step(self.safety, guard, self.guard)
        clamped = bool(np.abs(out.drive_v).max() > self.guard.drive_limit_v)
        self.publish(guarded.drive_v, guarded.tripped, clamped)
        if self.p["run_time_s"] > 0 and self.next_index / self.fs >= self.p["run_time_s"]:
            self.loop = self.loop._replace(mode=stroke_loop.DONE)
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
        up = self.drive_pub.get_subscription_count() > 0 and self.count_publishers(
            topics.WING_STATE
        )
        self.loop, action = stroke_loop.on_timer(self.loop, now, bool(up), self.timing_params)
        if action in (stroke_loop.START, stroke_loop.RETRY):
            for _ in range(self.in_flight if action == stroke_loop.START else 1):
                self.send(*io.empty_input(self.n))
        elif action == stroke_loop.TRIP:
            silent = now - self.loop.last_wall
            self.get_logger().error(
                f"WATCHDOG TRIPPED: no wing-state block for {silent:.2f} s; ramping to zero"
            )
            t_s = self.next_index / self.fs
            self.safety = safety.note_sensor_block(self.safety, t_s, False, self.guard)
            end_s = self.safety.trip_time_s + self.p["ramp_down_s"] + self.n / self.fs
            while self.next_index / self.fs < end_s:
                self.send(*io.empty_input(self.n))

    def close(self) -> None:
        """Shutdown: a zero-drive block so the actuator does not hold the last command."""
        self.publish(np.zeros(self.n), self.safety.status == safety.TRIPPED, False)
        time.sleep(0.1)


def main(args: list[str] | None = None) -> int:
    return run_node(StrokeControllerNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
