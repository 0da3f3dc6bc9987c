"""bridge_node: FLAAIR's side of the real-time target protocol (docs/REALTIME_PROTOCOL.md), over UDP.

The target's sensor packets (listen_host:listen_port) become SensorVoltageBlock on
/flaair/sensor_v (lost samples as NaN, which the front end marks invalid) and the drive the
target applied becomes DriveCommandBlock on /flaair/drive/applied. DriveCommandBlock from
/flaair/drive go to the target (target_host:target_port; empty / 0: whoever sends the sensor
packets) lead_samples ahead of its clock, clamped to +-drive_limit_v. A non-zero drive stream
that falls silent for drive_timeout_s, or a target silent for sensor_timeout_s, sends a stop
packet; so does every end of a run (Ctrl-C, SIGTERM, shutdown). Malformed datagrams are
counted and logged (rate-limited). A thin shell over flaair_bridge.bridge.step; the socket is
read by a thread (flaair_bridge.udp) that shares the core with the executor under one lock, so
the class can be loaded into any executor.

Usage: bin/flaair run flaair_bridge bridge_node --ros-args -p listen_port:=25000 -p lead_samples:=20
"""
from __future__ import annotations

import sys
import threading
import time

import numpy as np
from rclpy.node import Node

from flaair_bridge import bridge, udp
from flaair_common import cdr, intra, topics
from flaair_common.blocks import stamp_ns_of_sample
from flaair_common.params import ParameterError, ParamSpec, declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import run_node, warn_counted
from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock

NODE_NAME = "bridge_node"
CONFIG_FILE = "flaair.yaml"
GIL_SWITCH_S = 1e-4   # process-wide: at the default 5 ms the reader thread got the GIL ~200 times/s, < 2000 packets/s
STOP_COPIES = 3                           # a run's final stop packet is sent this many times (UDP may drop one)
PARAMS = [
    ParamSpec("sample_rate_hz", float, "Sample rate of the target and every block stream [Hz]", 1000.0, 1.0e6, read_only=True),
    ParamSpec("block_size", int, "Samples per published block", 1, 1000, read_only=True),
    ParamSpec("drive_limit_v", float, "Drive clamped to +-this before it is sent [V]", 0.0, 300.0, read_only=True),
    ParamSpec("listen_host", str, "Address the target's sensor packets arrive at", read_only=True),
    ParamSpec("listen_port", int, "UDP port the target's sensor packets arrive at", 1, 65535, read_only=True),
    ParamSpec("target_host", str, "Where drive packets go (empty: the sender of the sensor packets)", read_only=True),
    ParamSpec("target_port", int, "UDP port drive packets go to (0: the sender's port)", 0, 65535, read_only=True),
    ParamSpec("lead_samples", int, "Drive sent this many samples ahead of the target's clock", 0, 100000, read_only=True),
    ParamSpec("max_ahead_samples", int, "Drive never sent more than this beyond clock + lead", 0, 1000000, read_only=True),
    ParamSpec("max_fill_samples", int, "Lost samples up to this many are published as NaN; longer gaps jump", 0, 10000000, read_only=True),
    ParamSpec("resync_packets", int, "Stale packets in a row that mean the target restarted", 1, 1000000, read_only=True),
    ParamSpec("drive_timeout_s", float, "Non-zero drive stream silent this long: stop packet [s]", 1e-4, 60.0, read_only=True),
    ParamSpec("sensor_timeout_s", float, "Target silent this long: stop packet, samples published as lost [s]", 1e-4, 60.0, read_only=True),
    ParamSpec("tick_period_s", float, "Wall-clock period of the timeout checks [s]", 1e-4, 1.0, read_only=True),
    ParamSpec("receive_buffer_bytes", int, "UDP receive buffer (absorbs the bridge's stalls)", 65536, 1 << 30, read_only=True),
    ParamSpec("publish_applied", bool, "Publish the applied drive on /flaair/drive/applied", read_only=True),
    ParamSpec("timing_file", str, "Event times (.npz) at exit for benchmarks (empty: off)", read_only=True),
]


