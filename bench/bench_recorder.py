"""Recorder benchmark: messages/s and samples/s into the bag, loss, with the whole graph at 20 kHz.

Run: scripts/in_env.sh python bench/bench_recorder.py
[--duration 10] [--json out/bench_recorder.json]

Scenario "graph": plant_node (mode realtime) + drive_node (pacing realtime), 20 kHz in 10-sample
blocks (config/flaair.yaml): /flaair/drive, /flaair/sensor_v, /flaair/wing_state/truth at
2000 msg/s each, and /clock (one per plant block). The recorder (`bin/flaair record --clock`)
starts first; the publishers are stopped (SIGINT) before the recorder, so everything published
has had time to arrive.
Published counts: the nodes do not report counts, so for each block topic the count published
while the recorder was subscribed is taken from the stream's own sample index: blocks from the
first recorded first_sample_index to the last one. Any block lost in between is a gap in that
index (reported as loss); blocks before the recorder's subscription matched ("before
subscription") are outside that window. /clock carries sim time = samples / rate, one per
plant block; its loss is counted the same way from its time values.

Scenario "steady": one publisher process sends the same three block types and /clock at
exactly 2000 msg/s each (wall-clock paced) and reports how many it published: exact counts,
and the recorder's share of the loss separated from the graph's (a starved realtime plant or
drive catches up in bursts).

Baseline (same run): BagWriter alone writing the recorded serialized blocks (no DDS, no callbacks).
Throughput is counted over the window in which all four streams were flowing, and reported.
Targets: no block or /clock message lost or duplicated (a scenario that measured nothing fails),
the recorder under one core; the player's 2 s bag played at --rate 2 ends no earlier than its
schedule's span and less than 20 ms after it.

Reading the graph scenario: on a loaded machine the realtime plant and drive
fall behind and catch up in bursts; the plant then rejects gapped command blocks
from /flaair/drive too (its log says so), i.e. the loss is not the recorder's
alone. /clock is published CLOCK_DEPTH (1000) deep, as plant_node does.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import REPO_ROOT, Figure, best_time_s, compare, info, print_table, write_json
from flaair_common.graph import Graph as LaunchGraph
from flaair_model.config import node_parameters
from flaair_tools import bagio

FLAAIR = str(REPO_ROOT / "bin" / "flaair")
BLOCK_TOPICS = ("/flaair/drive", "/flaair/sensor_v", "/flaair/wing_state/truth")
from flaair_sim.plant_io import CLOCK_DEPTH

# Steady publisher: blocks like the graph's at `rate`
# msg/s per topic for `duration_s`; prints counts.
STEADY_PUBLISHER = r"""
import json, sys, time
import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from rosgraph_msgs.msg import Clock
from flaair_common.blocks import from_array
from flaair_common.qos import BLOCK_STREAM
from flaair_msgs.msg import DriveCommandBlock, SensorVoltageBlock, WingStateBlock
cfg = json.loads(sys.argv[1])
n, fs = cfg["block_size"], cfg["sample_rate_hz"]
rclpy.init()
node = rclpy.create_node("steady_publisher")
drive = node.create_publisher(DriveCommandBlock, "/flaair/drive", BLOCK_STREAM)
sensor = node.create_publisher(SensorVoltageBlock, "/flaair/sensor_v", BLOCK_STREAM)
truth = node.create_publisher(WingStateBlock, "/flaair/wing_state/truth", BLOCK_STREAM)
clock = node.create_publisher(Clock, "/clock", cfg["clock_depth"])
publishers = (drive, sensor, truth, clock)
deadline = time.monotonic() + 60.0
while time.monotonic() < deadline and any(p.get_subscription_count() == 0 for p in publishers):
    time.sleep(0.05)
