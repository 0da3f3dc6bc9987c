"""What the bridge reports of a run: the one-line summary of its counters, and raw event times
for benchmarks (`EventLog`).
"""

from __future__ import annotations

import math

import numpy as np

from flaair_bridge.core.bridge_state import Counters, DriveBlock, Input, Outputs, SensorDatagram

__all__ = ["EventLog", "summary"]


def summary(counters: Counters, timing: list[tuple[int, float, float]]) -> str:
    """One line of every counter and, from `Outputs.timing` records, the sensor-to-drive latency."""
    text = ", ".join(f"{name} {value}" for name, value in counters._asdict().items())
    if timing:
        latency_ms = 1e3 * np.array([send - arrival for _, arrival, send in timing])
        text += (
            f"; sensor arrival -> drive packet p50 {np.percentile(latency_ms, 50):.3f} ms, "
            f"p99 {np.percentile(latency_ms, 99):.3f} ms over {len(latency_ms)} packets"
        )
    return text


class EventLog:
    """Raw event times for benchmarks: each sensor packet (packets accepted so far, arrival s) and
    each drive block (stream index, receive s, send s, cause s). Send is NaN when the block was
    queued or dropped; cause is the arrival of the sensor packet whose handling produced the block
    (the composed loop answers a packet before it reads the next), NaN when there was none.
    """

    def __init__(self) -> None:
        self.sensor: list[tuple[int, float]] = []
        self.drive: list[tuple[int, float, float, float]] = []

    def record(
        self,
        inputs: Input,
        out: Outputs,
        counters: Counters,
        now_s: float,
        cause_s: float = math.nan,
    ) -> None:
        if isinstance(inputs, DriveBlock):
            self.drive.append(
                (
                    inputs.first_sample_index,
                    inputs.now_s,
                    now_s if out.packets else math.nan,
                    cause_s,
                )
            )
        elif isinstance(inputs, SensorDatagram):
            self.sensor.append((counters.sensor_packets, inputs.now_s))

    def arrays(self) -> dict[str, np.ndarray]:
        return {
            "sensor": np.array(self.sensor).reshape(-1, 2),
            "drive": np.array(self.drive).reshape(-1, 4),
        }
