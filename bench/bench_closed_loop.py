"""Closed-loop benchmark: plant (lockstep) -> front end -> dSA controller -> plant over DDS.

Run: scripts/in_env.sh python bench/bench_closed_loop.py
[--duration 2.0] [--json out/bench_closed_loop.json]

20 kHz data in 10-sample (0.5 ms) blocks; three node processes on a private ROS_DOMAIN_ID
(outside the 1..101 range tests use), localhost discovery, nothing else subscribed.

Figures:
* real-time factor = signal time / wall time over the run (first 10 % dropped: start-up),
  from the controller's own per-block timing (timing_file: monotonic receive and publish
  time of every block), as shipped (EventsExecutor, block streams as CDR bytes) with 1 block
  in flight (the loop as specified: one command block per wing-state block, loop delay one
  block), 2 and 4 (pipelined: plant, front end and controller can work on different blocks at
  once; the controller compensates the extra delay); baseline: the same loop with
  FLAAIR_EXECUTOR=single (rclpy's SingleThreadedExecutor), 1 block in flight;
* per-hop latency p50/p99, in a separate run with a probe process that stamps the arrival of
  every /flaair/sensor_v and /flaair/wing_state block (CLOCK_MONOTONIC is shared by the
  processes; blocks are matched by first_sample_index):
    controller -> plant -> sensor_v   drive publish (controller) .. sensor block at the probe
    front end                         sensor block at the probe .. wing-state block at the probe
    wing_state -> controller          wing-state block at the probe .. controller callback start
    controller                        callback start .. drive publish
  (the probe adds a subscriber to two streams, so this run is a little slower);
* CPU time per block of each node process (utime + stime from /proc, whole run / blocks):
  with one block in flight the three run one after another, so 0.5 ms / (sum of the three)
  bounds the real-time factor on an idle machine; pipelined, with 2 cores, 1 ms / sum.
* the rclpy floor: a ping-pong of a 10-sample block between two processes with no work in the
  callbacks, with the spin loop of flaair_common.runtime.run_node (SingleThreadedExecutor.spin_once)
  and with rclpy's C++ EventsExecutor;
* the composed loop (`flaair_common container` with the three nodes, block streams in-process,
  lockstep, 1 block in flight, --composed-duration of signal, default 4 s): its real-time factor
  (target >= 5, `COMPOSED_RTF_TARGET`) beside the separate-process loop of the same run, its
  whole process's CPU per block (target <= 0.5 ms / 5), and, from a second run with
  FLAAIR_PROFILE=1 (its timers cost CPU too), the CPU per block of each node's callback
  (core, shell and publishes; the container prints them at exit) and of the rest of the
  process (executor, DDS threads);
  --composed-only runs just these and the separate-process loop with 1 block in flight.
The machine's load average is reported beside them: other jobs share the 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import REPO_ROOT, Figure, compare, info, print_table, write_json
from flaair_common.graph import Graph

FS = 20000.0
BLOCK = 10
BLOCK_S = BLOCK / FS
# The composed loop's real-time factor a lab needs on a 2-core laptop (issue "Fast on a two-core
# machine"): room for the monitors and the recorder beside the loop.
COMPOSED_RTF_TARGET = 5.0
FLAAIR = str(REPO_ROOT / "bin" / "flaair")


def _cpu_s(pid: int) -> float:
    """Utime + stime of a process (s)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


NODES = {
    "plant": ("flaair_sim", "plant_node"),
    "frontend": ("flaair_sensors", "frontend_node"),
    "controller": ("flaair_control", "dsa_controller_node"),
}


def _node_cmd(name: str) -> list[str]:
    package, executable = NODES[name]
    return [FLAAIR, "run", package, executable]


def run_loop(
    duration_s: float,
    in_flight: int,
    domain: int,
    probe_file: Path | None,
    tmp: Path,
    executor: str = "events",
) -> dict:
    """One closed-loop run (executor: FLAAIR_EXECUTOR of the
    nodes); timing arrays and CPU per block per node.
    """
    timing_file = tmp / f"timing_{domain}.npz"
    log_dir = tmp / f"run{domain}"
    procs: dict[str, subprocess.Popen] = {}
    with Graph(log_dir=log_dir) as graph:  # a private domain; every node stopped on the way out
        graph.env["FLAAIR_EXECUTOR"] = executor

        def start(name: str, *args: str) -> None:
            procs[name] = graph.start(name, args)

        if probe_file is not None:
            start("probe", sys.executable, __file__, "--probe", str(probe_file))
        start(
            "plant",
            *_node_cmd("plant"),
            "--ros-args",
            "-p",
            "mode:=lockstep",
            "-p",
            "min_sensor_subscribers:=1",  # the front end matched before block 0 is stepped
        )
        start("frontend", *_node_cmd("frontend"))
        start(
            "controller",
            *_node_cmd("controller"),
            "--ros-args",
            "-p",
            f"run_time_s:={duration_s}",
            "-p",
            f"timing_file:={timing_file}",
            "-p",
            f"blocks_in_flight:={in_flight}",
            "-p",
            "watchdog_timeout_s:=30.0",
        )
        cpu0, cpu1 = _wait_for_run(
            log_dir / "controller.log",
            {n: p for n, p in procs.items() if n != "probe"},
            procs["controller"],
        )
    return _run_result(timing_file, log_dir / "controller.log", cpu0, cpu1)


