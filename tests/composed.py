"""In-process, deterministic harness: FLAAIR's own node classes composed on one `intra.Bus`.

The nodes are the ones `bin/flaair run` and `flaair live` start (the same shells over the same
cores), built side by side in this process as the container builds them, their block streams
delivered in-process. Nothing runs on its own: the harness drains the bus and fires each node's
timers on a fake clock, so a closed lockstep loop runs the same way, to the same sample, on a
quiet machine and on a loaded one, and a test can assert exact values.

    with composed(monkeypatch, [PlantNode, FrontendNode, DsaControllerNode],
                  {"dsa_controller_node": {"kr_ramp_start_s": 0.3}}) as loop:
        states = loop.sink(topics.CONTROLLER_STATE)
        loop.run_until(lambda: len(states) >= 100)

The clock: the nodes' `time.monotonic()` reads `loop.clock`; it advances by one block period
with every sensor block the plant steps (lockstep at the real-time rate), and jumps to the next
due timer when nothing else is left to do. Each node still has its DDS participant (on a leased
domain of its own), which no one outside listens to.
"""

from __future__ import annotations

import copy
import importlib
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from flaair_common import intra, topics
from flaair_common.graph import lease_domain
from flaair_tools.orchestration.graphs import GRAPHS, component_modules

REPO_ROOT = Path(__file__).resolve().parents[1]
FS_HZ = 20000.0
BLOCK = 10
# The block streams composed nodes hand each other in-process (everything `live` composes).
LOCAL_TOPICS = GRAPHS["lockstep_loop"].local_topics
# Node modules whose `time.monotonic` / `time.sleep` the fake clock replaces.
NODE_MODULES = component_modules()


class FakeClock:
    """`time` for the nodes: monotonic() and sleep() on a clock the harness moves; the rest real."""

    def __init__(self, start_s: float = 1000.0) -> None:
        self.now_s = start_s

    def monotonic(self) -> float:
        return self.now_s

    def sleep(self, duration_s: float) -> None:
        self.now_s += max(0.0, duration_s)

    def advance(self, duration_s: float) -> None:
        self.now_s += duration_s

    def __getattr__(self, name: str) -> Any:  # perf_counter, thread_time, ...: the real ones
        return getattr(time, name)


