"""bridge_node: FLAAIR's side of the real-time target protocol (docs/REALTIME_PROTOCOL.md).

Sensor packets (listen_host:listen_port) become SensorVoltageBlock on /flaair/sensor_v (lost
samples NaN: the front end marks them invalid), the drive the target applied DriveCommandBlock
on /flaair/drive/applied. /flaair/drive goes to the target (target_host:target_port; empty /
0: the sender, `core.target`) lead_samples ahead, clamped to +-drive_limit_v; watchdogs and
stop packets: `flaair_bridge.core.bridge`, of which this is a thin shell. A reader thread
(flaair_bridge.udp, SCHED_FIFO at realtime_priority) shares the node with the executor.

Usage: bin/flaair run flaair_bridge bridge_node --ros-args -p listen_port:=25000 -p lead_samples:=20
"""

from __future__ import annotations

import sys
import threading
import time

from flaair_bridge import bridge_io as io
from flaair_bridge.bridge_io import PARAMS
from flaair_bridge.core import bridge, bridge_report, bridge_state, target
from flaair_common import intra, topics
from flaair_common.node import FlaairNode
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import log_notes, run_node, warn_counted

NODE_NAME = "bridge_node"
CONFIG_FILE = "flaair.yaml"
# process-wide: at the default 5 ms the reader thread got the GIL ~200 times/s, < 2000 packets/s
GIL_SWITCH_S = 1e-4
# a run's final stop packet is sent this many times (UDP may drop one)
STOP_COPIES = 3


class BridgeNode(FlaairNode):
    """Thin shell over flaair_bridge.core.bridge.step: UDP and messages to core inputs and back."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.params = io.params_from_values(p)
        # a configured target that never speaks still gets the stop packet at the end
        self.target = target.configured(p["target_host"], p["target_port"])
        # re-entered when composed: the loop answers in-process
        self.state, self.lock = bridge.initial_state(self.params), threading.RLock()
        self.timing: list[tuple[int, float, float]] = []
        self.bad_drive_messages, self.closed, self.cause_s = 0, False, float("nan")
        self.events = bridge_report.EventLog() if p["timing_file"] else None  # for benchmarks
        self.fs_hz, self.block_size = p["sample_rate_hz"], p["block_size"]
        self.sensor = intra.block_publisher(
            self, topics.SENSOR_VOLTAGE, self.block_size, BLOCK_STREAM
        )
        self.applied = (
            intra.block_publisher(self, topics.DRIVE_APPLIED, self.block_size, BLOCK_STREAM)
            if p["publish_applied"]
            else None
        )
        intra.subscribe_stream(
            self, topics.DRIVE, self.block_size, self.on_drive, BLOCK_STREAM, self.on_undecodable
        )
        self.create_timer(
            p["tick_period_s"],
            lambda: self.process(bridge_state.Tick(time.time(), self.endpoint.pending())),
        )
        sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_S))
        self.publish_health(lambda: self.state, io.bridge_health)
        # read only once held: a target already sending is answered through self.endpoint
        self.endpoint = io.open_endpoint(p, self.on_datagram)
        io.start_reading(self.endpoint, self.get_logger())
        self.get_logger().info(io.ready_text(p))

    def on_datagram(self, data: bytes, sender: tuple[str, int], arrival_s: float) -> None:
        host, port, sender = self.p["target_host"], self.p["target_port"], tuple(sender[:2])
        if not bridge.foreign_sender(self.state, sender, self.params):  # a stranger: not followed
            self.target, notes = target.follow(host, port, sender, self.target, data)
            log_notes(self.get_logger(), notes)
        answered = self.state.counters.drive_packets
        self.process(bridge_state.SensorDatagram(data, arrival_s, time.time(), sender))
        # the loop has answered: a gap until the next block
        if self.state.counters.drive_packets != answered:
            intra.use_gap()

    def on_undecodable(self, exc: Exception) -> None:
        self.bad_drive_messages += 1
        warn_counted(self.get_logger(), self.bad_drive_messages, f"drive message dropped: {exc}")

    def on_drive(self, message) -> None:
        # composed, the controller's closing zero block follows the stop packet
        if not self.closed:
            self.process(io.drive_input(message, time.time()))

    def process(self, inputs: bridge_state.Input, copies: int = 1) -> None:
        """Step the core with one input; publish its blocks, send its packets, log its notices."""
        # publishing inside: blocks from the thread and from the timer stay in order
        with self.lock:
            # composed, the drive this packet's blocks produce comes back nested, caused by it
            outer_cause_s = self.cause_s
            if isinstance(inputs, bridge_state.SensorDatagram):
                self.cause_s = inputs.now_s
            self.state, out = bridge.step(self.state, inputs, self.params)
            for packet in [packet for packet in out.packets for _ in range(copies)]:
                if error := self.send(packet):
                    text = f"drive packet not sent to {self.target}: {error}"
                    self.get_logger().warning(text, throttle_duration_sec=1.0)
            self.timing.extend(out.timing)
            counters = self.state.counters
            if self.events is not None:
                self.events.record(inputs, out, counters, time.time(), self.cause_s)
            for block in out.blocks:  # stamps: the target's sample clock, anchored to ROS time
                if self.sample_clock_offset_ns is None:
                    self.anchor_sample_clock(block.first_sample_index, self.fs_hz, "target")
                stamp_ns = self.stamp_ns_of(block.first_sample_index, self.fs_hz)
                self.sensor.publish(stamp_ns, io.sensor_fields(block, self.fs_hz))
                if self.applied is not None:
                    self.applied.publish(stamp_ns, io.applied_fields(block, self.fs_hz))
            self.cause_s = outer_cause_s
        log_notes(self.get_logger(), out.notes, lambda counter: getattr(counters, counter))

    def close(self) -> None:
        """End of the run: stop packet (STOP_COPIES times), receiver stopped, counters logged."""
        if self.closed:
            return
        self.closed = True
        # a reader behind its backlog would hold the lock against the stop packet
        self.endpoint.stop_reading()
        self.process(bridge_state.Stop(time.time(), "end of run"), copies=STOP_COPIES)
        self.endpoint.close()
        summary = bridge_report.summary(self.state.counters, self.timing)
        self.get_logger().info(f"bridge closed, stop packet sent: {summary}")
        if self.p["timing_file"]:
            io.save_timing(self.p["timing_file"], self.timing, self.events)

    def send(self, packet: bytes) -> str:
        """Send `packet` to the target (if known); an error's text, or empty."""
        return self.endpoint.send(packet, self.target) if self.target is not None else ""

    def destroy_node(self) -> None:
        # whoever owns the node (run_node, a shared executor): the run ends with a stop packet
        self.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(BridgeNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
