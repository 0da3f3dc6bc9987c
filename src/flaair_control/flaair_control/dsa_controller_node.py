"""dsa_controller_node: the delayed-stretch-activation (dSA) controller closing the wingbeat loop.

One drive block (/flaair/drive) per wing-state block (/flaair/wing_state), a ControllerState
(/flaair/controller/state) with every state_every_blocks-th. A thin shell over the pure loop
supervisor `flaair_control.core.supervisor` (drive law, K_r ramp, delay compensation, safety
and watchdogs: read its docstring and `core.dsa`'s). Setting kr_target or kr_ramp_duration_s
while running starts a new ramp from the current K_r; the std_srvs/Trigger service
~/reset_watchdog re-arms a tripped watchdog; health on /diagnostics; G_a from the model file.
Usage: bin/flaair run flaair_control dsa_controller_node [--ros-args -p kr_ramp_start_s:=0.3 ...]
"""

from __future__ import annotations

import threading
import time

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from std_srvs.srv import Trigger

from flaair_common import cdr, intra, topics
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM, STATUS
from flaair_common.runtime import log_notes, run_node, warn_counted
from flaair_control import dsa_io as io
from flaair_control.core import loop_state
from flaair_control.core import supervisor as sv
from flaair_control.dsa_io import CONFIG_FILE, DSA_CONTROLLER_PARAMS
from flaair_msgs.msg import CollisionEvent, ControllerState

NODE_NAME = "dsa_controller_node"
PARAMS = DSA_CONTROLLER_PARAMS
WATCHDOG = {False: ControllerState.WATCHDOG_OK, True: ControllerState.WATCHDOG_TRIPPED}


class DsaControllerNode(FlaairNode):
    """Thin shell over flaair_control.core.supervisor.step."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.params = io.supervisor_params_from_values(p)
        self.state = sv.initial_state(self.params)
        sv.warm_up(self.params)  # the kernels load now, not on the first live block
        self.block_size, self.undecodable = p["block_size"], 0
        self.timing: list[tuple[int, float, float]] | None = [] if p["timing_file"] else None
        # CDR bytes or in-process (intra); a UDP thread may deliver the wing state
        self.lock = threading.RLock()
        self.drive = intra.block_publisher(self, topics.DRIVE, self.block_size, BLOCK_STREAM)
        codec = cdr.GeneralCodec(cdr.CONTROLLER_STATE)
        self.state_pub = intra.BlockPublisher(
            self, ControllerState, topics.CONTROLLER_STATE, codec, BLOCK_STREAM
        )
        on_wing, on_bad = self.on_wing_state, self.on_undecodable
        intra.subscribe_stream(
            self, topics.WING_STATE, self.block_size, on_wing, BLOCK_STREAM, on_bad
        )
        self.create_subscription(
            CollisionEvent, topics.COLLISION_EVENTS, self.on_collision_event, STATUS
        )  # volatile
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.create_timer(self.params.timer_period_s, self.on_timer)
        self.create_service(Trigger, "~/reset_watchdog", self.on_reset_watchdog)
        self.publish_health(lambda: self.state, io.controller_health)
        self.get_logger().info("dSA controller ready: " + io.describe_loop(self.params, p))

    def advance(
        self, inputs: loop_state.Input, t_receive: float | None = None
    ) -> loop_state.Outputs:
        """Run the supervisor on one event; publish its blocks, log its notes."""
        with self.lock:
            self.state, out = sv.step(self.state, inputs, self.params)
            for block in out.blocks:
                self.publish(block, t_receive)
        log_notes(self.get_logger(), out.notes, lambda counter: getattr(self.state.counts, counter))
        return out

    def publish(self, b: loop_state.DriveOut, t_receive: float | None) -> None:
        stamp_ns = self.stamp_ns_of(b.first_sample_index, self.params.sample_rate_hz)
        self.drive.publish(stamp_ns, io.drive_fields(b, self.params.sample_rate_hz))
        if b.answers_wing_block and self.timing is not None and t_receive is not None:
            self.timing.append((b.first_sample_index, t_receive, time.monotonic()))
        # volatile: no listener, nothing lost
        if b.with_state and self.state_pub.has_listeners():
            self.state_pub.publish(stamp_ns, io.controller_state_fields(b, WATCHDOG[b.tripped]))

    def on_undecodable(self, exc: Exception) -> None:
        self.undecodable += 1
        warn_counted(self.get_logger(), self.undecodable, io.dropped_text(exc, self.undecodable))

    def on_wing_state(self, m) -> None:
        t_receive = time.monotonic()
        self.follow_sample_clock(m, self.params.sample_rate_hz)  # stamps: the wing state's clock
        if self.state.mode == loop_state.DONE:
            return
        # only the start reads them (rclpy: ~20 us)
        peers = self.peers() if self.state.mode == loop_state.WAITING else 0
        self.advance(io.supervisor_wing_input(m, t_receive, peers), t_receive)

    def on_collision_event(self, m: CollisionEvent) -> None:
        onset = m.kind == CollisionEvent.ONSET
        self.advance(
            loop_state.Collision(time.monotonic(), onset, m.wingbeat_index, m.spectrum_rmse_deg)
        )

    def on_set_parameters(self, parameters) -> SetParametersResult:
        """kr_target / kr_ramp_duration_s: a new ramp from the current K_r."""
        changes = {param.name: param.value for param in parameters}
        request = io.ramp_request(changes, lambda name: self.get_parameter(name).value)
        out = self.advance(request) if request is not None else None
        if out is not None and out.refused:
            return SetParametersResult(successful=False, reason=out.refused)
        return SetParametersResult(successful=True)

    def on_reset_watchdog(self, request: Trigger.Request, response: Trigger.Response):
        out = self.advance(loop_state.ResetWatchdog(time.monotonic()))
        response.success, response.message = io.reset_reply(out.notes, self.state.mode)
        return response

    def on_timer(self) -> None:
        peers = (0, 0, 0)  # only the start reads them (rclpy's graph queries, every tick)
        if self.state.mode == loop_state.WAITING:
            count = self.count_publishers
            peers = (self.peers(), count(topics.SENSOR_VOLTAGE), count(topics.WING_STATE))
        self.advance(loop_state.Tick(time.monotonic(), *peers))

    def peers(self) -> int:
        """/flaair/drive's subscribers (0 until min_stream_listeners, min_state_subscribers)."""
        ready = (
            intra.dds_listeners() >= self.p["min_stream_listeners"]
            and self.state_pub.subscription_count() >= self.p["min_state_subscribers"]
        )
        return self.drive.subscription_count() if ready else 0

    def close(self) -> None:
        """Shutdown: a zero-drive block so the actuator does not hold the last command."""
        self.advance(loop_state.Close())
        if self.timing:
            np.savez(self.p["timing_file"], timing=np.array(self.timing))
        time.sleep(0.1)  # let reliable delivery of the zero block finish


def main(args: list[str] | None = None) -> int:
    return run_node(DsaControllerNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
