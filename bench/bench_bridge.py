"""Real-time target bridge against the emulated target: late/missing drive, lost sensor packets, loop latency.

The emulated target (flaair_bridge.emulated_target, 20 kHz in 10-sample packets, real-time
paced) talks UDP on 127.0.0.1 to the bridge node; a drive source in its own process answers
every /flaair/sensor_v block with one /flaair/drive block (a 140 Hz, 50 V sine), as a
controller does. Everything runs on a private ROS domain. Figures, each beside its target:

- drive samples late or missing at the target, % of the driven samples (target <= 0.1 %);
- sensor packets lost inside FLAAIR: sent by the target but not delivered, with data, to the
  drive source over DDS (target 0);
- latency from a sensor packet's arrival at the bridge (kernel timestamp) to the drive packet it
  causes leaving the bridge, p99 (target < 1 ms);
- CPU per packet of the bridge, the drive source and the emulated target.

Same-run baseline: the emulated target against a bare UDP echo (one Python process answering
each sensor packet with a drive packet, no ROS): what the machine allows without FLAAIR.
The composed one-process loop (front end and controller in the bridge's executor) belongs to
`flaair live`; this benchmark measures the bridge's own share.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import REPO_ROOT, Figure, print_table, write_json  # noqa: E402
from flaair_common.graph import Graph  # noqa: E402

FLAAIR = str(REPO_ROOT / "bin" / "flaair")
FS = 20000.0
BLOCK = 10
LEAD = 20


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _tree_cpu_s(pid: int) -> float:
    """CPU of a process and its children (bin/flaair execs, but be safe)."""
    total = _cpu_s(pid)
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        children = []
    return total + sum(_tree_cpu_s(int(child)) for child in children)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


# ------------------------------------------------------------------------------ helper processes
def responder_main(out_file: str) -> int:
    """Drive source: one drive block per sensor block (contiguous stream), counts what arrived."""
    import rclpy
    from rclpy.node import Node

    from flaair_common import cdr, topics
    from flaair_common.qos import BLOCK_STREAM
    from flaair_common.runtime import make_executor
    from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = Node("bench_drive_source")
    sensor_codec = cdr.FixedCodec(cdr.SENSOR_VOLTAGE_BLOCK, BLOCK, topics.FRAME_ID)
    drive_codec = cdr.FixedCodec(cdr.DRIVE_COMMAND_BLOCK, BLOCK)
    publisher = node.create_publisher(DriveCommandBlock, topics.DRIVE, BLOCK_STREAM)
    counts = {"blocks": 0, "nan_blocks": 0, "next_index": 0}

    def on_sensor(data: bytes) -> None:
        message = sensor_codec.decode(data)
        counts["blocks"] += 1
        counts["nan_blocks"] += int(np.isnan(message["stroke_sensor_v"]).any())
        index = counts["next_index"] + np.arange(BLOCK)
        drive = 50.0 * np.sin(2 * np.pi * 140.0 * index / FS)
        publisher.publish(drive_codec.encode(0, {"sample_rate_hz": FS, "first_sample_index": counts["next_index"],
                                                 "drive_v": drive}))
        counts["next_index"] += BLOCK

    node.create_subscription(SensorVoltageBlock, topics.SENSOR_VOLTAGE, on_sensor, BLOCK_STREAM, raw=True)
    executor = make_executor()
    executor.add_node(node)
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    while not stop:
        executor.spin_once(timeout_sec=0.05)
    Path(out_file).write_text(json.dumps(counts))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def echo_main(port: int, out_file: str) -> int:
    """Baseline: a bare UDP echo answering each sensor packet with a drive packet lead samples ahead."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.setsockopt(socket.SOL_SOCKET, 35, 1)   # SO_TIMESTAMPNS
    sock.settimeout(0.2)
    head, reply = struct.Struct("<4sIQfHH"), struct.Struct(f"<4sIQHH{BLOCK}f")
    latency, sequence, last = [], 0, None
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    while not stop:
        try:
            data, ancillary, _, sender = sock.recvmsg(65536, socket.CMSG_SPACE(16))
        except (socket.timeout, InterruptedError):
            continue
        _, _, first, _, n, _ = head.unpack_from(data)
        index = first + n + LEAD + np.arange(BLOCK)
        sock.sendto(reply.pack(b"FLD1", sequence, first + n + LEAD, BLOCK, 0,
                               *(50.0 * np.sin(2 * np.pi * 140.0 * index / FS))), sender)
        sequence += 1
        if ancillary:
            seconds, nanoseconds = struct.unpack("@qq", ancillary[0][2][:16])
            latency.append(time.time() - (seconds + 1e-9 * nanoseconds))
    np.save(out_file, np.array(latency))
    return 0


