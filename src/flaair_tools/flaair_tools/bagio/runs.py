"""Runs from bags: the measured-run columns of every run in one or more bags.

A run is what a lab exports as one CSV (docs/LAB_CSV_FORMAT.md): drive, both sensor
voltages and ground-truth angles (NaN where the truth is missing or invalid). Bags mark their
runs on /flaair/run_marker; a bag without markers is one run named after the bag.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flaair_common import topics
from flaair_tools import bagio

# The topics a run is made of.
RUN_TOPICS = (topics.SENSOR_VOLTAGE, topics.DRIVE, topics.WING_STATE_TRUTH, bagio.RUN_MARKER_TOPIC)


@dataclass(frozen=True)
class Run:
    """One run's columns (measured-run names and units), its name and sample rate."""

    name: str
    bag: str
    sample_rate_hz: float
    columns: dict[str, np.ndarray]
    expected_n_samples: int | None = None  # samples its run marker announced (None: no marker)

    def __getitem__(self, column: str) -> np.ndarray:
        return self.columns[column]

    def __contains__(self, column: str) -> bool:
        return column in self.columns

    @property
    def n_samples(self) -> int:
        return len(self.columns["stroke_sensor_v"])

    @property
    def fraction_present(self) -> float:
        """Share of the marker's announced samples that are in the bag (1 without a marker)."""
        return 1.0 if not self.expected_n_samples else self.n_samples / self.expected_n_samples


def _marked(blocks: bagio.Blocks | None, marker: bagio.RunMarker) -> bagio.Blocks | None:
    """The samples of `blocks` that `marker` names (None stays None: a stream the bag lacks)."""
    if blocks is None:
        return None
    return bagio.select_samples(blocks, marker.first_sample_index, marker.n_samples)


def _columns(
    sensor: bagio.Blocks, drive: bagio.Blocks | None, truth: bagio.Blocks | None
) -> dict[str, np.ndarray]:
    first = int(sensor.sample_index[0])
    n = len(sensor.sample_index)
    fs = float(sensor.sample_rate_hz)
    columns = {
        "time_s": (sensor.sample_index - first) / fs,
        "stroke_sensor_v": sensor["stroke_sensor_v"],
        "pitch_sensor_v": sensor["pitch_sensor_v"],
    }

    def aligned(blocks: bagio.Blocks, field: str, valid: str | None = None) -> np.ndarray:
        out = np.full(n, np.nan)
        where = blocks.sample_index - first
        keep = (where >= 0) & (where < n)
        values = blocks[field].astype(float)
        if valid is not None:
            values = np.where(blocks[valid].astype(bool), values, np.nan)
        out[where[keep]] = values[keep]
        return out

    if drive is not None:
        columns["drive_v"] = aligned(drive, "drive_v")
    if truth is not None:
        columns["stroke_deg"] = aligned(truth, "stroke_deg", "stroke_valid")
        columns["pitch_deg"] = aligned(truth, "pitch_deg", "pitch_valid")
    return columns


def load_runs(
    bags: Sequence[str | Path],
    *,
    need_truth: bool = True,
    need_drive: bool = True,
    missing: list[tuple[str, str]] | None = None,
) -> list[Run]:
    """Every run of every bag, as measured-run columns.

    Parameters
    ----------
    bags
        Bag directories.
    need_truth, need_drive
        Refuse bags without /flaair/wing_state/truth or /flaair/drive.
    missing
        A marked run without any sensor sample (a recovered, cut-short bag) is skipped; if
        `missing` is given, it is appended there as (bag, run).

    Raises
    ------
    bagio.BagError
        A bag is unreadable or lacks a needed topic (the message names the bag and topic).
    """
    runs: list[Run] = []
    for bag in bags:
        contents = bagio.read_bag(bag, RUN_TOPICS)
        runs += runs_of_bag(contents, need_truth=need_truth, need_drive=need_drive, missing=missing)
    return runs


def runs_of_bag(
    contents: bagio.BagContents,
    *,
    need_truth: bool = True,
    need_drive: bool = True,
    missing: list[tuple[str, str]] | None = None,
) -> list[Run]:
    """Every run of one bag already read (`bagio.read_bag(bag,
    RUN_TOPICS + ...)`); see `load_runs`.
    """
    bag = contents.info.path
    present = set(contents.info.topics)
    needed = (
        [topics.SENSOR_VOLTAGE]
        + ([topics.WING_STATE_TRUTH] if need_truth else [])
        + ([topics.DRIVE] if need_drive else [])
    )
    absent = [t for t in needed if t not in present]
    if absent:
        raise bagio.BagTopicError(
            f"{bag}: needed topic(s) {', '.join(absent)} not in the bag "
            f"(it has: {', '.join(sorted(present)) or 'nothing'})"
        )
    sensor = contents.blocks(topics.SENSOR_VOLTAGE)
    drive = contents.blocks(topics.DRIVE) if topics.DRIVE in present else None
    truth = contents.blocks(topics.WING_STATE_TRUTH) if topics.WING_STATE_TRUTH in present else None
    markers = contents.run_markers()
    if not markers:
        return [
            Run(bag.name, str(bag), float(sensor.sample_rate_hz), _columns(sensor, drive, truth))
        ]
    runs: list[Run] = []
    for marker in markers:
        part = _marked(sensor, marker)
        if len(part.sample_index) == 0:
            if missing is not None:
                missing.append((str(bag), marker.run))
            continue
        runs.append(
            Run(
                marker.run,
                str(bag),
                float(sensor.sample_rate_hz),
                _columns(part, _marked(drive, marker), _marked(truth, marker)),
                marker.n_samples,
            )
        )
    return runs