rng = np.random.default_rng(0)
blocks = int(cfg["duration_s"] * fs / n)
start = time.monotonic()
for i in range(blocks):
    delay = start + i * n / fs - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    sec, nanosec = divmod(round(i * n / fs * 1e9), 1_000_000_000)
    d = DriveCommandBlock(sample_rate_hz=fs, first_sample_index=i * n)
    d.header.stamp = Time(sec=sec, nanosec=nanosec)
    d.drive_v = from_array(rng.normal(0, 50, n))
    s = SensorVoltageBlock(sample_rate_hz=fs, first_sample_index=i * n)
    s.header = d.header
    s.stroke_sensor_v = from_array(rng.normal(1.25, 0.3, n))
    s.pitch_sensor_v = from_array(rng.normal(1.25, 0.3, n))
    w = WingStateBlock(sample_rate_hz=fs, first_sample_index=i * n, source=1)
    w.header = d.header
    w.stroke_deg = from_array(rng.normal(0, 30, n))
    w.pitch_deg = from_array(rng.normal(0, 30, n))
    w.stroke_velocity_deg_s = from_array(np.full(n, np.nan))
    w.stroke_valid = [True] * n
    w.pitch_valid = [True] * n
    drive.publish(d); sensor.publish(s); truth.publish(w)
    sec, nanosec = divmod(round((i + 1) * n / fs * 1e9), 1_000_000_000)
    clock.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