# ------------------------------------------------------------------------------ runs
def bridge_run(duration_s: float, tmp: Path) -> dict:
    port = _free_port()
    timing = tmp / "timing.npz"
    graph = Graph(log_dir=tmp)   # a private domain; every child stopped on the way out
    env = graph.env

    def start(name: str, *args: str) -> subprocess.Popen:
        return graph.start(name, args, stdout=subprocess.DEVNULL)

    try:
        bridge = start("bridge", FLAAIR, "run", "flaair_bridge", "bridge_node", "--ros-args", "-p", f"listen_port:={port}",
                       "-p", f"lead_samples:={LEAD}", "-p", f"timing_file:={timing}",
                       # the emulator on a shared machine stalls now and then, a real target does not: no false silences
                       "-p", "sensor_timeout_s:=1.0")
        source = start("source", sys.executable, __file__, "--responder", str(tmp / "source.json"))
        for topic in ("/flaair/sensor_v", "/flaair/drive"):
            wait = subprocess.run([FLAAIR, "topic", "wait", topic, "--publishers", "1", "--subscribers", "1",
                                   "--timeout", "120"], env=env, capture_output=True, text=True, cwd=REPO_ROOT)
            if wait.returncode:
                raise RuntimeError(f"{wait.stderr}\n{(tmp / 'bridge.log').read_text()}")
        cpu0 = {"bridge": _tree_cpu_s(bridge.pid), "source": _cpu_s(source.pid)}
        target = start("target", FLAAIR, "run", "flaair_bridge", "emulated_target", "--bridge", f"127.0.0.1:{port}",
                       "--listen", "127.0.0.1:0", "--duration", str(duration_s), "--counters", str(tmp / "target.json"))
        while target.poll() is None:
            cpu_target = _tree_cpu_s(target.pid)
            time.sleep(0.2)
        if target.returncode != 0:
            raise RuntimeError((tmp / "target.log").read_text())
        time.sleep(1.0)  # the bridge and the source drain what is still queued
        cpu1 = {"bridge": _tree_cpu_s(bridge.pid), "source": _cpu_s(source.pid), "target": cpu_target}
    finally:
        graph.close()
    counters = json.loads((tmp / "target.json").read_text())
    n_packets = counters["packets_sent"]
    cpu = {name: 1e6 * (cpu1[name] - cpu0.get(name, 0.0)) / n_packets for name in cpu1}
    summary = [line for line in (tmp / "bridge.log").read_text().splitlines() if "bridge closed" in line]
    return {"target": counters, "source": json.loads((tmp / "source.json").read_text()),
            "events": dict(np.load(timing)), "cpu_us": cpu, "summary": summary[0] if summary else ""}


def echo_run(duration_s: float, tmp: Path) -> dict:
    port = _free_port()
    with Graph() as graph:
        graph.start("echo", [sys.executable, __file__, "--echo", str(port), str(tmp / "echo.npy")])
        time.sleep(3.0)  # the echo imports numpy and binds
        target = graph.start("target", [FLAAIR, "run", "flaair_bridge", "emulated_target", "--bridge", f"127.0.0.1:{port}",
                                        "--listen", "127.0.0.1:0", "--duration", str(duration_s),
                                        "--counters", str(tmp / "echo_target.json")])
        target.wait(timeout=duration_s * 4 + 120)
    return {"target": json.loads((tmp / "echo_target.json").read_text()), "latency_s": np.load(tmp / "echo.npy")}


