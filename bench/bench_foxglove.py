"""Live view benchmark: does the Foxglove live view keep up with four 20 kHz block streams.

Source: one publisher process streams what the graph streams to the live view (drive, sensor
voltages, ground truth, estimate: 20 kHz each in 10-sample blocks, 8,000 blocks/s, as raw
CDR) for --duration seconds and says how many blocks it sent, so "streamed" is exact. The
live view (foxglove_node) serves every sample (or every Nth) as its own message; a WebSocket
client in this process subscribes to the four channels and counts what arrives. The client
parses the frames off the socket itself (RawFoxgloveCounter, ~1 us a frame) so that it, not
the live view, is never what falls behind; `flaair_tools.liveview.foxglove_client` (the
`websockets` package, ~12 us a frame) cannot take 80,000 frames/s on a loaded 2-core machine.

Figures, each beside its same-run baseline:
- messages per second delivered to the client, and delivered / streamed (4 x 20,000 samples/s
  at decimation 1): the live view keeps up at >= 0.95;
- CPU the live view adds: CPU seconds of the foxglove_node process per second of signal, beside
  the source's own CPU per second of signal (the same run).

Run: scripts/in_env.sh nice -n 10 python bench/bench_foxglove.py
[--duration 10] [--json out/bench_foxglove.json]
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import socket
import struct
import sys
import tempfile
import time
from pathlib import Path

import psutil

from benchlib import Figure, compare, info, print_table, write_json
from flaair_common.graph import Graph, node_argv, wait_for
from flaair_tools.liveview import live_view

FS_HZ, BLOCK, STREAMS = 20000.0, 10, 4
# The source: the live view's four block streams as raw
# CDR, paced by the wall clock; prints what it sent.
SOURCE = r"""
import json, sys, time
import numpy as np
import rclpy
from flaair_common import cdr, topics
from flaair_common.qos import BLOCK_STREAM
from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock, WingStateBlock
n, fs, duration_s = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node("live_view_source")
streams = [(topics.DRIVE, DriveCommandBlock, cdr.DRIVE_COMMAND_BLOCK),
           (topics.SENSOR_VOLTAGE, SensorVoltageBlock, cdr.SENSOR_VOLTAGE_BLOCK),
           (topics.WING_STATE_TRUTH, WingStateBlock, cdr.WING_STATE_BLOCK),
           (topics.WING_STATE, WingStateBlock, cdr.WING_STATE_BLOCK)]
publishers = [(node.create_publisher(cls, topic, BLOCK_STREAM),
               cdr.FixedCodec(layout, n, topics.FRAME_ID))
              for topic, cls, layout in streams]
deadline = time.monotonic() + 60.0
while time.monotonic() < deadline and any(p.get_subscription_count() == 0 for p, _ in publishers):
    time.sleep(0.05)
offsets_s, blocks = np.arange(n) / fs, int(duration_s * fs / n)
ones = np.ones(n, bool)
start = time.monotonic()
for i in range(blocks):
    delay = start + i * n / fs - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    wave = 40.0 * np.sin(2 * np.pi * 140.0 * (i * n / fs + offsets_s))
    values = {"sample_rate_hz": fs, "first_sample_index": i * n, "drive_v": wave,
              "stroke_sensor_v": 1.25 + wave / 50, "pitch_sensor_v": 1.25 - wave / 50,
              "stroke_deg": wave, "pitch_deg": 0.5 * wave, "stroke_velocity_deg_s": wave,
              "stroke_valid": ones, "pitch_valid": ones, "source": 1}
    for publisher, codec in publishers:
        publisher.publish(codec.encode(round(i * n / fs * 1e9), values))