class BridgeNode(Node):
    """Thin shell over flaair_bridge.bridge.step: UDP and messages to core inputs and back."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        p = self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        try:
            self.params = bridge.BridgeParams(**{name: p[name] for name in bridge.BridgeParams.__dataclass_fields__})
        except bridge.BridgeParameterError as exc:
            raise ParameterError(str(exc)) from exc
        self.target: tuple[str, int] | None = None   # where drive packets go (known once the target speaks)
        self.state, self.lock = bridge.initial_state(), threading.RLock()   # re-entered when composed: the loop answers in-process
        self.timing: list[tuple[int, float, float]] = []
        self.events = bridge.EventLog() if p["timing_file"] else None   # raw event times for benchmarks
        self.fs_hz, self.block_size = p["sample_rate_hz"], p["block_size"]
        self.sensor_codec = cdr.FixedCodec(cdr.SENSOR_VOLTAGE_BLOCK, self.block_size, topics.FRAME_ID)
        self.drive_codec = cdr.FixedCodec(cdr.DRIVE_COMMAND_BLOCK, self.block_size)
        self.sensor = intra.BlockPublisher(self, SensorVoltageBlock, topics.SENSOR_VOLTAGE, self.sensor_codec, BLOCK_STREAM)
        self.applied = intra.BlockPublisher(self, DriveCommandBlock, topics.DRIVE_APPLIED, self.drive_codec,
                                            BLOCK_STREAM) if p["publish_applied"] else None
        intra.subscribe_blocks(self, DriveCommandBlock, topics.DRIVE, self.drive_codec, self.on_drive, BLOCK_STREAM,
                               self.on_undecodable)
        self.create_timer(p["tick_period_s"], lambda: self.process(bridge.Tick(time.time(), self.endpoint.pending())))
        sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_S))
        self.bad_drive_messages, self.closed, self.cause_s = 0, False, float("nan")
        try:   # the socket last: its reader thread delivers at once, into a fully built node
            self.endpoint = udp.DatagramEndpoint(p["listen_host"], p["listen_port"], p["receive_buffer_bytes"],
                                                 self.on_datagram)
        except OSError as exc:
            raise ParameterError(f"parameters 'listen_host'/'listen_port' = {p['listen_host']}:{p['listen_port']}: {exc}") from exc
        self.get_logger().info(
            f"bridge ready: sensor packets on udp {p['listen_host']}:{p['listen_port']}, drive to "
            f"{p['target_host'] or '<sender>'}:{p['target_port'] or '<sender port>'}, lead {p['lead_samples']} samples "
            f"({1e3 * p['lead_samples'] / self.fs_hz:g} ms), limit +-{p['drive_limit_v']:g} V")

    def on_datagram(self, data: bytes, sender: tuple[str, int], arrival_s: float) -> None:
        self.target = (self.p["target_host"] or sender[0], self.p["target_port"] or sender[1])
        self.process(bridge.SensorDatagram(data, arrival_s, time.time()))

    def on_undecodable(self, exc: Exception) -> None:
        self.bad_drive_messages += 1
        warn_counted(self.get_logger(), self.bad_drive_messages, f"drive message dropped: {exc}")

    def on_drive(self, message) -> None:
        self.process(bridge.DriveBlock(int(message["first_sample_index"]), np.array(message["drive_v"]), time.time()))

    def process(self, inputs: bridge.Input, copies: int = 1) -> None:
        """Step the core with one input; publish its blocks, send its packets, log its notices."""
        with self.lock:  # publishing inside: blocks from the thread and from the timer stay in order
            outer_cause_s = self.cause_s   # composed: the drive this packet's blocks produce comes back nested
            if isinstance(inputs, bridge.SensorDatagram):
                self.cause_s = inputs.now_s
            self.state, out = bridge.step(self.state, inputs, self.params)
            for packet in [packet for packet in out.packets for _ in range(copies)]:
                if error := (self.endpoint.send(packet, self.target) if self.target is not None else ""):
                    self.get_logger().warning(f"drive packet not sent to {self.target}: {error}", throttle_duration_sec=1.0)
            self.timing.extend(out.timing)
            counters = self.state.counters
            if self.events is not None:
                self.events.record(inputs, out, counters, time.time(), self.cause_s)
            for block in out.blocks:
                stamp_ns = stamp_ns_of_sample(block.first_sample_index, self.fs_hz)
                self.sensor.publish(stamp_ns, {
                    "sample_rate_hz": self.fs_hz, "first_sample_index": block.first_sample_index,
                    "stroke_sensor_v": block.stroke_sensor_v, "pitch_sensor_v": block.pitch_sensor_v})
                if self.applied is not None:
                    self.applied.publish(stamp_ns, {"sample_rate_hz": self.fs_hz, "first_sample_index": block.first_sample_index,
                                                    "drive_v": block.drive_v})
            self.cause_s = outer_cause_s
        for notice in out.notices:  # errors always; the rest rate-limited by their counter
            log = self.get_logger().error if notice.error else None
            log(notice.text) if log else warn_counted(self.get_logger(), getattr(counters, notice.kind), notice.text)

    def close(self) -> None:
        """End of the run: stop packet (sent STOP_COPIES times), receiver stopped, counters logged."""
        if self.closed:
            return
        self.closed = True
        self.endpoint.stop_reading()   # a reader behind its backlog would hold the lock against the stop packet
        self.process(bridge.Stop(time.time(), "end of run"), copies=STOP_COPIES)
        self.endpoint.close()
        self.get_logger().info(f"bridge closed, stop packet sent: {bridge.summary(self.state.counters, self.timing)}")
        if self.p["timing_file"]:
            np.savez(self.p["timing_file"], timing=np.array(self.timing).reshape(-1, 3), **self.events.arrays())

    def destroy_node(self) -> None:
        self.close()  # whoever owns the node (run_node, a shared executor): the run ends with a stop packet
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(BridgeNode, PARAMS, CONFIG_FILE, NODE_NAME, args)


if __name__ == "__main__":
    raise SystemExit(main())