def _wait_for_run(
    log_path: Path, procs: dict[str, subprocess.Popen], controller: subprocess.Popen
) -> tuple[dict[str, float], dict[str, float]]:
    """Wait for the controller's "run complete"; CPU (s)
    of each process at "loop closed" and at the end.
    """
    cpu0: dict[str, float] = {}
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        text = log_path.read_text() if log_path.exists() else ""
        if not cpu0 and "loop closed" in text:
            cpu0 = {n: _cpu_s(p.pid) for n, p in procs.items()}
        if "run complete" in text:
            return cpu0, {n: _cpu_s(p.pid) for n, p in procs.items()}
        if controller.poll() is not None:
            raise RuntimeError(f"controller exited:\n{text}")
        time.sleep(0.02)
    raise RuntimeError("closed loop did not complete within 600 s")


def _run_result(
    timing_file: Path, log_path: Path, cpu0: dict[str, float], cpu1: dict[str, float]
) -> dict:
    timing = np.load(timing_file)["timing"]
    n_blocks = timing.shape[0]
    summary = [line for line in log_path.read_text().splitlines() if "run complete" in line]
    return {
        "timing": timing,
        "cpu_per_block_us": {n: 1e6 * (cpu1[n] - cpu0.get(n, cpu1[n])) / n_blocks for n in cpu1},
        "summary": summary[0] if summary else "",
    }


COMPOSED = [
    "flaair_sim.plant_node:PlantNode",
    "flaair_sensors.frontend_node:FrontendNode",
    "flaair_control.dsa_controller_node:DsaControllerNode",
]
PROFILE_LINE = re.compile(
    r"profile: (\w+)\.(\w+): (\d+) calls, ([\d.]+) us CPU, ([\d.]+) us wall per call"
)


def run_composed(duration_s: float, tmp: Path, profile: bool) -> dict:
    """The same loop composed in one process (flaair_common container, block streams in-process).

    profile: FLAAIR_PROFILE=1, the container prints each node callback's CPU and wall time per
    call at exit (`flaair_common.intra.CallbackProfile`): `node_cpu_us` / `node_wall_us`.
    """
    tag = "profiled" if profile else "plain"
    timing_file, log_dir, params_file = (
        tmp / f"timing_composed_{tag}.npz",
        tmp / f"composed_{tag}",
        tmp / f"{tag}.yaml",
    )
    params_file.write_text(
        json.dumps(
            {  # YAML: one section per node name
                "plant_node": {"ros__parameters": {"mode": "lockstep"}},
                "dsa_controller_node": {
                    "ros__parameters": {
                        "run_time_s": duration_s,
                        "timing_file": str(timing_file),
                        "blocks_in_flight": 1,
                        "watchdog_timeout_s": 30.0,
                    }
                },
            }
        )
    )
    with Graph(log_dir=log_dir) as graph:
        if profile:
            graph.env["FLAAIR_PROFILE"] = "1"
        process = graph.start(
            "controller",
            [
                FLAAIR,
                "run",
                "flaair_common",
                "container",
                *COMPOSED,
                "--ros-args",
                "--params-file",
                str(params_file),
            ],
        )
        cpu0, cpu1 = _wait_for_run(log_dir / "controller.log", {"container": process}, process)
        graph.stop(process)  # SIGINT: the nodes close, the container prints its profile
    result = _run_result(timing_file, log_dir / "controller.log", cpu0, cpu1)
    lines = PROFILE_LINE.findall((log_dir / "controller.log").read_text())
    result["node_cpu_us"] = {node: float(cpu) for node, _, _, cpu, _ in lines}
    result["node_wall_us"] = {node: float(wall) for node, _, _, _, wall in lines}
    if profile and len(lines) != len(COMPOSED):
        raise RuntimeError(
            f"container printed {len(lines)} profile lines, expected {len(COMPOSED)}"
        )
    return result


