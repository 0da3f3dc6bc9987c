"""`flaair import`: lab CSVs become block messages,
values exact, truth gaps kept, bad files named.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from flaair_model.config import node_parameters
from flaair_tools import bagio
from flaair_tools.bagio import import_cli
from rosproc import FLAAIR, isolated_env, run

HEADER = ("time_s", "drive_v", "stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg")
FS_HZ = 20000.0


def _write_csv(
    path: Path,
    n: int,
    seed: int,
    order: tuple[str, ...] = HEADER,
    stroke_gap: range = range(0),
    pitch_gap: range = range(0),
) -> dict[str, np.ndarray]:
    """A run CSV with full float64 precision (repr) and
    truth gaps (empty cells, 'nan'); returns the columns.
    """
    rng = np.random.default_rng(seed)
    columns = {
        "time_s": np.arange(n) / FS_HZ,
        "drive_v": 100.0 * np.sin(2 * np.pi * 140.0 * np.arange(n) / FS_HZ)
        + rng.normal(0, 1e-3, n),
        "stroke_sensor_v": 1.25 + rng.normal(0, 0.3, n),
        "pitch_sensor_v": 1.25 + rng.normal(0, 0.3, n),
        "stroke_deg": rng.normal(0, 30.0, n),
        "pitch_deg": rng.normal(0, 40.0, n),
    }
    columns["stroke_deg"][list(stroke_gap)] = np.nan
    columns["pitch_deg"][list(pitch_gap)] = np.nan
    lines = [",".join(order)]
    for k in range(n):
        cells = []
        for name in order:
            value = float(columns[name][k])
            if math.isnan(value):
                cells.append("" if name == "stroke_deg" else "nan")
            else:
                cells.append(repr(value))
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return columns


def test_import_round_trips_exactly_and_keeps_truth_gaps(tmp_path: Path) -> None:
    block_size = int(node_parameters("flaair.yaml", "import_runs")["block_size"])
    gap_s = float(node_parameters("flaair.yaml", "import_runs")["gap_s"])
    a = _write_csv(
        tmp_path / "chirp_full.csv",
        1003,
        seed=1,
        stroke_gap=range(100, 160),
        pitch_gap=range(500, 505),
    )
    b = _write_csv(
        tmp_path / "chirp_half.csv",
        400,
        seed=2,
        order=tuple(reversed(HEADER)),
        stroke_gap=range(0, 3),
    )
    bag = tmp_path / "runs"
    assert (
        import_cli.main(
            [str(tmp_path / "chirp_full.csv"), str(tmp_path / "chirp_half.csv"), "--out", str(bag)]
        )
        == 0
    )

    markers = bagio.read_run_markers(bag)
    assert [(m.run, m.first_sample_index, m.n_samples) for m in markers] == [
        ("chirp_full", 0, 1003),
        ("chirp_half", 1003, 400),
    ]
    assert (
        markers[0].source_file == str(tmp_path / "chirp_full.csv")
        and markers[0].sample_rate_hz == FS_HZ
    )
    span_a_ns = round(1003 / FS_HZ * 1e9)
    # one after the other, gap between
    assert markers[1].start_ns == markers[0].start_ns + span_a_ns + round(gap_s * 1e9)
    custom = json.loads(bagio.bag_info(bag).custom_data[bagio.RUNS_CUSTOM_KEY])
    assert [entry["run"] for entry in custom] == ["chirp_full", "chirp_half"]

    counts = bagio.message_counts(bag)
    blocks_expected = math.ceil(1003 / block_size) + math.ceil(400 / block_size)
    assert counts == {
        "/flaair/drive": blocks_expected,
        "/flaair/sensor_v": blocks_expected,
        "/flaair/wing_state/truth": blocks_expected,
        bagio.RUN_MARKER_TOPIC: 2,
    }

    for marker, columns in zip(markers, (a, b), strict=True):
        sensor = bagio.read_blocks(bag, "/flaair/sensor_v", run=marker.run)
        drive = bagio.read_blocks(bag, "/flaair/drive", run=marker.run)
        truth = bagio.read_blocks(bag, "/flaair/wing_state/truth", run=marker.run)
        assert sensor.sample_rate_hz == FS_HZ
        assert np.array_equal(drive["drive_v"], columns["drive_v"])  # exact float64
        assert np.array_equal(sensor["stroke_sensor_v"], columns["stroke_sensor_v"])
        assert np.array_equal(sensor["pitch_sensor_v"], columns["pitch_sensor_v"])
        for name in ("stroke", "pitch"):
            values, valid = truth[f"{name}_deg"], truth[f"{name}_valid"]
            assert np.array_equal(valid, np.isfinite(columns[f"{name}_deg"]))
            assert np.isnan(values[~valid]).all()  # a gap stays a gap, never zero-filled
            assert np.array_equal(values[valid], columns[f"{name}_deg"][valid])
        assert np.array_equal(
            truth.sample_index, marker.first_sample_index + np.arange(marker.n_samples)
        )
        assert (truth.scalars["source"] == 1).all()  # SOURCE_GROUND_TRUTH
        assert np.allclose(
            truth.time_ns - marker.start_ns, columns["time_s"] * 1e9, rtol=0.0, atol=1.0
        )
        assert set(np.diff(truth.block_first_index)) <= {block_size}
    assert not np.any(bagio.read_blocks(bag, "/flaair/wing_state/truth")["stroke_valid"][100:160])

    with open(next(bag.glob("*.mcap")), "rb") as stream:  # and the mcap library decodes them too
        decoded = [
            (c.topic, m)
            for _, c, _, m in make_reader(
                stream, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages()
        ]
    assert len(decoded) == sum(counts.values())
    first_truth = next(m for topic, m in decoded if topic == "/flaair/wing_state/truth")
    assert first_truth.source == 1 and first_truth.header.frame_id == "robot"


def test_reader_names_a_missing_topic(tmp_path: Path) -> None:
    _write_csv(tmp_path / "r.csv", 50, seed=3)
    assert import_cli.main([str(tmp_path / "r.csv"), "--out", str(tmp_path / "bag")]) == 0
    with pytest.raises(bagio.BagTopicError, match="no topic '/flaair/wing_state' in the bag"):
        bagio.read_blocks(tmp_path / "bag", "/flaair/wing_state")
    with pytest.raises(bagio.BagError, match="no run 'sweep'"):
        bagio.read_blocks(tmp_path / "bag", "/flaair/sensor_v", run="sweep")


BAD_FILES = {
    "missing_column": (
        "time_s,drive_v,stroke_sensor_v,stroke_deg,pitch_deg\n0,1,1.2,0,0\n5e-05,1,1.2,0,0\n",
        r"line 1: missing column\(s\) pitch_sensor_v",
    ),
    "non_numeric_sensor": (
        "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n"
        "0,1,1.2,1.3,0,0\n5e-05,1,1.2,1.3,0,0\n0.0001,1,abc,1.3,,0\n",
        r"line 4, column stroke_sensor_v: not a number: 'abc'",
    ),
    "time_not_increasing": (
        "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n"
        "0,1,1.2,1.3,0,0\n5e-05,1,1.2,1.3,0,0\n5e-05,1,1.2,1.3,0,0\n",
        r"line 4, column time_s: time not increasing",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_malformed_csv_is_refused_naming_file_line_column(
    tmp_path: Path, case: str, capsys
) -> None:
    text, expected = BAD_FILES[case]
    good = tmp_path / "good.csv"
    _write_csv(good, 20, seed=4)
    bad = tmp_path / f"{case}.csv"
    bad.write_text(text, encoding="utf-8")
    assert import_cli.main([str(good), str(bad), "--out", str(tmp_path / "bag")]) != 0
    err = capsys.readouterr().err
    assert str(bad) in err and re.search(expected, err), err
    assert not (tmp_path / "bag").exists()  # nothing written: every file is checked first


def test_malformed_csv_cli_exits_nonzero_without_traceback(tmp_path: Path) -> None:
    text, expected = BAD_FILES["non_numeric_sensor"]
    bad = tmp_path / "bad.csv"
    bad.write_text(text, encoding="utf-8")
    # through bin/flaair in a new process, as a person runs it (other tests: run_offline)
    result = run([FLAAIR, "import", str(bad), "--out", str(tmp_path / "bag")], isolated_env())
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    expected = f"{bad}: line 4, column stroke_sensor_v: not a number: 'abc'"
    assert expected in result.stderr, result.stderr
    assert not (tmp_path / "bag").exists()
