"""Property tests (issue 15 item 7): random bytes into the CSV reader, the bag reader and
recovery, and the CDR codec. Each answers with its named error, never another exception.
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from flaair_common import cdr
from flaair_common.runcsv import RunFileError, read_run
from flaair_tools import bagio

HEADER = b"time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n"
CELL = st.sampled_from(
    [
        "0",
        "1.25",
        "",
        "nan",
        "inf",
        "-1e309",
        "1_0",
        " 2 ",
        "0x1",
        "1e",
        '"3"',
        "abc",
        "\x00",
        "\ufeff",
    ]
)
ROW = st.lists(CELL, min_size=0, max_size=8).map(lambda cells: ",".join(cells).encode())
SETTINGS = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@SETTINGS
@given(
    st.one_of(
        st.binary(max_size=400),
        st.lists(ROW, max_size=6).map(lambda rows: HEADER + b"\n".join(rows)),
    )
)
def test_csv_reader_answers_random_bytes_with_run_file_error(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "run.csv"
        path.write_bytes(data)
        try:
            run = read_run(path)
        except RunFileError as exc:
            assert "run.csv" in str(exc)
            return
        assert all(
            np.isfinite(run[name]).all()
            for name in ("time_s", "drive_v", "stroke_sensor_v", "pitch_sensor_v")
        )


def _small_bag(directory: Path) -> bytes:
    store = bagio.typestore()
    with bagio.BagWriter(directory, store=store, compression=True, chunk_size_bytes=2000) as writer:
        for k in range(60):
            writer.write_message(
                "/flaair/chatter",
                k,
                bagio.new_message("std_msgs/msg/String", store, data=f"m{k}" * 20),
            )
    return next(directory.glob("*.mcap")).read_bytes()


@pytest.mark.slow  # property test: many damaged bags, each read and recovered
@SETTINGS
@given(st.data())
def test_bag_reader_and_recovery_answer_damaged_bytes_with_bag_error(data) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        original = _small_bag(bag)
        mcap_file = next(bag.glob("*.mcap"))
        damaged = bytearray(original)
        for _ in range(data.draw(st.integers(1, 4))):
            start = data.draw(st.integers(0, len(damaged) - 1))
            damaged[start : start + data.draw(st.integers(1, 300))] = data.draw(
                st.binary(min_size=1, max_size=300)
            )
        cut = data.draw(st.integers(0, len(damaged)))
        mcap_file.write_bytes(bytes(damaged[:cut]))
        for read in (
            lambda: bagio.bag_info(bag),
            lambda: list(bagio.iter_messages(bag)),
            lambda: bagio.check_bag(bag),
        ):
            with contextlib.suppress(bagio.BagError):
                read()
        try:
            report = bagio.reindex(bag)
        except bagio.BagError:
            # refused: the original is untouched
            assert mcap_file.read_bytes() == bytes(damaged[:cut])
            return
        kept = report.counts.get("/flaair/chatter", 0)
        assert kept == sum(1 for _ in bagio.iter_raw(bag))
        assert not (bag / ".reindex").exists()


@SETTINGS
@given(
    st.binary(max_size=64).map(lambda b: b"\x00\x01\x00\x00" + b),
    st.sampled_from(sorted(cdr.LAYOUTS)),
)
def test_cdr_decoder_answers_random_bytes_with_cdr_error(data: bytes, type_name: str) -> None:
    layout = cdr.LAYOUTS[type_name]
    with contextlib.suppress(cdr.CdrError):
        cdr.decode(layout, data)
    if not any(kind == "string" for _, kind in layout.fields):
        with contextlib.suppress(cdr.CdrError):
            cdr.FixedCodec(layout, 10).decode(data)


@SETTINGS
@given(st.binary(max_size=600))
def test_mcap_scan_answers_random_bytes_with_bag_error(data: bytes) -> None:
    for candidate in (data, bagio.MCAP_MAGIC + data):
        try:
            records = list(bagio.scan_mcap(candidate))
        except bagio.BagError:
            continue
        assert all(r is not None for r in records)