def rtf(timing: np.ndarray) -> float:
    """Signal time / wall time over the run after the first 10 % of blocks."""
    k = timing.shape[0] // 10
    idx, rx = timing[k:, 0], timing[k:, 1]
    return float((idx[-1] - idx[0]) / FS / (rx[-1] - rx[0]))


def pct(x: np.ndarray) -> tuple[float, float]:
    return float(np.percentile(x, 50)), float(np.percentile(x, 99))


def hops(timing: np.ndarray, probe: dict, in_flight: int) -> dict[str, np.ndarray]:
    """Per-hop latencies (s), matched by sample index."""
    drive_index, ctrl_rx, ctrl_tx = timing[:, 0].astype(np.int64), timing[:, 1], timing[:, 2]
    tx_of = dict(zip(drive_index.tolist(), ctrl_tx.tolist(), strict=True))
    # wing state i -> drive i + W N
    rx_of_ws = dict(zip((drive_index - in_flight * BLOCK).tolist(), ctrl_rx.tolist(), strict=True))
    sensor = dict(zip(probe["sensor_index"].tolist(), probe["sensor_t"].tolist(), strict=True))
    ws = dict(zip(probe["ws_index"].tolist(), probe["ws_t"].tolist(), strict=True))
    out: dict[str, list[float]] = {
        "plant": [],
        "frontend": [],
        "to_controller": [],
        "controller": [],
        "loop": [],
    }
    for i, t_tx in tx_of.items():
        if i in sensor:
            out["plant"].append(sensor[i] - t_tx)
        if i in sensor and i in ws:
            out["frontend"].append(ws[i] - sensor[i])
        if i in ws and i in rx_of_ws:
            out["to_controller"].append(rx_of_ws[i] - ws[i])
        if i in rx_of_ws:
            out["loop"].append(rx_of_ws[i] - t_tx)
    out["controller"] = list(ctrl_tx - ctrl_rx)
    k = 0.1
    return {name: np.asarray(v[int(k * len(v)) :]) for name, v in out.items()}


