"""Runs into one rosbag2 (MCAP) bag: measured-run CSV files, or runs a lab import has read.

Each run becomes block messages, block_size samples each (config/flaair.yaml), exactly as
the simulated robot publishes them:
  /flaair/drive              DriveCommandBlock   drive_v
  /flaair/sensor_v           SensorVoltageBlock  stroke_sensor_v, pitch_sensor_v
  /flaair/wing_state/truth   WingStateBlock      stroke_deg, pitch_deg (source GROUND_TRUTH);
                                                 stroke_valid / pitch_valid false where the video
                                                 lost the wing (the NaN is kept, never filled)
Runs follow one another in time, gap_s apart; first_sample_index counts on across runs.
Each run is marked by a std_msgs/String on /flaair/run_marker holding JSON
{"run", "first_sample_index", "n_samples", "source_file", "sample_rate_hz", "start_ns"},
and listed in the bag's custom_data "flaair.runs". The last block of a run may be shorter.

Every file is checked before anything is written; a bad file is named with its line and column
(exit 2), and a failed or interrupted import leaves no bag behind.

Usage: bin/flaair import RUN.csv [RUN.csv ...] --out BAG [--gap-s S] [--kind KIND]
(flaair_tools.bagio.import_cli). Columns and units of RUN.csv: docs/LAB_CSV_FORMAT.md.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from flaair_common import cdr, topics
from flaair_common.qos import BLOCK_STREAM, EVENTS
from flaair_common.runcsv import MeasuredRun, read_run
from flaair_common.signal_ranges import implausible
from flaair_tools import bagio

CONFIG_FILE = "flaair.yaml"
SECTION = "import_runs"
DRIVE_TYPE = "flaair_msgs/msg/DriveCommandBlock"
SENSOR_TYPE = "flaair_msgs/msg/SensorVoltageBlock"
WING_TYPE = "flaair_msgs/msg/WingStateBlock"
PROGRESS_BLOCKS = 1000  # progress is reported every this many blocks
RATE_DIGITS = 9  # CSV times carry about this many significant digits: the rate is rounded to them
_NS_PER_S = 1_000_000_000


class RunSetError(ValueError):
    """Runs that cannot go into one bag together (the message names the runs)."""


def run_rate_hz(run: MeasuredRun) -> float:
    """The run's sample rate, rounded to the precision
    CSV times carry (5e-05 s steps -> 20000 Hz).
    """
    return float(f"{run.sample_rate_hz:.{RATE_DIGITS}g}")


def run_span_ns(run: MeasuredRun) -> int:
    """Duration of a run including its last sample period [ns]."""
    time_s = run["time_s"]
    return round((time_s[-1] - time_s[0] + 1.0 / run_rate_hz(run)) * _NS_PER_S)


def run_marker(
    run: MeasuredRun, *, source_file: str, start_ns: int, first_sample_index: int
) -> bagio.RunMarker:
    """The marker of a run starting at `start_ns` and `first_sample_index`."""
    return bagio.RunMarker(
        run=run.name,
        first_sample_index=first_sample_index,
        n_samples=len(run["time_s"]),
        source_file=source_file,
        sample_rate_hz=run_rate_hz(run),
        start_ns=start_ns,
    )


def encode_run(
    run: MeasuredRun,
    *,
    start_ns: int,
    first_sample_index: int,
    block_size: int,
    frame_id: str,
    truth_source: int,
) -> Iterator[tuple[str, int, bytes]]:
    """A run's block messages as (topic, stamp ns, CDR bytes) in time order, made one block at
    a time (pure): per block drive, sensor and ground truth (the run marker is the caller's).

    Block k starts at sample k * block_size; its header stamp is start_ns plus the CSV time of
    that sample (relative to the run's first sample). The stamp is also the message's log
    time in the bag, so viewers show the signal's own timeline. The bytes are those rclpy
    would publish (flaair_common.cdr, checked against rclpy in tests/test_cdr.py).
    """
    rate_hz = run_rate_hz(run)
    time_s = run["time_s"]
    n_samples = len(time_s)
    # one per block
    block_start_ns = np.round((time_s[::block_size] - time_s[0]) * _NS_PER_S).astype(np.int64)
    codecs: dict = {}
    for k0 in range(0, n_samples, block_size):
        part = slice(k0, min(k0 + block_size, n_samples))
        stamp_ns = start_ns + int(block_start_ns[k0 // block_size])
        sec, nanosec = divmod(stamp_ns, _NS_PER_S)
        head = {
            "sec": sec,
            "nanosec": nanosec,
            "sample_rate_hz": rate_hz,
            "first_sample_index": first_sample_index + k0,
        }
        stroke_deg, pitch_deg = run["stroke_deg"][part], run["pitch_deg"][part]
        yield (
            topics.DRIVE,
            stamp_ns,
            cdr.encode_fields(
                cdr.DRIVE_COMMAND_BLOCK,
                {**head, "frame_id": "", "drive_v": run["drive_v"][part]},
                codecs.setdefault(DRIVE_TYPE, {}),
            )[1],
        )
        yield (
            topics.SENSOR_VOLTAGE,
            stamp_ns,
            cdr.encode_fields(
                cdr.SENSOR_VOLTAGE_BLOCK,
                {
                    **head,
                    "frame_id": frame_id,
                    "stroke_sensor_v": run["stroke_sensor_v"][part],
                    "pitch_sensor_v": run["pitch_sensor_v"][part],
                },
                codecs.setdefault(SENSOR_TYPE, {}),
            )[1],
        )
        yield (
            topics.WING_STATE_TRUTH,
            stamp_ns,
            cdr.encode_fields(
                cdr.WING_STATE_BLOCK,
                {
                    **head,
                    "frame_id": frame_id,
                    "source": truth_source,
                    "stroke_deg": stroke_deg,
                    "pitch_deg": pitch_deg,
                    "stroke_velocity_deg_s": np.full(stroke_deg.size, np.nan),
                    "stroke_valid": np.isfinite(stroke_deg),
                    "pitch_valid": np.isfinite(pitch_deg),
                },
                codecs.setdefault(WING_TYPE, {}),
            )[1],
        )


def check_runs(runs: list[tuple[Path, MeasuredRun]]) -> None:
    """Runs must have plausible values, distinct names and one sample rate (a block topic
    has one rate).
    """
    names: dict[str, Path] = {}
    for path, run in runs:
        if problem := implausible(run):  # CSV and lab files alike
            raise RunSetError(f"{path}: {problem}")
        if run.name in names:
            raise RunSetError(
                f"{path}: run name '{run.name}' already used by {names[run.name]}; rename one file"
            )
        names[run.name] = path
    rates = {run_rate_hz(run): path for path, run in runs}
    if len(rates) > 1:
        listing = ", ".join(f"{path} {rate:g} Hz" for rate, path in rates.items())
        raise RunSetError(
            f"runs have different sample rates ({listing}); import them into separate bags"
        )


def import_runs(
    paths: list[Path],
    out: Path,
    *,
    gap_s: float,
    block_size: int,
    frame_id: str,
    progress: Callable[[int], None] | None = None,
    kind: str | None = None,
) -> list[bagio.RunMarker]:
    """Read and check every CSV, then write the bag (`write_runs`); returns the run markers."""
    check_settings(gap_s, block_size)
    runs = [(path, read_run(path)) for path in paths]
    check_runs(runs)
    return write_runs(
        [(str(path), run, {}) for path, run in runs],
        out,
        gap_s=gap_s,
        block_size=block_size,
        frame_id=frame_id,
        progress=progress,
        kind=kind,
    )


def check_settings(gap_s: float, block_size: int) -> None:
    """The gap between runs and the block size, before any file is read."""
    if not math.isfinite(gap_s) or gap_s < 0:
        raise RunSetError(f"--gap-s must be a finite time >= 0 s, got {gap_s}")
    if block_size < 1:
        raise RunSetError(
            f"config/{CONFIG_FILE}: {SECTION}.block_size must be >= 1, got {block_size}"
        )


def write_runs(
    runs: list[tuple[str, MeasuredRun, dict[str, Any]]],
    out: Path,
    *,
    gap_s: float,
    block_size: int,
    frame_id: str,
    progress: Callable[[int], None] | None = None,
    kind: str | None = None,
) -> list[bagio.RunMarker]:
    """Write runs already read and checked, (source, run, marker extras) each, into a new bag.

    Messages are made and written one block at a time. If anything fails (or the user
    interrupts) after the bag directory was created, it is removed: no partial bag is left
    that looks valid. `progress` is called with the samples written so far. `kind` (a
    flaair_tools.analysis.runkind kind) and each run's extras (what a lab import recorded: its
    files, rig and sync) go into the run marker's JSON; `flaair analyze` reads them.
    """
    markers: list[bagio.RunMarker] = []
    marker_values: list[dict[str, Any]] = []
    start_ns = 0
    first_index = 0
    writer = bagio.BagWriter(out, store=bagio.typestore())
    try:
        for source, run, extras in runs:
            values = write_run(
                writer,
                run,
                source_file=source,
                start_ns=start_ns,
                first_sample_index=first_index,
                block_size=block_size,
                frame_id=frame_id,
                extras={**extras, **({"kind": kind} if kind else {})},
                progress=progress,
            )
            markers.append(bagio.RunMarker.from_json(json.dumps(values)))
            marker_values.append(values)
            first_index += markers[-1].n_samples
            start_ns += run_span_ns(run) + round(gap_s * _NS_PER_S)
        writer.set_custom_data(bagio.RUNS_CUSTOM_KEY, json.dumps(marker_values))
        writer.close()
    except BaseException:
        writer.abandon()
        raise
    return markers


def write_run(
    writer: bagio.BagWriter,
    run: MeasuredRun,
    *,
    source_file: str,
    start_ns: int,
    first_sample_index: int,
    block_size: int,
    frame_id: str,
    extras: dict[str, Any] | None = None,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Write one run into an open bag: its marker (with `extras`), then its blocks
    (`encode_run`); returns the marker's JSON values.
    """
    offered = {
        topics.DRIVE: [bagio.qos_from_rclpy(BLOCK_STREAM)],
        topics.SENSOR_VOLTAGE: [bagio.qos_from_rclpy(BLOCK_STREAM)],
        topics.WING_STATE_TRUTH: [bagio.qos_from_rclpy(BLOCK_STREAM)],
    }
    for topic, msgtype in (
        (topics.DRIVE, DRIVE_TYPE),
        (topics.SENSOR_VOLTAGE, SENSOR_TYPE),
        (topics.WING_STATE_TRUTH, WING_TYPE),
    ):
        writer.add_topic(topic, msgtype, offered[topic])
    marker = run_marker(
        run, source_file=source_file, start_ns=start_ns, first_sample_index=first_sample_index
    )
    values = {**json.loads(marker.to_json()), **(extras or {})}
    writer.write_message(
        bagio.RUN_MARKER_TOPIC,
        start_ns,
        bagio.new_message(bagio.RUN_MARKER_TYPE, writer.store, data=json.dumps(values)),
        [bagio.qos_from_rclpy(EVENTS)],
    )
    for k, (topic, stamp_ns, data) in enumerate(
        encode_run(
            run,
            start_ns=start_ns,
            first_sample_index=first_sample_index,
            block_size=block_size,
            frame_id=frame_id,
            truth_source=writer.store.types[WING_TYPE].SOURCE_GROUND_TRUTH,
        )
    ):
        writer.write(topic, stamp_ns, data)
        if progress is not None and k % (3 * PROGRESS_BLOCKS) == 0:
            progress(first_sample_index + min(k // 3 * block_size, marker.n_samples))
    if progress is not None:
        progress(first_sample_index + marker.n_samples)
    return values