def sensor_to_drive_ms(events: dict) -> np.ndarray:
    """Arrival of the k-th sensor packet at the bridge -> the drive packet sent for the source's k-th block.

    The drive source answers every sensor block with the next block of its stream (source index
    10 k answers the k-th block), so the pairing is by position; blocks that were queued (no
    packet sent at once) are left out.
    """
    sensor, drive = events["sensor"], events["drive"]
    k = (drive[:, 0] // BLOCK).astype(int)
    ok = (k < len(sensor)) & np.isfinite(drive[:, 2])
    arrival = np.full(int(sensor[:, 0].max(initial=0)) + 1, np.nan)
    arrival[sensor[:, 0].astype(int)] = sensor[:, 1]
    k, send = k[ok] + 1, drive[ok, 2]        # counters.sensor_packets is 1 after the first packet
    ok = k < len(arrival)
    return 1e3 * (send[ok] - arrival[k[ok]])


def percentile(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q)) if values.size else float("nan")


def late_or_missing_pct(counters: dict) -> float:
    driven = counters["fresh_samples"] + counters["missing_samples"]
    return 100.0 * counters["missing_samples"] / driven if driven else 100.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=60.0, help="signal time of the bridge run [s]")
    parser.add_argument("--baseline-duration", type=float, default=20.0, help="signal time of the UDP-echo baseline [s]")
    parser.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench_bridge.json")
    parser.add_argument("--responder", help=argparse.SUPPRESS)
    parser.add_argument("--echo", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.responder:
        return responder_main(args.responder)
    if args.echo:
        return echo_main(int(args.echo[0]), args.echo[1])
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        load0 = os.getloadavg()[0]
        echo = echo_run(args.baseline_duration, tmp)
        run = bridge_run(args.duration, tmp)
        load1 = os.getloadavg()[0]
    load = f"load avg {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores"
    t, e = run["target"], echo["target"]
    figures = []
    pct, pct_echo = late_or_missing_pct(t), late_or_missing_pct(e)
    figures.append(Figure(f"drive samples late or missing at the target, {args.duration:g} s", pct, "%", "<= 0.1",
                          pct <= 0.1, f"UDP echo {pct_echo:.3f} %; late {t['late_samples']}, missing {t['missing_samples']} "
                                      f"of {t['fresh_samples'] + t['missing_samples']}; {load}"))
    lost = t["packets_sent"] - (run["source"]["blocks"] - run["source"]["nan_blocks"])
    figures.append(Figure("sensor packets lost inside FLAAIR", lost, "packets", "0", lost == 0,
                          f"of {t['packets_sent']} sent; {run['source']['nan_blocks']} blocks marked lost by the bridge"))
    latency = sensor_to_drive_ms(run["events"])
    echo_ms = echo["latency_s"] * 1e3
    p99 = percentile(latency, 99)
    figures.append(Figure("sensor arrival -> drive packet, p99", p99, "ms", "< 1", p99 < 1.0,
                          f"p50 {percentile(latency, 50):.3f} ms over {latency.size} packets; UDP echo p99 "
                          f"{percentile(echo_ms, 99):.3f} ms, p50 {percentile(echo_ms, 50):.3f} ms"))
    for name, label in (("bridge", "bridge node"), ("source", "drive source (DDS, no work)"), ("target", "emulated target")):
        figures.append(Figure(f"CPU per 0.5 ms packet: {label}", run["cpu_us"][name], "us", "", True,
                              "whole process incl. rclpy/DDS" if name != "target" else "plant + UDP + pacing"))
    figures.append(Figure("emulated target overruns (its own deadline missed)", t["overruns"], "packets", "", True,
                          f"max lag {t['max_lag_ms']:.1f} ms; UDP echo run {e['overruns']}"))
    print_table(figures)
    print(run["summary"].split("]: ", 1)[-1])
    write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
