"""Live view benchmark: does the Foxglove live view keep up with a graph streaming 20 kHz?

The graph: plant (real time) + drive (140 Hz sine, real time) + front end, i.e. four 20 kHz
streams (drive, sensor voltages, ground truth, estimate) in 10-sample blocks. The live view
(foxglove_node) serves every sample (or every Nth) as its own message; a WebSocket client
(flaair_tools.foxglove_client, the `websockets` package) in this process subscribes to every
channel and counts what arrives.

Figures, each beside its same-run baseline:
- messages per second delivered to the client, and that as a fraction of the samples the
  graph streamed (4 x 20,000 / s at decimation 1): the live view keeps up at >= 0.95;
- CPU the live view adds: CPU seconds of the foxglove_node process per second of signal,
  beside the graph's own CPU per second of signal without the live view.

Run: scripts/in_env.sh nice -n 10 python bench/bench_foxglove.py [--duration 10] [--json out/bench_foxglove.json]
"""
from __future__ import annotations

import argparse
import socket
import sys
import tempfile
import time
from pathlib import Path

import psutil

from benchlib import Figure, print_table, write_json  # noqa: E402  (puts src/ packages on the path)
from flaair_common.graph import Graph, node_argv, wait_for  # noqa: E402
from flaair_tools import live_view  # noqa: E402
from flaair_tools.foxglove_client import FoxgloveClient  # noqa: E402

FS_HZ, STREAMS = 20000.0, 4
WARM_UP_S = 5.0


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _cpu_s(processes: list) -> float:
    total = 0.0
    for process in processes:
        times = psutil.Process(process.pid).cpu_times()
        total += times.user + times.system
    return total


def run_graph(duration_s: float, decimation: int | None, logs: Path) -> dict[str, float]:
    """Run the graph (with the live view at `decimation`, or without it: None); measure."""
    with Graph(log_dir=logs) as graph:
        nodes = [graph.start("plant", node_argv("flaair_sim", "plant_node", ["-p", "mode:=realtime", "-p", "publish_clock:=false"])),
                 graph.start("frontend", node_argv("flaair_sensors", "frontend_node"))]
        fox, client, port = None, None, _free_port()
        if decimation is not None:
            fox = graph.start("foxglove", node_argv("flaair_tools", "foxglove_node",
                                                    ["-p", f"port:={port}", "-p", f"sample_decimation:={decimation}"]))

            def connect() -> bool:
                nonlocal client
                try:
                    client = FoxgloveClient(f"ws://127.0.0.1:{port}", open_timeout_s=2.0)
                    return True
                except OSError:
                    graph.check_alive()
                    return False

            if not wait_for(connect, 120.0, 0.5):
                raise SystemExit(f"foxglove_node did not listen on {port}:\n{graph.log_tail('foxglove')}")
            topics = [stream.topic for stream in live_view.STREAMS.values()] + [live_view.WINGBEAT_TOPIC]
            client.wait_for_channels(topics, 30.0)
            client.subscribe(topics)
        nodes.append(graph.start("drive", node_argv("flaair_sim", "drive_node", [
            "-p", "pacing:=realtime", "-p", "frequency_hz:=140.0", "-p", "min_subscribers:=1"])))

        def spin(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                if client is not None:
                    client.receive(0.05)
                else:
                    time.sleep(0.05)
                graph.check_alive()

        spin(WARM_UP_S)
        start_wall, graph_cpu0 = time.monotonic(), _cpu_s(nodes)
        fox_cpu0 = _cpu_s([fox]) if fox else 0.0
        count0 = client.received.count() if client else 0
        signal0 = client.received.times_ns[-1] if client and client.received.times_ns else None
        spin(duration_s)
        wall = time.monotonic() - start_wall
        out = {"wall_s": wall, "graph_cpu_s": _cpu_s(nodes) - graph_cpu0}
        if client is not None:
            out["fox_cpu_s"] = _cpu_s([fox]) - fox_cpu0
            out["messages"] = client.received.count() - count0
            signal1 = client.received.times_ns[-1] if client.received.times_ns else None
            out["signal_s"] = (signal1 - signal0) * 1e-9 if signal0 is not None and signal1 is not None else wall
            client.close()
        else:
            out["signal_s"] = wall  # the real-time plant: signal time follows the wall clock
        return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=10.0, help="measured seconds per configuration")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    logs = Path(tempfile.mkdtemp(prefix="bench_foxglove_"))
    base = run_graph(args.duration, None, logs / "baseline")
    base_cpu = base["graph_cpu_s"] / base["signal_s"]
    figures: list[Figure] = []
    for decimation in (1, 10):
        live = run_graph(args.duration, decimation, logs / f"live{decimation}")
        rate = live["messages"] / live["wall_s"]
        streamed = STREAMS * FS_HZ / decimation * live["signal_s"] / live["wall_s"]
        added = live["fox_cpu_s"] / live["signal_s"]
        figures += [
            Figure(f"live view 1/{decimation}: messages/s delivered to a WS client", rate, "msg/s", "reported", True,
                   f"graph streamed {streamed:,.0f} samples/s to serve"),
            Figure(f"live view 1/{decimation}: delivered / streamed", rate / streamed, "fraction", ">= 0.95",
                   rate / streamed >= 0.95, "1.0 = every served sample arrived"),
            Figure(f"live view 1/{decimation}: CPU added per signal second", added, "cpu-s/s", "reported", True,
                   f"graph without live view {base_cpu:.2f} cpu-s/s (same run); "
                   f"real-time factor {live['signal_s'] / live['wall_s']:.2f}"),
        ]
    print_table(figures)
    if args.json:
        write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