def probe_main(out_file: str) -> int:
    """Subscriber that stamps the arrival of every sensor and wing-state block (monotonic)."""
    import rclpy

    from flaair_common.qos import BLOCK_STREAM
    from flaair_msgs.msg import SensorVoltageBlock, WingStateBlock

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("bench_probe")
    sensor: list[tuple[int, float]] = []
    ws: list[tuple[int, float]] = []
    node.create_subscription(
        SensorVoltageBlock,
        "/flaair/sensor_v",
        lambda m: sensor.append((m.first_sample_index, time.monotonic())),
        BLOCK_STREAM,
    )
    node.create_subscription(
        WingStateBlock,
        "/flaair/wing_state",
        lambda m: ws.append((m.first_sample_index, time.monotonic())),
        BLOCK_STREAM,
    )
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    while not stop:
        rclpy.spin_once(node, timeout_sec=0.05)
    s = np.array(sensor or [(0, 0.0)])
    w = np.array(ws or [(0, 0.0)])
    np.savez(
        out_file,
        sensor_index=s[:, 0].astype(np.int64),
        sensor_t=s[:, 1],
        ws_index=w[:, 0].astype(np.int64),
        ws_t=w[:, 1],
    )
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def pingpong(role: str, executor: str, n: int) -> int:
    """Rclpy floor: two processes bounce a 10-sample
    DriveCommandBlock; the spin loop of run_node.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from flaair_common.blocks import from_array
    from flaair_common.qos import BLOCK_STREAM
    from flaair_msgs.msg import DriveCommandBlock

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node(f"bench_pingpong_{role}")
    out_topic, in_topic = (
        ("/bench/ping", "/bench/pong") if role == "a" else ("/bench/pong", "/bench/ping")
    )
    pub = node.create_publisher(DriveCommandBlock, out_topic, BLOCK_STREAM)
    msg = DriveCommandBlock(sample_rate_hz=FS)
    msg.drive_v = from_array(np.zeros(BLOCK))
    st = {"count": 0, "t0": 0.0, "c0": 0.0}

    def on_message(m: DriveCommandBlock) -> None:
        st["count"] += 1
        if st["count"] == 100:
            st["t0"], st["c0"] = time.monotonic(), time.process_time()
        msg.first_sample_index = m.first_sample_index + 1
        pub.publish(msg)

    node.create_subscription(DriveCommandBlock, in_topic, on_message, BLOCK_STREAM)
    if executor == "events":
        from rclpy.experimental import EventsExecutor

        ex = EventsExecutor()
    else:
        ex = SingleThreadedExecutor()
    ex.add_node(node)
    if role == "a":
        while pub.get_subscription_count() == 0 or node.count_publishers(in_topic) == 0:
            ex.spin_once(timeout_sec=0.05)
        time.sleep(1.0)
        pub.publish(msg)
    deadline = time.monotonic() + 120
    while st["count"] < n and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)
    if role == "a":
        k = st["count"] - 100
        print(
            json.dumps(
                {
                    "wall_us": 1e6 * (time.monotonic() - st["t0"]) / k,
                    "cpu_us": 1e6 * (time.process_time() - st["c0"]) / k,
                }
            )
        )
    return 0


def run_pingpong(executor: str, domain: int, n: int = 3000) -> dict:
    with Graph() as graph:
        graph.start("pong", [sys.executable, __file__, "--pingpong", "b", executor, str(n + 100)])
        a = subprocess.run(
            [sys.executable, __file__, "--pingpong", "a", executor, str(n)],
            env=graph.env,
            capture_output=True,
            text=True,
            timeout=180,
        )
    return json.loads(a.stdout.strip().splitlines()[-1])


def composed_figures(composed: dict, profiled: dict, separate: dict, load: str) -> list[Figure]:
    """The composed loop's RTF beside the separate-process
    loop of the same run, and its CPU per block by part.
    """
    r_composed, r_separate = rtf(composed["timing"]), rtf(separate["timing"])
    figures = [
        compare(
            "composed loop RTF (lockstep, 1 process)",
            r_composed,
            "x",
            ">=",
            COMPOSED_RTF_TARGET,
            f"separate processes {r_separate:.3f} x ({r_composed / r_separate:.2f}x); {load}",
        )
    ]
    # the whole process's CPU from the plain run: the profiled one pays for its own timers
    total, profiled_total = (
        composed["cpu_per_block_us"]["container"],
        profiled["cpu_per_block_us"]["container"],
    )
    nodes = profiled["node_cpu_us"]
    for node in ("plant_node", "frontend_node", "dsa_controller_node"):
        figures.append(
            info(
                f"composed CPU per block: {node}",
                nodes[node],
                "us",
                f"wall {profiled['node_wall_us'][node]:.0f} us; its callback: core + "
                "shell + publishes",
            )
        )
    figures.append(
        info(
            "composed CPU per block: rest (executor, DDS threads)",
            profiled_total - sum(nodes.values()),
            "us",
            "the profiled run's process CPU minus the three callbacks",
        )
    )
    figures.append(
        compare(
            "composed CPU per block: whole process",
            total,
            "us",
            "<=",
            BLOCK_S * 1e6 / COMPOSED_RTF_TARGET,
            f"the 0.5 ms block / {COMPOSED_RTF_TARGET:g}: {COMPOSED_RTF_TARGET:g}x real time; "
            "separate processes: "
            f"{sum(separate['cpu_per_block_us'].values()):.0f} us "
            f"summed; the profiled run {profiled_total:.1f} us, RTF {rtf(profiled['timing']):.3f} "
            "x",
        )
    )
    return figures


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=2.0, help="signal time per run [s]")
    parser.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench_closed_loop.json")
    parser.add_argument(
        "--composed-duration", type=float, default=4.0, help="signal time of the composed runs [s]"
    )
    parser.add_argument(
        "--composed-only",
        action="store_true",
        help="only the composed loop and its baseline, the separate-process loop (1 in flight)",
    )
    parser.add_argument("--probe", help=argparse.SUPPRESS)
    parser.add_argument("--pingpong", nargs=3, help=argparse.SUPPRESS)
    args, rest = parser.parse_known_args()
    if args.probe:
        return probe_main(args.probe)
    if args.pingpong:
        return pingpong(args.pingpong[0], args.pingpong[1], int(args.pingpong[2]))
    if rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    base = 160 + os.getpid() % 60
    figures: list[Figure] = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        load0 = os.getloadavg()[0]
        ping = {
            kind: run_pingpong(kind, base + 3 + i) for i, kind in enumerate(("single", "events"))
        }
        composed = run_composed(args.composed_duration, tmp, profile=False)
        profiled = run_composed(args.composed_duration, tmp, profile=True)
        if args.composed_only:
            runs = {1: run_loop(args.duration, 1, base + 5, None, tmp)}
            load1 = os.getloadavg()[0]
            figures = composed_figures(
                composed, profiled, runs[1], f"load avg {load0:.1f} -> {load1:.1f}"
            )
            print_table(figures)
            write_json(figures, args.json)
            return 0
        single = run_loop(args.duration, 1, base, None, tmp, executor="single")
        runs = {k: run_loop(args.duration, k, base + 4 + k, None, tmp) for k in (1, 2, 4)}
        probe_file = tmp / "probe.npz"
        probed = run_loop(args.duration, 1, base + 2, probe_file, tmp)
        load1 = os.getloadavg()[0]
        probe = dict(np.load(probe_file))
    load = f"load avg {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores"
    r_single = rtf(single["timing"])
    r = {k: rtf(run["timing"]) for k, run in runs.items()}
    figures.append(
        compare(
            "closed loop real-time factor, 1 block in flight",
            r[1],
            "x",
            ">=",
            1.0,
            f"SingleThreadedExecutor {r_single:.3f} x ({r[1] / r_single:.2f}x); {load}",
        )
    )
    for k in (2, 4):
        figures.append(
            compare(
                f"closed loop real-time factor, {k} blocks in flight",
                r[k],
                "x",
                ">=",
                1.0,
                f"pipelined; {r[k] / r[1]:.2f}x the 1-block loop",
            )
        )
    cpu = runs[1]["cpu_per_block_us"]
    cpu_sum = sum(cpu.values())
    for name in ("plant", "frontend", "controller"):
        figures.append(
            info(
                f"CPU per block: {name} process",
                cpu[name],
                "us",
                f"SingleThreadedExecutor {single['cpu_per_block_us'][name]:.0f} us; "
                "whole process incl. rclpy/DDS",
            )
        )
    for kind, label in (
        ("single", "SingleThreadedExecutor.spin_once"),
        ("events", "EventsExecutor"),
    ):
        figures.append(
            info(
                f"rclpy ping-pong, {label}: CPU per message",
                ping[kind]["cpu_us"],
                "us",
                f"round trip {ping[kind]['wall_us']:.0f} us wall; no work in the callback",
            )
        )
    bound1 = 500.0 / cpu_sum
    figures.append(
        compare(
            "RTF bound from CPU, 1 in flight (0.5 ms / sum)",
            bound1,
            "x",
            ">=",
            1.0,
            f"sum {cpu_sum:.0f} us per block",
        )
    )
    figures.append(
        compare(
            "RTF bound from CPU, pipelined on 2 cores",
            2 * bound1,
            "x",
            ">=",
            1.0,
        )
    )
    t = runs[1]["timing"]
    k = t.shape[0] // 10
    loop_out = (t[k + 1 :, 1] - t[k:-1, 2]) * 1e6  # publish of block j -> wing state answering it
    ctrl = (t[k:, 2] - t[k:, 1]) * 1e6
    p50, p99 = pct(loop_out)
    figures.append(
        compare(
            "loop outside the controller p50 (drive pub -> wing state)",
            p50,
            "us",
            "<",
            500.0,
            f"p99 {p99:.0f} us",
        )
    )
    p50, p99 = pct(ctrl)
    figures.append(info("controller callback -> drive publish p50", p50, "us", f"p99 {p99:.0f} us"))
    h = hops(probed["timing"], probe, 1)
    for name, label in (
        ("plant", "hop controller -> plant -> sensor_v"),
        ("frontend", "hop sensor_v -> front end -> wing_state"),
        # two subscribers of one topic, not a hop: negative when the controller is served first
        ("to_controller", "wing_state received, controller minus probe"),
        ("controller", "hop controller callback -> drive"),
        ("loop", "whole loop drive -> wing state at controller"),
    ):
        if h[name].size:
            p50, p99 = pct(h[name] * 1e6)
            figures.append(
                info(
                    f"{label} p50 (probe run)",
                    p50,
                    "us",
                    f"p99 {p99:.0f} us, n={h[name].size}",
                )
            )
    figures.append(
        info(
            "real-time factor of the probe run",
            rtf(probed["timing"]),
            "x",
            "probe subscribed to 2 streams",
        )
    )
    figures += composed_figures(composed, profiled, runs[1], load)
    print_table(figures)
    for run, name in (
        (runs[1], "1 in flight"),
        (runs[2], "2 in flight"),
        (runs[4], "4 in flight"),
        (single, "SingleThreadedExecutor, 1 in flight"),
        (probed, "probe"),
        (composed, "composed"),
        (profiled, "composed, FLAAIR_PROFILE=1"),
    ):
        print(f"{name}: {run['summary'].split(']: ', 1)[-1]}")
    write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