print(json.dumps({"blocks": blocks, "elapsed_s": time.monotonic() - start}), flush=True)
time.sleep(2.0)
"""


class RawFoxgloveCounter:
    """A Foxglove WebSocket client that only counts: the handshake, `advertise`, `subscribe`, then
    message-data frames counted per subscription and the latest Time broadcast (server frames are
    unmasked and unfragmented; parsed straight off the socket in bulk).
    """

    def __init__(self, port: int, timeout_s: float) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: "
                "websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: "
                f"{key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: "
                "foxglove.sdk.v1, foxglove.websocket.v1\r\n\r\n"
            ).encode()
        )
        self.buffer = b""
        while b"\r\n\r\n" not in self.buffer:
            self._read()
        head, self.buffer = self.buffer.split(b"\r\n\r\n", 1)
        if b" 101 " not in head.split(b"\r\n", 1)[0]:
            raise OSError(f"no WebSocket upgrade: {head[:80]!r}")
        self.channels: dict[str, int] = {}
        self.counts: dict[int, int] = {}
        self.latest_time_ns: int | None = None

    def _read(self) -> bool:
        try:
            chunk = self.sock.recv(1 << 20)
        except TimeoutError:
            return False
        if not chunk:
            raise OSError("server closed the connection")
        self.buffer += chunk
        return True

    def poll(self) -> bool:
        """Read what has arrived and handle every whole
        frame; False if nothing arrived in the timeout.
        """
        arrived = self._read()
        data, position, end = self.buffer, 0, len(self.buffer)
        counts = self.counts
        while end - position >= 2:
            opcode, length, head = data[position] & 0x0F, data[position + 1] & 0x7F, 2
            if length == 126:
                if end - position < 4:
                    break
                length, head = struct.unpack_from(">H", data, position + 2)[0], 4
            elif length == 127:
                if end - position < 10:
                    break
                length, head = struct.unpack_from(">Q", data, position + 2)[0], 10
            if end - position < head + length:
                break
            body = position + head
            if opcode == 2 and data[body] == 1:
                subscription = struct.unpack_from("<I", data, body + 1)[0]
                counts[subscription] = counts.get(subscription, 0) + 1
            elif opcode == 2 and data[body] == 2:
                self.latest_time_ns = struct.unpack_from("<Q", data, body + 1)[0]
            elif opcode == 1:
                message = json.loads(data[body : body + length])
                if message.get("op") == "advertise":
                    self.channels.update({c["topic"]: c["id"] for c in message["channels"]})
            position = body + length
        self.buffer = data[position:]
        return arrived

    def subscribe(self, topics: list[str]) -> None:
        """Subscribe to `topics` (subscription id = position + 1), once they are advertised."""
        while not all(topic in self.channels for topic in topics):
            self.poll()
        text = json.dumps(
            {
                "op": "subscribe",
                "subscriptions": [
                    {"id": number, "channelId": self.channels[topic]}
                    for number, topic in enumerate(topics, start=1)
                ],
            }
        ).encode()
        mask = os.urandom(4)
        header = (
            bytes([0x81, 0x80 | 126]) + struct.pack(">H", len(text))
            if len(text) >= 126
            else bytes([0x81, 0x80 | len(text)])
        )
        self.sock.sendall(header + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(text)))

    def count(self) -> int:
        return sum(self.counts.values())

    def close(self) -> None:
        self.sock.close()


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _cpu_s(process) -> float:
    times = psutil.Process(process.pid).cpu_times()
    return times.user + times.system


def run(
    duration_s: float,
    decimation: int,
    logs: Path,
    node: list[str] | None = None,
    extra: tuple[str, ...] = (),
) -> dict[str, float]:
    """Stream for `duration_s` into the live view at `decimation` (`node`: another foxglove_node
    command, `extra`: more ROS arguments); what was streamed and delivered, and the CPU.
    """
    port = _free_port()
    with Graph(log_dir=logs) as graph:
        args = ["-p", f"port:={port}", "-p", f"sample_decimation:={decimation}", *extra]
        fox = graph.start(
            "foxglove",
            [*node, "--ros-args", *args]
            if node
            else node_argv("flaair_tools", "foxglove_node", args),
        )
        client = None

        def connect() -> bool:
            nonlocal client
            try:
                client = RawFoxgloveCounter(port, 0.05)
                return True
            except OSError:
                graph.check_alive()
                return False

        if not wait_for(connect, 120.0, 0.5):
            raise SystemExit(
                f"foxglove_node did not listen on {port}:\n{graph.log_tail('foxglove')}"
            )
        client.subscribe([stream.topic for stream in live_view.STREAMS.values()])
        source = graph.start(
            "source", [sys.executable, "-c", SOURCE, str(BLOCK), str(FS_HZ), str(duration_s)]
        )
        fox_cpu0, source_cpu, sampled = _cpu_s(fox), 0.0, time.monotonic()
        # the source sleeps 2 s after its last block: the client drains meanwhile
        while source.poll() is None:
            client.poll()
            if time.monotonic() - sampled > 0.2:
                try:
                    source_cpu, sampled = _cpu_s(source), time.monotonic()
                except psutil.NoSuchProcess:
                    break
        fox_cpu = _cpu_s(fox) - fox_cpu0
        graph.check_alive()
        sent = json.loads(graph.log_tail("source").strip().splitlines()[-1])
        client.close()
    signal_s = sent["blocks"] * BLOCK / FS_HZ
    return {
        "delivered": client.count(),
        "streamed": STREAMS * sent["blocks"] * BLOCK / decimation,
        "signal_s": signal_s,
        "wall_s": sent["elapsed_s"],
        "fox_cpu_s": fox_cpu,
        "source_cpu_s": source_cpu,
    }


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--duration", type=float, default=10.0, help="seconds streamed per configuration"
    )
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    logs = Path(tempfile.mkdtemp(prefix="bench_foxglove_"))
    figures: list[Figure] = []
    for decimation in (1, 10):
        live = run(args.duration, decimation, logs / f"live{decimation}")
        rate, fraction = live["delivered"] / live["wall_s"], live["delivered"] / live["streamed"]
        figures += [
            info(
                f"live view 1/{decimation}: messages/s delivered to a WS client",
                rate,
                "msg/s",
                f"streamed {live['streamed'] / live['wall_s']:,.0f} samples/s to serve",
            ),
            compare(
                f"live view 1/{decimation}: delivered / streamed",
                fraction,
                "fraction",
                ">=",
                0.95,
                f"{live['delivered']:,} of {live['streamed']:,.0f}",
            ),
            info(
                f"live view 1/{decimation}: CPU added per signal second",
                live["fox_cpu_s"] / live["signal_s"],
                "cpu-s/s",
                "the source publishing the 4 streams: "
                f"{live['source_cpu_s'] / live['signal_s']:.2f} cpu-s/s",
            ),
        ]
    print_table(figures)
    if args.json:
        write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