elapsed = time.monotonic() - start
time.sleep(1.0)
print(json.dumps({"blocks": blocks, "elapsed_s": elapsed}), flush=True)
"""


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Graph(LaunchGraph):
    """The project's graph launcher, logs next to the bag, with log-based readiness."""

    def __init__(self, logs: Path) -> None:
        super().__init__(log_dir=logs)
        self.logs = logs

    def start(self, name: str, *args: str) -> subprocess.Popen:  # type: ignore[override]
        return super().start(name, args)

    def log(self, name: str) -> str:
        return (self.logs / f"{name}.log").read_text()

    def wait_log(self, name: str, text: str, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while text not in self.log(name):
            if time.monotonic() > deadline:
                raise SystemExit(
                    f"{name}: no '{text}' within {timeout_s:g} s; see {self.logs / (name + '.log')}"
                )
            time.sleep(0.1)


def record_scenario(
    bag: Path, scenario: str, duration_s: float, block_size: int, rate_hz: float
) -> dict[str, object]:
    """Record one scenario ("graph" or "steady") into `bag`;
    returns recorder CPU and what publishers reported.
    """
    graph = Graph(bag.parent)
    try:
        recorder = graph.start("recorder", FLAAIR, "record", "-o", str(bag), "--clock")
        graph.wait_log("recorder", "recording", 60.0)
        crashed: dict[str, int] = {}
        if scenario == "graph":
            plant = graph.start(
                "plant",
                FLAAIR,
                "run",
                "flaair_sim",
                "plant_node",
                "--ros-args",
                "-p",
                "mode:=realtime",
            )
            # numba compiles the plant kernel on a cold cache
            graph.wait_log("plant", "plant ready", 300.0)
            drive = graph.start(
                "drive",
                FLAAIR,
                "run",
                "flaair_sim",
                "drive_node",
                "--ros-args",
                "-p",
                "pacing:=realtime",
            )
            graph.wait_log("drive", "drive:", 60.0)
            cpu_start_s, wall_start_s = _cpu_s(recorder.pid), time.monotonic()
            time.sleep(duration_s)
            cpu_s, wall_s = _cpu_s(recorder.pid) - cpu_start_s, time.monotonic() - wall_start_s
            crashed = {
                name: p.returncode
                for name, p in (("plant", plant), ("drive", drive))
                if p.poll() is not None
            }
            graph.stop(drive, timeout_s=20.0)
            graph.stop(plant, timeout_s=20.0)
            reported = None
        else:
            config = {
                "duration_s": duration_s,
                "block_size": block_size,
                "sample_rate_hz": rate_hz,
                "clock_depth": CLOCK_DEPTH,
            }
            cpu_start_s, wall_start_s = _cpu_s(recorder.pid), time.monotonic()
            publisher = graph.start(
                "steady", sys.executable, "-c", STEADY_PUBLISHER, json.dumps(config)
            )
            if publisher.wait(timeout=duration_s + 120.0) != 0:
                raise SystemExit(f"steady publisher failed; see {bag.parent / 'steady.log'}")
            cpu_s, wall_s = _cpu_s(recorder.pid) - cpu_start_s, time.monotonic() - wall_start_s
            reported = json.loads(graph.log("steady").strip().splitlines()[-1])
        time.sleep(1.0)
        code = graph.stop(recorder, timeout_s=20.0)
        if code != 0:
            raise SystemExit(f"recorder exited with {code}; see {bag.parent / 'recorder.log'}")
        return {"recorder_cores": cpu_s / wall_s, "crashed": crashed, "reported": reported}
    finally:
        graph.close()


def _stream_stats(indices: np.ndarray, step: int, samples: int) -> dict[str, float]:
    """Counts of one stream from its block indices:
    recorded, published in the window, lost, duplicated.
    """
    if indices.size == 0:
        return {
            "recorded": 0.0,
            "published": 0.0,
            "lost": 0.0,
            "duplicates": 0.0,
            "samples": 0.0,
            "first_index": 0.0,
        }
    published = int((indices.max() - indices.min()) // step + 1)
    unique = np.unique(indices).size
    return {
        "recorded": float(indices.size),
        "published": float(published),
        "lost": float(published - unique),
        "duplicates": float(indices.size - unique),
        "samples": float(samples),
        "first_index": float(indices.min()),
    }


def analyse(bag: Path, block_size: int, rate_hz: float) -> dict[str, dict[str, float]]:
    """Per topic: recorded count, count published in the
    window, lost, duplicated, first index; and the span.
    """
    out: dict[str, dict[str, float]] = {}
    counts = bagio.message_counts(bag)
    for topic in BLOCK_TOPICS:
        if counts.get(topic):
            blocks = bagio.read_blocks(bag, topic, allow_gaps=True)
            out[topic] = _stream_stats(blocks.block_first_index, block_size, blocks.n_samples)
        else:
            out[topic] = _stream_stats(np.zeros(0, dtype=np.int64), block_size, 0)
    clock_ns = np.array(
        [
            m.clock.sec * 1_000_000_000 + m.clock.nanosec
            for _, _, m in bagio.iter_messages(bag, ["/clock"])
        ]
        if counts.get("/clock")
        else [],
        dtype=np.int64,
    )
    out["/clock"] = _stream_stats(
        np.round(clock_ns * rate_hz / 1e9).astype(np.int64), block_size, 0
    )
    # Throughput window: while every stream was flowing (first to last receive time common to all).
    received: dict[str, list[int]] = {}
    for topic, _, t, _ in bagio.iter_raw(bag):
        received.setdefault(topic, []).append(t)
    streams = [
        np.asarray(received.get(topic, []), dtype=np.int64) for topic in (*BLOCK_TOPICS, "/clock")
    ]
    if all(r.size > 1 for r in streams):
        start, stop = max(int(r.min()) for r in streams), min(int(r.max()) for r in streams)
    else:
        start = stop = 0
    in_window = {
        topic: int(((r >= start) & (r <= stop)).sum())
        for topic, r in zip((*BLOCK_TOPICS, "/clock"), streams, strict=True)
    }
    window_s = max(stop - start, 1) * 1e-9
    out["_span"] = {
        "span_s": window_s,
        "messages": float(sum(in_window.values())),
        "samples": float(sum(in_window[t] for t in BLOCK_TOPICS) * block_size),
        **{f"rate {t}": in_window[t] / window_s for t in in_window},
    }
    return out


def writer_baseline(bag_dir: Path, source: Path, n_messages: int) -> float:
    """Messages/s of BagWriter alone, writing recorded serialized blocks (best of 3)."""
    raw = [
        (topic, t, bytes(data)) for topic, _, t, data in bagio.iter_raw(source, list(BLOCK_TOPICS))
    ][:n_messages]
    types = {t: i.msgtype for t, i in bagio.bag_info(source).topics.items()}
    counter = iter(range(1000))

    def write() -> None:
        with bagio.BagWriter(bag_dir / f"baseline_{next(counter)}") as writer:
            for topic in BLOCK_TOPICS:
                writer.add_topic(topic, types[topic])
            for topic, t, data in raw:
                writer.write(topic, t, data)

    return len(raw) / best_time_s(write)


def report(
    name: str,
    bag: Path,
    run: dict[str, object],
    block_size: int,
    rate_hz: float,
    baseline_msg_s: float,
) -> list[Figure]:
    """Print the per-topic table of one scenario and return its figures."""
    stats = analyse(bag, block_size, rate_hz)
    span = stats.pop("_span")
    for node, code in run["crashed"].items():
        print(
            f"WARNING: {node} exited (code {code}) during the run; see "
            f"{bag.parent / (node + '.log')}"
        )
    # the steady publisher's exact counts replace the index-span estimate
    if run["reported"] is not None:
        for s in stats.values():
            s["published"] = float(run["reported"]["blocks"])
            s["lost"] = s["published"] - s["recorded"] + s["duplicates"]
    print(
        f"\n[{name}] {bag}: {int(span['messages'])} messages in the {span['span_s']:.2f} s while "
        "all 4 streams flowed"
    )
    print(
        f"{'topic':28s} {'published':>10s} {'in bag':>8s} {'lost':>6s} {'dup':>5s} "
        f"{'rate in bag':>13s} {'before subscription':>20s}"
    )
    for topic, s in stats.items():
        print(
            f"{topic:28s} {int(s['published']):10d} {int(s['recorded']):8d} {int(s['lost']):6d} "
            f"{int(s['duplicates']):5d} {span['rate ' + topic]:9.0f} /s "
            f"{int(s['first_index'] // block_size):20d}"
        )
    recorded = sum(s["recorded"] for s in stats.values())
    published = sum(s["published"] for s in stats.values())
    lost_blocks = sum(stats[t]["lost"] + stats[t]["duplicates"] for t in BLOCK_TOPICS)
    published_blocks = sum(stats[t]["published"] for t in BLOCK_TOPICS)
    lost_clock = stats["/clock"]["lost"] + stats["/clock"]["duplicates"]
    # what the publishers send: the throughput is reported beside it (`info`); the target is
    # that nothing is lost (README: "0 lost"), which the two loss counts below enforce
    nominal_msg_s = (len(BLOCK_TOPICS) + 1) * rate_hz / block_size
    nominal_samples_s = len(BLOCK_TOPICS) * rate_hz
    msg_s, samples_s, cores = (
        span["messages"] / span["span_s"],
        span["samples"] / span["span_s"],
        run["recorder_cores"],
    )
    return [
        info(
            f"[{name}] recorder throughput (3 block topics + /clock)",
            msg_s,
            "msg/s",
            f"published at {nominal_msg_s:g}/s; publishers ~"
            f"{msg_s * published / max(recorded, 1):,.0f}/s; BagWriter alone "
            f"{baseline_msg_s:,.0f}/s",
        ),
        info(
            f"[{name}] recorder throughput, samples (3 x 20 kHz)",
            samples_s,
            "samples/s",
            f"published at {nominal_samples_s:g}/s; {int(span['samples'])} samples in "
            f"{span['span_s']:.2f} s",
        ),
        compare(
            f"[{name}] block messages lost or duplicated",
            lost_blocks if published_blocks > 0 else math.nan,  # nothing measured: not "0 lost"
            "messages",
            "==",
            0,
            f"of {int(published_blocks)} published (queues 1000 deep)",
        ),
        compare(
            f"[{name}] /clock messages lost or duplicated",
            lost_clock if stats["/clock"]["published"] > 0 else math.nan,
            "messages",
            "==",
            0,
            f"of {int(stats['/clock']['published'])} published (publisher queue {CLOCK_DEPTH} "
            "deep)",
        ),
        compare(
            f"[{name}] recorder CPU",
            cores,
            "cores",
            "<",
            1.0,
            "2-core machine shared with other work",
        ),
    ]


def player_pacing(
    work: Path, n: int = 400, period_ns: int = 5_000_000, rate: float = 2.0
) -> list[Figure]:
    """`flaair play --rate 2` of a 2 s bag: how long the play lasts against the schedule's span
    (the test checks only that it never runs ahead). Baseline: the same schedule slept out in this
    process with the player's own wait loop, in the same run.
    """
    from flaair_common.qos import BLOCK_STREAM
    from flaair_tools.recorder.player import wall_offset_s

    store, bag = bagio.typestore(), work / "pacing_bag"
    with bagio.BagWriter(bag, store=store) as writer:
        for i in range(n):
            stamp_ns = 10_000_000_000 + i * period_ns
            message = bagio.new_message(
                "flaair_msgs/msg/SensorVoltageBlock",
                store,
                header=bagio.new_message(
                    "std_msgs/msg/Header", store, stamp=bagio.time_msg(stamp_ns, store)
                ),
                sample_rate_hz=20000.0,
                first_sample_index=10 * i,
                stroke_sensor_v=np.zeros(10),
                pitch_sensor_v=np.zeros(10),
            )
            writer.write_message(
                "/flaair/sensor_v", stamp_ns, message, [bagio.qos_from_rclpy(BLOCK_STREAM)]
            )
    span_s = (n - 1) * period_ns * 1e-9 / rate
    with Graph(work / "pacing_logs") as graph:
        player = graph.start(
            "player", str(REPO_ROOT / "bin" / "flaair"), "play", str(bag), "--rate", str(rate)
        )
        player.wait(timeout=120)
        import re

        found = re.search(r"in ([0-9.]+) s", graph.log("player"))
    played_s = float(found.group(1)) if found else float("nan")
    start = time.monotonic()
    for i in range(n):  # the baseline: the player's wait loop alone
        due = start + wall_offset_s(i * period_ns, 0, rate)
        while (wait := due - time.monotonic()) > 0:
            time.sleep(min(wait, 0.1))
    slept_s = time.monotonic() - start
    late_ms = (played_s - span_s) * 1e3
    # two bounds, each its own comparison: the play never ends before the schedule's span
    # (never runs ahead) and at most 20 ms after it
    return [
        compare(
            "player --rate 2: play time beyond the schedule's span (2 s bag)",
            round(late_ms, 2),
            "ms",
            "<",
            20.0,
            f"wait loop alone: {(slept_s - span_s) * 1e3:.2f} ms",
        ),
        compare(
            "player --rate 2: play time not short of the schedule's span (2 s bag)",
            round(late_ms, 2),
            "ms",
            ">=",
            0.0,
            f"played {played_s:.3f} s against a span of {span_s:.3f} s",
        ),
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="seconds recorded per scenario")
    ap.add_argument(
        "--scenarios", nargs="+", default=["graph", "steady"], choices=["graph", "steady"]
    )
    ap.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench_recorder.json")
    ap.add_argument("--keep", action="store_true", help="keep the bags and logs (printed path)")
    args = ap.parse_args()
    shared = node_parameters("flaair.yaml", "plant_node")
    block_size, rate_hz = int(shared["block_size"]), float(shared["sample_rate_hz"])
    work = Path(tempfile.mkdtemp(prefix="bench_recorder_"))
    figures: list[Figure] = []
    try:
        for scenario in args.scenarios:
            (work / scenario).mkdir()
            bag = work / scenario / "bag"
            run = record_scenario(bag, scenario, args.duration, block_size, rate_hz)
            baseline = writer_baseline(work / scenario, bag, 30000)
            figures += report(scenario, bag, run, block_size, rate_hz, baseline)
        figures += player_pacing(work)
        print()
        print_table(figures)
        write_json(figures, args.json)
    finally:
        if args.keep:
            print(f"kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
