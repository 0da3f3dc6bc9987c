"""bagio: bags written here are read back by rosbags and, independently, by the mcap library."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

from flaair_common.blocks import from_array
from flaair_common.msgdict import to_dict
from flaair_common.qos import BLOCK_STREAM, EVENTS, STATUS
from flaair_msgs.msg import (
    CollisionEvent,
    CollisionStatus,
    ControllerState,
    DriveCommandBlock,
    SensorVoltageBlock,
    WingStateBlock,
)
from flaair_tools import bagio

REPO_ROOT = Path(__file__).resolve().parents[1]
PROJECT_TYPES = (
    "CollisionEvent",
    "CollisionStatus",
    "ControllerState",
    "DriveCommandBlock",
    "SensorVoltageBlock",
    "WingStateBlock",
)


def _stamp(message, sec: int, nanosec: int) -> None:
    message.header.stamp.sec = sec
    message.header.stamp.nanosec = nanosec


def _rclpy_messages() -> dict[str, tuple[str, object, object]]:
    """Topic -> (type, rclpy message, QoS) covering every flaair_msgs type and std_msgs/String."""
    sensor = SensorVoltageBlock(sample_rate_hz=20000.0, first_sample_index=40)
    _stamp(sensor, 3, 2_000_000)
    sensor.header.frame_id = "robot"
    sensor.stroke_sensor_v = from_array(1.25 + np.linspace(-0.1, 0.1, 10))
    sensor.pitch_sensor_v = from_array(1.25 - np.linspace(-0.2, 0.2, 10))
    drive = DriveCommandBlock(sample_rate_hz=20000.0, first_sample_index=40)
    _stamp(drive, 3, 2_000_000)
    drive.drive_v = from_array(np.linspace(-100.0, 100.0, 10))
    truth = WingStateBlock(
        sample_rate_hz=20000.0, first_sample_index=40, source=WingStateBlock.SOURCE_GROUND_TRUTH
    )
    _stamp(truth, 3, 2_000_000)
    truth.stroke_deg = from_array(np.array([1.0, np.nan, 3.0]))
    truth.pitch_deg = from_array(np.array([-1.0, -2.0, np.nan]))
    truth.stroke_velocity_deg_s = from_array(np.array([10.0, 20.0, 30.0]))
    truth.stroke_valid = [True, False, True]
    truth.pitch_valid = [True, True, False]
    status = CollisionStatus(
        wingbeat_index=7,
        wingbeat_frequency_hz=140.0,
        colliding=True,
        spectrum_rmse_deg=2.5,
        time_rmse_deg=1.5,
        threshold_deg=2.0,
    )
    _stamp(status, 3, 5_000_000)
    event = CollisionEvent(kind=CollisionEvent.ONSET, wingbeat_index=7, spectrum_rmse_deg=2.5)
    _stamp(event, 3, 5_000_000)
    state = ControllerState(
        k_r=0.25,
        async_drive_v=12.5,
        sync_drive_v=-3.0,
        drive_v=9.5,
        drive_clamped=True,
        watchdog=ControllerState.WATCHDOG_TRIPPED,
        fault="stroke sensor silent",
        amplitude_scale=0.5,
        stroke_frequency_hz=139.5,
    )
    _stamp(state, 3, 6_000_000)
    return {
        "/flaair/sensor_v": ("flaair_msgs/msg/SensorVoltageBlock", sensor, BLOCK_STREAM),
        "/flaair/drive": ("flaair_msgs/msg/DriveCommandBlock", drive, BLOCK_STREAM),
        "/flaair/wing_state/truth": ("flaair_msgs/msg/WingStateBlock", truth, BLOCK_STREAM),
        "/flaair/collision/status": ("flaair_msgs/msg/CollisionStatus", status, STATUS),
        "/flaair/collision/events": ("flaair_msgs/msg/CollisionEvent", event, EVENTS),
        "/flaair/controller/state": ("flaair_msgs/msg/ControllerState", state, STATUS),
        bagio.RUN_MARKER_TOPIC: (
            "std_msgs/msg/String",
            String(data='{"run": "chirp_full"}'),
            EVENTS,
        ),
    }


def _same(reference: object, decoded: object) -> bool:
    """Field-by-field equality of an rclpy message and a
    decoded one (rosbags or mcap_ros2); NaN == NaN.
    """
    return _equal(to_dict(reference), decoded)


def _equal(expected: object, decoded: object) -> bool:
    if isinstance(expected, dict):
        return all(_equal(value, getattr(decoded, name)) for name, value in expected.items())
    if isinstance(expected, list):
        expected_arr, decoded_arr = np.asarray(expected), np.asarray(decoded)
        if expected_arr.dtype.kind == "f":
            return expected_arr.shape == decoded_arr.shape and bool(
                np.array_equal(expected_arr, decoded_arr, equal_nan=True)
            )
        return expected_arr.tolist() == decoded_arr.tolist()
    return expected == decoded


@pytest.fixture()
def all_types_bag(tmp_path: Path) -> tuple[Path, dict]:
    messages = _rclpy_messages()
    bag = tmp_path / "all_types"
    with bagio.BagWriter(bag, compression=True, chunk_size_bytes=4096) as writer:
        for topic, (msgtype, message, qos) in messages.items():
            writer.add_topic(topic, msgtype, [bagio.qos_from_rclpy(qos)])
            data = serialize_message(message)  # the bytes rclpy puts on the wire
            for k in range(3):
                writer.write(topic, 3_000_000_000 + 1_000_000 * k, data)
    return bag, messages


def test_rosbags_reads_every_type_back_equal(all_types_bag: tuple[Path, dict]) -> None:
    bag, messages = all_types_bag
    store = bagio.typestore()
    seen: dict[str, int] = {}
    with Reader(bag) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {
            t: v[0] for t, v in messages.items()
        }
        for connection, _timestamp, data in reader.messages():
            decoded = store.deserialize_cdr(data, connection.msgtype)
            assert _same(messages[connection.topic][1], decoded), connection.topic
            seen[connection.topic] = seen.get(connection.topic, 0) + 1
    assert seen == {topic: 3 for topic in messages}


def test_mcap_library_decodes_every_type_independently(all_types_bag: tuple[Path, dict]) -> None:
    bag, messages = all_types_bag
    mcap_file = next(bag.glob("*.mcap"))
    seen: dict[str, int] = {}
    with open(mcap_file, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
        assert {index.compression for index in summary.chunk_indexes} == {"zstd"}
        assert len(summary.chunk_indexes) > 1  # 4 KiB chunks: several
        assert {s.name for s in summary.schemas.values()} == {m[0] for m in messages.values()}
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        for _, channel, _, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == "cdr"
            assert _same(messages[channel.topic][1], decoded), channel.topic
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
    assert seen == {topic: 3 for topic in messages}


def test_offered_qos_and_type_hashes_recorded_as_rosbag2_does(
    all_types_bag: tuple[Path, dict],
) -> None:
    bag, messages = all_types_bag
    with open(next(bag.glob("*.mcap")), "rb") as stream:
        summary = make_reader(stream).get_summary()
    for channel in summary.channels.values():
        offered = bagio.qos_from_yaml(channel.metadata["offered_qos_profiles"])
        assert offered == [bagio.qos_from_rclpy(messages[channel.topic][2])]
    events = next(c for c in summary.channels.values() if c.topic == "/flaair/collision/events")
    assert "durability: transient_local" in events.metadata["offered_qos_profiles"]
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert (
        metadata["version"] == 9
        and metadata["storage_identifier"] == "mcap"
        and metadata["ros_distro"] == "jazzy"
    )
    assert metadata["message_count"] == 3 * len(messages)
    hashes = {
        t["topic_metadata"]["type"]: t["topic_metadata"]["type_description_hash"]
        for t in metadata["topics_with_message_count"]
    }
    # the hashes the typestore computes from the .msg files equal the ones rosidl generated
    for name in PROJECT_TYPES:
        generated = json.loads(
            (REPO_ROOT / "install" / "share" / "flaair_msgs" / "msg" / f"{name}.json").read_text()
        )
        assert hashes[f"flaair_msgs/msg/{name}"] == generated["type_hashes"][0]["hash_string"]


def test_leading_stamp_read_from_cdr_without_decoding() -> None:
    truth = WingStateBlock()
    _stamp(truth, 12, 345_678_901)
    clock = Clock()
    clock.clock.sec, clock.clock.nanosec = 7, 5
    assert bagio.leading_stamp_ns(serialize_message(truth)) == 12_345_678_901
    assert bagio.leading_stamp_ns(serialize_message(clock)) == 7_000_000_005
    assert bagio.has_leading_stamp("flaair_msgs/msg/WingStateBlock")
    assert bagio.has_leading_stamp("rosgraph_msgs/msg/Clock")
    assert not bagio.has_leading_stamp("std_msgs/msg/String")


def _write_sensor_blocks(bag: Path, firsts: list[int], length: int = 10) -> None:
    store = bagio.typestore()
    with bagio.BagWriter(bag, store=store) as writer:
        for number, first in enumerate(firsts):
            stamp_ns = first * 50_000
            message = bagio.new_message(
                "flaair_msgs/msg/SensorVoltageBlock",
                store,
                header=bagio.new_message(
                    "std_msgs/msg/Header", store, stamp=bagio.time_msg(stamp_ns, store)
                ),
                sample_rate_hz=20000.0,
                first_sample_index=first,
                stroke_sensor_v=first + np.arange(length, dtype=float),
                pitch_sensor_v=np.full(length, number * 1.0),
            )
            writer.write_message("/flaair/sensor_v", stamp_ns, message)


def test_read_blocks_concatenates_and_checks_continuity(tmp_path: Path) -> None:
    _write_sensor_blocks(tmp_path / "ok", [0, 10, 20, 30])
    blocks = bagio.read_blocks(tmp_path / "ok", "/flaair/sensor_v")
    assert (
        blocks.sample_rate_hz == 20000.0
        and blocks.first_sample_index == 0
        and blocks.n_samples == 40
    )
    assert np.array_equal(blocks["stroke_sensor_v"], np.arange(40.0))
    assert np.array_equal(blocks.sample_index, np.arange(40))
    assert np.array_equal(blocks.time_ns, np.arange(40) * 50_000)

    _write_sensor_blocks(tmp_path / "gap", [0, 10, 30, 40])
    with pytest.raises(
        bagio.BagContinuityError,
        match=r"'/flaair/sensor_v': block 2 has "
        r"first_sample_index 30, expected 20 \(10 "
        r"samples missing\)",
    ):
        bagio.read_blocks(tmp_path / "gap", "/flaair/sensor_v")
    gappy = bagio.read_blocks(tmp_path / "gap", "/flaair/sensor_v", allow_gaps=True)
    # the gap stays a gap: nothing filled in
    assert gappy.gaps == ((20, 30),) and gappy.n_samples == 40
    assert np.array_equal(gappy.sample_index[15:25], [15, 16, 17, 18, 19, 30, 31, 32, 33, 34])

    _write_sensor_blocks(tmp_path / "repeat", [0, 10, 10])
    with pytest.raises(bagio.BagContinuityError, match="10 samples repeated"):
        bagio.read_blocks(tmp_path / "repeat", "/flaair/sensor_v")


def test_missing_topic_is_named(tmp_path: Path) -> None:
    _write_sensor_blocks(tmp_path / "bag", [0, 10])
    with pytest.raises(
        bagio.BagTopicError,
        match=r"no topic '/flaair/wing_state/truth' in the bag \(it has: "
        r"/flaair/sensor_v\)",
    ):
        bagio.read_blocks(tmp_path / "bag", "/flaair/wing_state/truth")
    with pytest.raises(bagio.BagError, match="no such bag"):
        bagio.read_blocks(tmp_path / "nothing", "/flaair/sensor_v")


def test_unflushed_data_lost_flushed_chunks_recovered_by_reindex(tmp_path: Path) -> None:
    """What a kill -9 leaves: the file as it is on disk, a half-written chunk at its end."""
    store = bagio.typestore()
    writer = bagio.BagWriter(
        tmp_path / "live", store=store, compression=True, chunk_size_bytes=1 << 20
    )
    message = bagio.new_message("std_msgs/msg/String", store, data="x" * 100)
    for k in range(50):
        writer.write_message("/flaair/chatter", k, message)
    writer.flush()  # the first 50 are on disk now
    for k in range(50, 80):
        writer.write_message("/flaair/chatter", k, message)  # still in the open chunk (memory)
    killed = tmp_path / "killed"
    shutil.copytree(tmp_path / "live", killed)
    writer.close()
    mcap_file = next(killed.glob("*.mcap"))
    complete_chunk = (tmp_path / "live" / mcap_file.name).read_bytes()[mcap_file.stat().st_size :]
    with open(mcap_file, "ab") as stream:  # a chunk cut off in the middle of its write
        stream.write(complete_chunk[: len(complete_chunk) // 3])

    with pytest.raises(bagio.BagUnfinishedError, match=f"bin/flaair bag reindex {killed}"):
        bagio.read_blocks(killed, "/flaair/chatter")
    with open(mcap_file, "rb") as stream:  # the mcap library reads it without a summary
        records = []
        # what the library raises at the cut depends on where it falls (struct.error, EndOfFile)
        with pytest.raises(Exception):  # noqa: B017  any error: the cut is not the library's format
            for record in StreamReader(stream).records:
                records.append(record)
    assert sum(type(r).__name__ == "Message" for r in records) == 50

    report = bagio.reindex(killed)
    assert not report.was_complete and report.counts == {"/flaair/chatter": 50}
    with Reader(killed) as reader:
        assert [t for _, t, _ in reader.messages()] == list(range(50))
    assert bagio.message_counts(killed) == {"/flaair/chatter": 50}
    assert bagio.reindex(tmp_path / "live").was_complete
    assert bagio.message_counts(tmp_path / "live") == {"/flaair/chatter": 80}