class Composed:
    """Nodes on one bus, a fake clock, and sinks that keep every block of a topic."""

    def __init__(
        self, bus: intra.Bus, nodes: list[Any], clock: FakeClock, block_period_s: float
    ) -> None:
        self.bus, self.nodes, self.clock, self.block_period_s = bus, nodes, clock, block_period_s
        # id(timer) -> when it fires next (a node may add or destroy timers)
        self.due_s: dict[int, float] = {}
        self.stepped_blocks = 0
        bus.subscribe(topics.SENSOR_VOLTAGE, self._on_stepped)

    def _on_stepped(self, _fields: dict) -> None:
        self.stepped_blocks += 1
        self.clock.advance(self.block_period_s)

    def node(self, name: str) -> Any:
        (found,) = [node for node in self.nodes if node.get_name() == name]
        return found

    def sink(self, topic: str) -> list[dict]:
        """Every block of `topic` from now on (a copy of its fields); the topic must be local."""
        assert topic in self.bus.local_topics, f"{topic} is not delivered in-process"
        kept: list[dict] = []
        self.bus.subscribe(topic, lambda fields: kept.append(copy.deepcopy(fields)))
        return kept

    def post(self, topic: str, fields: dict) -> None:
        """Queue a block for `topic`'s in-process subscribers without running them now: what a node
        that publishes on plain rclpy (not `intra`) would have DDS deliver later, not from inside
        its own publish call.
        """
        for callback, background in self.bus.subscribers.get(topic, ()):
            (self.bus.background_queue if background else self.bus.queue).append((callback, fields))

    def live_timers(self) -> list[tuple[Any, float]]:
        """(timer, period s) of every node's timers now, each with its next due time set."""
        timers = [
            (timer, timer.timer_period_ns * 1e-9)
            for node in self.nodes
            for timer in node.timers
            if not timer.is_canceled()
        ]
        for timer, period in timers:
            self.due_s.setdefault(id(timer), self.clock.now_s + period)
        return timers

    def fire_due_timers(self) -> int:
        fired = 0
        for timer, period in self.live_timers():
            if self.clock.now_s >= self.due_s[id(timer)]:
                self.due_s[id(timer)] = self.clock.now_s + period
                timer.callback()
                fired += 1
        return fired

    def run_until(
        self,
        done: Callable[[], bool],
        max_clock_s: float = 60.0,
        budget: int = 8,
        idle_until_s: float | None = None,
    ) -> None:
        """Drain the bus and fire due timers until `done()`; fail after `max_clock_s` of fake time.

        With nothing queued and no timer left, the clock jumps to `idle_until_s` (if given: the
        end of a `run_for`), else the run fails: `done()` could never come true.
        """
        end_s = self.clock.now_s + max_clock_s
        while not done():
            assert self.clock.now_s < end_s, f"not done after {max_clock_s:g} s of (fake) clock"
            worked = self.bus.drain(budget) + self.fire_due_timers()
            if not worked and not self.bus.pending():
                live = [self.due_s[id(timer)] for timer, _ in self.live_timers()]
                if idle_until_s is not None:
                    live.append(idle_until_s)
                assert live, "nothing left to run: no queued block and no timer"
                self.clock.now_s = max(self.clock.now_s, min(live))

    def run_for(self, duration_s: float) -> None:
        """Run on for `duration_s` of the fake clock."""
        end_s = self.clock.now_s + duration_s
        self.run_until(lambda: self.clock.now_s >= end_s, duration_s + 1.0, idle_until_s=end_s)


def write_params(path: Path, params: dict[str, dict[str, Any]]) -> Path:
    """A ROS params file with one section per node name."""
    path.write_text(
        yaml.safe_dump({name: {"ros__parameters": values} for name, values in params.items()})
    )
    return path


@contextmanager
def composed(
    monkeypatch,
    node_classes: list[type],
    params: dict[str, dict[str, Any]] | None = None,
    tmp_path: Path | None = None,
    local_topics: tuple[str, ...] = LOCAL_TOPICS,
) -> Iterator[Composed]:
    """Build `node_classes` in this process on one bus (per-node parameter overrides in `params`),
    their clocks faked; destroy them and shut rclpy down at the end.
    """
    import tempfile

    import rclpy

    clock = FakeClock()
    for name in NODE_MODULES:
        module = importlib.import_module(name)
        if hasattr(module, "time"):
            monkeypatch.setattr(module, "time", clock)
    lease = lease_domain()
    params_dir = Path(tempfile.mkdtemp(prefix="flaair-composed-")) if tmp_path is None else tmp_path
    params_file = write_params(params_dir / "composed_params.yaml", params or {})
    bus = intra.Bus(set(local_topics))
    if rclpy.ok():
        rclpy.shutdown()
    rclpy.init(
        args=["composed", "--ros-args", "--params-file", str(params_file)],
        domain_id=lease.domain_id,
    )
    intra.install(bus)
    nodes: list[Any] = []
    try:
        for cls in node_classes:
            nodes.append(cls())
        yield Composed(bus, nodes, clock, BLOCK / FS_HZ)
    finally:
        for node in reversed(nodes):
            node.destroy_node()
        intra.install(None)
        rclpy.try_shutdown()
        lease.release()


def joined(blocks: list[dict], field: str) -> np.ndarray:
    """One per-sample field of consecutive blocks, joined (asserts they are gap-free)."""
    starts = [int(b["first_sample_index"]) for b in blocks]
    sizes = [len(b[field]) for b in blocks]
    assert starts == list(np.cumsum([starts[0], *sizes[:-1]])), "blocks are not contiguous"
    return np.concatenate([np.asarray(b[field], dtype=float) for b in blocks])
