"""rosbag2 (MCAP) bag I/O for FLAAIR: typestore, writer, block reader, run markers, reindex.

A bag is a rosbag2 directory as ROS 2 Jazzy writes it: `metadata.yaml` (version 9) next to
one MCAP file (`<bag>_0.mcap`, profile `ros2`, `cdr` messages, `ros2msg` schemas, zstd-compressed
chunks, each channel's offered QoS profiles in its metadata as rosbag2 records them).
Types come from rosbags' Jazzy typestore plus this project's `.msg` files. The MCAP file is
written with the `mcap` library (chunk size and flush under our control, so a writer killed
with SIGKILL leaves every flushed chunk readable); `reindex` turns such an unfinished bag back
into a complete one. Reading goes through rosbags.

Bag-level conventions
---------------------
- Block topics (SensorVoltageBlock, DriveCommandBlock, WingStateBlock) are read back whole with
  `read_blocks`: each array field concatenated, `first_sample_index` continuity checked.
- Runs (imported lab CSVs) are marked by std_msgs/String messages on `RUN_MARKER_TOPIC` holding
  JSON `{"run", "first_sample_index", "n_samples", "source_file", ...}`, and listed in the bag's
  `custom_data` under `RUNS_CUSTOM_KEY`.

Recovery: `scan_mcap` reads every record an MCAP file still holds, through cut-off and
corrupt chunks; `reindex` rebuilds a bag from it (verified before it replaces anything) and
`check_bag` reports damage. The command line is `flaair_tools.bag_cli` (`bin/flaair bag`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import mmap
import os
import shutil
import struct
import zlib
from collections.abc import Generator, Iterator, Sequence
from dataclasses import dataclass, field
from importlib.metadata import version as package_version
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel as McapChannel
from mcap.records import MessageIndex, Statistics
from mcap.records import Metadata as McapMetadata
from mcap.records import Schema as McapSchema
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Nodetype, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from flaair_common import cdr
from flaair_common.msgdefs import MSG_PACKAGE, MsgDefinitionError, project_types
from flaair_model.config import ConfigError, node_parameters

BAG_VERSION = 9  # rosbag2 metadata version written by ROS 2 Jazzy
ROS_DISTRO = "jazzy"
RUN_MARKER_TOPIC = "/flaair/run_marker"
RUN_MARKER_TYPE = "std_msgs/msg/String"
RUNS_CUSTOM_KEY = "flaair.runs"
STORAGE_SECTION = "recorder_node"  # config section holding the storage settings (compression, chunk size)
CONFIG_FILE = "flaair.yaml"
HEADER_TYPE = "std_msgs/msg/Header"
TIME_TYPE = "builtin_interfaces/msg/Time"
_NS_PER_S = 1_000_000_000
_LIBRARY = f"flaair bagio (mcap {package_version('mcap')}, rosbags {package_version('rosbags')})"


class BagError(ValueError):
    """A bag cannot be read or written as asked; the message names the bag (and topic)."""


class BagTopicError(BagError):
    """A needed topic is missing from the bag, or holds an unexpected type."""


class BagContinuityError(BagError):
    """Blocks of a topic skip or repeat samples (first_sample_index discontinuity)."""


class BagUnfinishedError(BagError):
    """The bag has no metadata.yaml: its writer did not close it (repair with `bin/flaair bag reindex`)."""


# --------------------------------------------------------------------------------------------
# Types
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def typestore() -> Typestore:
    """rosbags' ROS 2 Jazzy typestore with flaair_msgs registered from its `.msg` files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    try:
        store.register(project_types())
    except MsgDefinitionError as exc:
        raise BagError(str(exc)) from exc
    return store


def message_definition(msgtype: str, store: Typestore | None = None) -> tuple[str, str]:
    """The `ros2msg` definition (with dependencies) and RIHS01 hash of `msgtype`."""
    store = store or typestore()
    if msgtype not in store.fielddefs:
        raise BagTopicError(f"message type '{msgtype}' is unknown to the typestore (Jazzy + {MSG_PACKAGE})")
    text, _ = store.generate_msgdef(msgtype, ros_version=2)
    return text, store.hash_rihs01(msgtype)


def new_message(msgtype: str, store: Typestore | None = None, **values: Any) -> Any:
    """A typestore message of `msgtype` with `values`; every other field zero / empty."""
    store = store or typestore()
    cls = store.types[msgtype]
    _, fields = store.fielddefs[msgtype]
    kwargs: dict[str, Any] = {}
    for name, (node, detail) in fields:
        if name in values:
            kwargs[name] = values[name]
        elif node == Nodetype.NAME:
            kwargs[name] = new_message(detail, store)
        elif node == Nodetype.BASE:
            kwargs[name] = "" if detail[0] == "string" else (False if detail[0] == "bool" else 0)
        elif node == Nodetype.SEQUENCE and detail[0][0] == Nodetype.BASE and detail[0][1][0] != "string":
            kwargs[name] = np.zeros(0, dtype=_numpy_dtype(detail[0][1][0]))
        else:
            kwargs[name] = []
    unknown = set(values) - set(kwargs)
    if unknown:
        raise BagError(f"{msgtype} has no field(s) {', '.join(sorted(unknown))}")
    return cls(**kwargs)


def _numpy_dtype(base: str) -> np.dtype:
    names = {"float64": "f8", "float32": "f4", "bool": "bool", "byte": "u1", "char": "u1",
             "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4",
             "uint32": "u4", "int64": "i8", "uint64": "u8"}
    return np.dtype(names[base])


def time_msg(stamp_ns: int, store: Typestore | None = None) -> Any:
    """builtin_interfaces/Time for a time in nanoseconds."""
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    return new_message(TIME_TYPE, store, sec=sec, nanosec=nanosec)


def has_leading_stamp(msgtype: str, store: Typestore | None = None) -> bool:
    """True if the first field of `msgtype` is a std_msgs/Header or a builtin_interfaces/Time."""
    store = store or typestore()
    _, fields = store.fielddefs[msgtype]
    return bool(fields) and fields[0][1][0] == Nodetype.NAME and fields[0][1][1] in (HEADER_TYPE, TIME_TYPE)


def leading_stamp_ns(data: bytes | memoryview) -> int:
    """Time of the leading Header/Time field of a CDR-serialized message, in nanoseconds.

    The stamp is the first member after the 4-byte encapsulation header in both little- and
    big-endian CDR (int32 sec, uint32 nanosec), so no deserialization is needed.
    """
    if len(data) < 12:
        raise BagError(f"CDR message of {len(data)} bytes is too short to hold a stamp")
    endian = "<" if data[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(endian + "iI", data, 4)
    return sec * _NS_PER_S + nanosec


# --------------------------------------------------------------------------------------------
# QoS
# --------------------------------------------------------------------------------------------
def _qos_time(duration: Any) -> QosTime:
    nanoseconds = int(getattr(duration, "nanoseconds", duration))
    sec, nsec = divmod(nanoseconds, _NS_PER_S)
    return QosTime(sec, nsec)


def qos_from_rclpy(profile: Any) -> Qos:
    """rosbags Qos of an rclpy QoSProfile (duck-typed: rclpy is not imported here)."""
    return Qos(
        QosHistory(int(profile.history)),
        int(profile.depth),
        QosReliability(int(profile.reliability)),
        QosDurability(int(profile.durability)),
        _qos_time(profile.deadline),
        _qos_time(profile.lifespan),
        QosLiveliness(int(profile.liveliness)),
        _qos_time(profile.liveliness_lease_duration),
        bool(profile.avoid_ros_namespace_conventions),
    )


def qos_to_yaml(profiles: Sequence[Qos]) -> str:
    """Offered QoS profiles as the YAML text rosbag2 (Jazzy, v9) stores in MCAP channel metadata."""
    if not profiles:
        return ""
    return yaml.safe_dump(dump_qos_v9(list(profiles)), default_flow_style=False, sort_keys=False).strip()


def qos_from_yaml(text: str) -> list[Qos]:
    """Offered QoS profiles from the YAML text of a channel's metadata (inverse of `qos_to_yaml`)."""
    return parse_qos(text)


# --------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------
def storage_settings() -> tuple[bool, int]:
    """(compression, chunk_size_bytes) for new bags, from config/flaair.yaml's recorder_node section."""
    try:
        values = node_parameters(CONFIG_FILE, STORAGE_SECTION)
        return bool(values["compression"]), int(values["chunk_size_bytes"])
    except (ConfigError, KeyError) as exc:
        raise BagError(f"config/{CONFIG_FILE}: {STORAGE_SECTION}: storage settings missing: {exc}") from exc


@dataclass
class _Topic:
    channel_id: int
    msgtype: str
    type_hash: str
    offered_qos: list[Qos]
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None


class BagWriter:
    """Write a rosbag2 MCAP bag: topics, serialized messages, custom data; `close()` finalizes.

    Parameters
    ----------
    path
        Bag directory to create (must not exist).
    compression, chunk_size_bytes
        zstd chunk compression and chunk size (None: config/flaair.yaml, recorder_node).
    store
        Typestore (default: `typestore()`).
    file_name
        MCAP file name inside the bag (default `<bag name>_0.mcap`, as rosbag2 names it).
    """

    def __init__(self, path: str | Path, *, compression: bool | None = None, chunk_size_bytes: int | None = None,
                 store: Typestore | None = None, file_name: str | None = None) -> None:
        self.path = Path(path)
        if compression is None or chunk_size_bytes is None:
            default_compression, default_chunk = storage_settings()
            compression = default_compression if compression is None else compression
            chunk_size_bytes = default_chunk if chunk_size_bytes is None else chunk_size_bytes
        self.store = store or typestore()
        self.compression = bool(compression)
        try:
            self.path.mkdir(parents=True, exist_ok=False)
        except FileExistsError:
            raise BagError(f"{self.path}: exists already; choose a new bag directory") from None
        except OSError as exc:
            raise BagError(f"{self.path}: cannot create the bag directory: {exc.strerror}") from None
        self.file_path = self.path / (file_name or f"{self.path.name}_0.mcap")
        self._stream = open(self.file_path, "xb")
        self._mcap = McapWriter(
            self._stream, chunk_size=int(chunk_size_bytes),
            compression=CompressionType.ZSTD if self.compression else CompressionType.NONE,
        )
        self._mcap.start(profile="ros2", library=_LIBRARY)
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self.custom_data: dict[str, str] = {}
        self.closed = False

    def add_topic(self, topic: str, msgtype: str, offered_qos: Sequence[Qos] = (), *,
                  msgdef: str | None = None, type_hash: str | None = None) -> None:
        """Register `topic` of `msgtype`; its schema comes from the typestore unless `msgdef` is given."""
        known = self._topics.get(topic)
        if known is not None:
            if known.msgtype != msgtype:
                raise BagTopicError(f"{self.path}: topic '{topic}' is already recorded as {known.msgtype}, not {msgtype}")
            return
        if msgdef is None or type_hash is None:
            generated, generated_hash = message_definition(msgtype, self.store)
            msgdef = generated if msgdef is None else msgdef
            type_hash = generated_hash if type_hash is None else type_hash
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._mcap.register_schema(msgtype, "ros2msg", msgdef.encode())
        metadata = {"offered_qos_profiles": qos_to_yaml(offered_qos), "topic_type_hash": type_hash}
        channel_id = self._mcap.register_channel(topic, "cdr", self._schemas[msgtype], metadata)
        self._topics[topic] = _Topic(channel_id, msgtype, type_hash, list(offered_qos))

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview, publish_time_ns: int | None = None) -> None:
        """Append one CDR-serialized message of a registered topic."""
        entry = self._topics.get(topic)
        if entry is None:
            raise BagTopicError(f"{self.path}: topic '{topic}' was not added before writing")
        timestamp_ns = int(timestamp_ns)
        self._mcap.add_message(entry.channel_id, timestamp_ns, bytes(data),
                               timestamp_ns if publish_time_ns is None else int(publish_time_ns),
                               entry.count & 0xFFFFFFFF)  # MCAP sequence is uint32
        entry.count += 1
        entry.first_ns = timestamp_ns if entry.first_ns is None else min(entry.first_ns, timestamp_ns)
        entry.last_ns = timestamp_ns if entry.last_ns is None else max(entry.last_ns, timestamp_ns)

    def write_message(self, topic: str, timestamp_ns: int, message: Any, offered_qos: Sequence[Qos] = ()) -> None:
        """Serialize a typestore message and append it (registering the topic on first use)."""
        msgtype = message.__msgtype__
        if topic not in self._topics:
            self.add_topic(topic, msgtype, offered_qos)
        self.write(topic, timestamp_ns, self.store.serialize_cdr(message, msgtype))

    def set_custom_data(self, key: str, value: str) -> None:
        """Store a string in the bag metadata's custom_data."""
        if not isinstance(value, str):
            raise BagError(f"custom_data '{key}' must be a string, not {type(value).__name__}")
        self.custom_data[key] = value

    def has_topic(self, topic: str) -> bool:
        """True once `topic` was added."""
        return topic in self._topics

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, by topic."""
        return {topic: entry.count for topic, entry in self._topics.items()}

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS: it survives a kill of this process."""
        self._mcap.flush()

    def close(self) -> None:
        """Finish the MCAP file (summary, indexes, rosbag2 metadata record) and write metadata.yaml."""
        if self.closed:
            return
        self.closed = True
        info = self.metadata()
        text = yaml.safe_dump(info["rosbag2_bagfile_information"], default_flow_style=False, sort_keys=False)
        self._mcap.add_metadata("rosbag2", {"serialized_metadata": text, "ROS_DISTRO": ROS_DISTRO})
        self._mcap.finish()
        self._stream.close()
        temporary = self.path / "metadata.yaml.tmp"
        temporary.write_text(yaml.safe_dump(info, default_flow_style=False, sort_keys=False), encoding="utf-8")
        temporary.replace(self.path / "metadata.yaml")

    def abandon(self) -> None:
        """Give up on the bag: close the file and remove the bag directory this writer created."""
        self.closed = True
        self._stream.close()
        shutil.rmtree(self.path, ignore_errors=True)

    def metadata(self) -> dict[str, Any]:
        """The rosbag2 metadata.yaml document of what was written so far."""
        return bag_metadata(self.file_path.name, self._topics, self.custom_data)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def bag_metadata(file_name: str, topics: dict[str, _Topic], custom_data: dict[str, str]) -> dict[str, Any]:
    """rosbag2 (version 9) metadata.yaml document for one MCAP file with `topics`."""
    firsts = [t.first_ns for t in topics.values() if t.first_ns is not None]
    lasts = [t.last_ns for t in topics.values() if t.last_ns is not None]
    start = min(firsts) if firsts else 0
    duration = (max(lasts) - start) if lasts else 0
    count = sum(t.count for t in topics.values())
    return {"rosbag2_bagfile_information": {
        "version": BAG_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": name, "type": t.msgtype, "serialization_format": "cdr",
                                "offered_qos_profiles": dump_qos_v9(t.offered_qos),
                                "type_description_hash": t.type_hash},
             "message_count": t.count}
            for name, t in topics.items()
        ],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [file_name],
        "files": [{"path": file_name, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": count}],
        "custom_data": dict(custom_data) or None,
        "ros_distro": ROS_DISTRO,
    }}


# --------------------------------------------------------------------------------------------
# Reader
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: type, message count and the QoS its publishers offered."""

    msgtype: str
    count: int
    offered_qos: tuple[Qos, ...]


@dataclass(frozen=True)
class BagInfo:
    """What a bag holds."""

    path: Path
    topics: dict[str, TopicInfo]
    start_ns: int
    end_ns: int
    message_count: int
    custom_data: dict[str, str]


def _open(bag: str | Path) -> Reader:
    path = Path(bag)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if path.is_dir() and not (path / "metadata.yaml").exists():
        if any(path.glob("*.mcap")):
            raise BagUnfinishedError(
                f"{path}: no metadata.yaml (the recorder did not close the bag); recover it with: bin/flaair bag reindex {path}")
        raise BagError(f"{path}: not a rosbag2 bag (no metadata.yaml, no .mcap file)")
    try:
        reader = Reader(path)
        reader.open()
    except FileNotFoundError as exc:
        raise BagError(f"{path}: cannot open bag: {exc}") from None
    except ReaderError as exc:
        raise BagError(f"{path}: cannot open bag: {exc}; if it is damaged, recover what is left with: "
                       f"bin/flaair bag reindex {path}") from None
    except Exception as exc:  # noqa: BLE001 - metadata or summary bytes that do not parse: a damaged bag
        raise BagError(f"{path}: damaged bag, cannot open it: {type(exc).__name__}: {exc}; "
                       f"recover what is left with: bin/flaair bag reindex {path}") from None
    return reader


def _messages(bag: str | Path, reader: Reader, connections: Sequence[Any]) -> Iterator[tuple[Any, int, bytes]]:
    """reader.messages, with any failure to decode the file reported as a damaged bag."""
    try:
        yield from reader.messages(connections=connections)
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - zstd, MCAP framing, struct: the file's content is damaged
        raise BagError(f"{bag}: damaged bag, cannot read its messages: {type(exc).__name__}: {exc}") from None


def bag_info(bag: str | Path) -> BagInfo:
    """Topics (type, count, offered QoS), time span and custom data of a bag."""
    reader = _open(bag)
    try:
        return _info(bag, reader)
    finally:
        reader.close()


def _info(bag: str | Path, reader: Reader) -> BagInfo:
    topics = {}
    for name, info in reader.topics.items():
        qos = info.connections[0].ext.offered_qos_profiles if info.connections else []
        topics[name] = TopicInfo(info.msgtype or "", info.msgcount, tuple(qos))
    custom = dict(reader.storage.metadata.custom or {}) if hasattr(reader.storage, "metadata") else {}
    return BagInfo(Path(bag), topics, reader.start_time, reader.end_time, reader.message_count, custom)


def message_counts(bag: str | Path) -> dict[str, int]:
    """Messages per topic, counted by reading every message of the bag."""
    counts: dict[str, int] = {}
    for topic, _, _, _ in iter_raw(bag):
        counts[topic] = counts.get(topic, 0) + 1
    return counts


def iter_raw(bag: str | Path, topics: Sequence[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log time ns, CDR bytes) of every message (of `topics`) in log-time order."""
    reader = _open(bag)
    try:
        connections = reader.connections
        if topics is not None:
            _require_topics(bag, reader, topics)
            connections = [c for c in connections if c.topic in topics]
            if not connections:
                return  # rosbags reads every topic when given none
        for connection, timestamp, data in _messages(bag, reader, connections):
            yield connection.topic, connection.msgtype, timestamp, data
    finally:
        reader.close()


def iter_messages(bag: str | Path, topics: Sequence[str] | None = None,
                  store: Typestore | None = None) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time ns, deserialized message) of every message (of `topics`) in log-time order."""
    store = store or typestore()
    for topic, msgtype, timestamp, data in iter_raw(bag, topics):
        yield topic, timestamp, _deserialize(bag, store, data, msgtype)


def _deserialize(bag: str | Path, store: Typestore, data: bytes, msgtype: str) -> Any:
    """One CDR message, a damaged one reported as a BagError naming the bag."""
    try:
        return store.deserialize_cdr(data, msgtype)
    except Exception as exc:  # noqa: BLE001 - truncated or scrambled CDR bytes
        raise BagError(f"{bag}: damaged {msgtype} message: {type(exc).__name__}: {exc}") from None


def _require_topics(bag: str | Path, reader: Reader, topics: Sequence[str]) -> None:
    present = reader.topics
    missing = [t for t in topics if t not in present]
    if missing:
        raise BagTopicError(
            f"{bag}: no topic {', '.join(repr(t) for t in missing)} in the bag "
            f"(it has: {', '.join(sorted(present)) or 'no topics'})")


@dataclass(frozen=True)
class Blocks:
    """Every block of one topic, concatenated: per-sample arrays by field name.

    `sample_index` and `time_ns` give each sample's stream index and time (block stamp +
    k / sample_rate_hz); `gaps` lists (expected, found) first_sample_index pairs where the
    stream skipped or repeated samples (empty unless read with allow_gaps=True).
    """

    topic: str
    msgtype: str
    sample_rate_hz: float
    first_sample_index: int
    fields: dict[str, np.ndarray]
    sample_index: np.ndarray
    time_ns: np.ndarray
    block_stamps_ns: np.ndarray
    block_first_index: np.ndarray
    scalars: dict[str, np.ndarray] = field(default_factory=dict)
    gaps: tuple[tuple[int, int], ...] = ()

    def __getitem__(self, name: str) -> np.ndarray:
        return self.fields[name]

    @property
    def n_samples(self) -> int:
        """Samples in all blocks."""
        return int(self.sample_index.size)

    @property
    def time_s(self) -> np.ndarray:
        """Sample times [s] (relative to the bag's time origin)."""
        return self.time_ns * 1e-9


def block_array_fields(msgtype: str, store: Typestore | None = None) -> tuple[list[str], list[str]]:
    """(per-sample array fields, per-block scalar fields) of a block message type."""
    store = store or typestore()
    _, fields = store.fielddefs[msgtype]
    arrays, scalars = [], []
    for name, (node, detail) in fields:
        if node == Nodetype.SEQUENCE and detail[0][0] == Nodetype.BASE:
            arrays.append(name)
        elif node == Nodetype.BASE and name not in ("sample_rate_hz", "first_sample_index"):
            scalars.append(name)
    names = {name for name, _ in fields}
    if not arrays or not {"header", "sample_rate_hz", "first_sample_index"} <= names:
        raise BagTopicError(f"{msgtype} is not a block message (needs header, sample_rate_hz, first_sample_index and arrays)")
    return arrays, scalars


@dataclass(frozen=True)
class _BlockColumns:
    """Block messages in columns (message order): one value per message, arrays concatenated."""

    rate_hz: np.ndarray
    first: np.ndarray
    stamp_ns: np.ndarray
    lengths: np.ndarray
    arrays: dict[str, np.ndarray]
    scalars: dict[str, np.ndarray]
    bad_lengths: tuple[int, dict[str, int]] | None = None  # first message whose arrays differ in length


def _columns_from_messages(messages: Sequence[Any], arrays: list[str], scalars: list[str]) -> _BlockColumns:
    """Deserialized block messages in columns (a message whose arrays differ in length contributes none)."""
    rows: list[dict[str, np.ndarray]] = []
    bad = None
    for number, message in enumerate(messages):
        row = {name: np.asarray(getattr(message, name)) for name in arrays}
        sizes = {name: v.size for name, v in row.items()}
        if len(set(sizes.values())) != 1:
            bad = bad or (number, sizes)
            row = {name: v[:0] for name, v in row.items()}
        rows.append(row)
    return _BlockColumns(
        rate_hz=np.array([float(m.sample_rate_hz) for m in messages], dtype=float),
        first=np.array([int(m.first_sample_index) for m in messages], dtype=np.int64),
        stamp_ns=np.array([m.header.stamp.sec * _NS_PER_S + m.header.stamp.nanosec for m in messages], dtype=np.int64),
        lengths=np.array([next(iter(row.values())).size for row in rows], dtype=np.int64),
        arrays={name: np.concatenate([row[name] for row in rows]) if rows else np.zeros(0) for name in arrays},
        scalars={name: np.asarray([getattr(m, name) for m in messages]) for name in scalars},
        bad_lengths=bad)


def _damaged(bag: str | Path, msgtype: str, exc: Exception) -> BagError:
    return BagError(f"{bag}: damaged {msgtype} message: {type(exc).__name__}: {exc}")


def _decode_by_size(layout: cdr.Layout, datas: Sequence[bytes], bag: str | Path) -> list[tuple[np.ndarray, Any]]:
    """(message numbers, records) per message size (`cdr.decode_batch`), each message that fits no
    fixed layout decoded alone (a dict); a message that is no CDR of its type is a damaged bag."""
    groups, unfit = cdr.decode_batch(layout, datas)
    for number in unfit:
        try:
            message = cdr.decode(layout, datas[number])
        except cdr.CdrError as exc:
            raise _damaged(bag, layout.type_name, exc) from None
        groups.append((np.array([number]), {k: np.asarray(v)[None] for k, v in message.items() if k != "frame_id"}))
    return groups


def _columns_from_cdr(layout: cdr.Layout, datas: Sequence[bytes], bag: str | Path) -> _BlockColumns:
    """CDR bytes of the project's block messages in columns, decoded with numpy (no per-message objects)."""
    sequences = [name for name, kind in layout.fields if kind.endswith("[]")]
    scalars = [(name, kind) for name, kind in layout.fields if not kind.endswith("[]") and name not in ("sample_rate_hz", "first_sample_index")]
    n = len(datas)
    groups = _decode_by_size(layout, datas, bag)
    lengths, bad = np.zeros(n, dtype=np.int64), None
    for numbers, records in groups:
        found = {name: records[name].shape[1] for name in sequences}
        if len(set(found.values())) != 1:     # only a message decoded alone can disagree
            bad = min(bad or (n, found), (int(numbers[0]), found), key=lambda b: b[0])
        else:
            lengths[numbers] = found[sequences[0]]
    starts = np.cumsum(lengths) - lengths
    rate, first, stamp = np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    scalar_out = {name: np.zeros(n, dtype=bool if kind == "bool" else float if kind == "float64" else np.int64) for name, kind in scalars}
    array_out = {name: np.zeros(int(lengths.sum()), dtype=cdr._KINDS[kind][0].newbyteorder("="))
                 for name, kind in layout.fields if kind.endswith("[]")}
    for numbers, records in groups:
        rate[numbers] = records["sample_rate_hz"]
        first[numbers] = records["first_sample_index"].astype(np.int64)
        stamp[numbers] = records["sec"].astype(np.int64) * _NS_PER_S + records["nanosec"].astype(np.int64)
        for name in scalar_out:
            scalar_out[name][numbers] = records[name]
        width = int(lengths[numbers[0]])
        if width:
            where = (starts[numbers][:, None] + np.arange(width)).ravel()
            for name in array_out:
                array_out[name][where] = records[name].ravel()
    return _BlockColumns(rate, first, stamp, lengths, array_out, scalar_out, bad)


def _assemble(topic: str, msgtype: str, columns: _BlockColumns, allow_gaps: bool, bag: str | Path) -> Blocks:
    """Blocks from columns: same sample rate throughout, retransmitted blocks dropped, continuity checked."""
    where = f"{bag}: topic '{topic}'" if bag else f"topic '{topic}'"
    if columns.rate_hz.size == 0:
        raise BagTopicError(f"{where}: no messages")
    rate_hz = float(columns.rate_hz[0])
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise BagError(f"{where}: block 0: sample_rate_hz {rate_hz} is not positive")
    errors: list[tuple[int, int, type, str]] = []   # (message, check order within a message, error, text)
    differs = np.flatnonzero(columns.rate_hz != rate_hz)
    if differs.size:
        errors.append((int(differs[0]), 0, BagError, f"sample_rate_hz {float(columns.rate_hz[differs[0]])} differs from {rate_hz}"))
    if columns.bad_lengths is not None:
        errors.append((columns.bad_lengths[0], 1, BagError, f"array lengths differ: {columns.bad_lengths[1]}"))
    first, lengths = columns.first, columns.lengths
    starts = np.cumsum(lengths) - lengths
    keep = np.ones(first.size, dtype=bool)
    for number in np.flatnonzero((first[1:] == first[:-1]) & (lengths[1:] == lengths[:-1])) + 1:
        now, before = slice(starts[number], starts[number] + lengths[number]), slice(starts[number - 1], starts[number - 1] + lengths[number - 1])
        keep[number] = not all(np.array_equal(v[now], v[before]) for v in columns.arrays.values())
    kept = np.flatnonzero(keep)   # a retransmission (a controller's start-up retry) is the same block again: dropped
    expected = first[kept[:-1]] + lengths[kept[:-1]]
    jumps = np.flatnonzero(first[kept[1:]] != expected)
    if jumps.size and not allow_gaps:
        number, want, got = int(kept[jumps[0] + 1]), int(expected[jumps[0]]), int(first[kept[jumps[0] + 1]])
        kind = f"{got - want} samples missing" if got > want else f"{want - got} samples repeated"
        errors.append((number, 2, BagContinuityError, f"block {number} has first_sample_index {got}, expected {want} ({kind})"))
    if errors:
        number, _, error, text = min(errors)
        raise error(f"{where}: {text}" if error is BagContinuityError else f"{where}: block {number}: {text}")
    gaps = tuple((int(e), int(f)) for e, f in zip(expected[jumps], first[kept[jumps + 1]]))
    sample_keep = np.repeat(keep, lengths)
    lengths_arr, firsts_arr, stamps_arr = lengths[kept], first[kept], columns.stamp_ns[kept]
    offsets = np.arange(int(lengths_arr.sum()), dtype=np.int64) - np.repeat(np.cumsum(lengths_arr) - lengths_arr, lengths_arr)
    sample_index = np.repeat(firsts_arr, lengths_arr) + offsets
    time_ns = np.repeat(stamps_arr, lengths_arr) + np.round(offsets * (_NS_PER_S / rate_hz)).astype(np.int64)
    return Blocks(
        topic=topic, msgtype=msgtype, sample_rate_hz=rate_hz, first_sample_index=int(firsts_arr[0]),
        fields={name: values if keep.all() else values[sample_keep] for name, values in columns.arrays.items()},
        sample_index=sample_index, time_ns=time_ns, block_stamps_ns=stamps_arr, block_first_index=firsts_arr,
        scalars={name: values[kept] for name, values in columns.scalars.items()},
        gaps=gaps,
    )


def assemble_blocks(topic: str, msgtype: str, messages: Sequence[Any], *, allow_gaps: bool = False,
                    bag: str | Path = "", store: Typestore | None = None) -> Blocks:
    """Concatenate deserialized block messages (pure: no file access); see `read_blocks`."""
    arrays, scalars = block_array_fields(msgtype, store)
    return _assemble(topic, msgtype, _columns_from_messages(messages, arrays, scalars), allow_gaps, bag)


def blocks_from_cdr(topic: str, msgtype: str, datas: Sequence[bytes], *, allow_gaps: bool = False,
                    bag: str | Path = "", store: Typestore | None = None) -> Blocks:
    """`assemble_blocks` of CDR bytes: the project's block types decoded with numpy (flaair_common.cdr),
    thousands of messages at once; any other block type through the typestore."""
    arrays, scalars = block_array_fields(msgtype, store)
    layout = cdr.LAYOUTS.get(msgtype)
    if layout is not None and datas and {name for name, kind in layout.fields if kind.endswith("[]")} == set(arrays) \
            and {name for name, kind in layout.fields if not kind.endswith("[]")} >= set(scalars):
        return _assemble(topic, msgtype, _columns_from_cdr(layout, datas, bag), allow_gaps, bag)
    store = store or typestore()
    messages = [_deserialize(bag, store, data, msgtype) for data in datas]
    return _assemble(topic, msgtype, _columns_from_messages(messages, arrays, scalars), allow_gaps, bag)


@dataclass(frozen=True)
class BagContents:
    """A bag read once: what it holds (`info`) and the CDR bytes of the topics asked for, in log-time order."""

    info: BagInfo
    raw: dict[str, list[bytes]]

    def has(self, topic: str) -> bool:
        """True if the bag holds `topic` (read or not)."""
        return topic in self.info.topics

    def _data(self, topic: str) -> list[bytes]:
        if topic not in self.info.topics:
            raise BagTopicError(f"{self.info.path}: no topic '{topic}' in the bag "
                                f"(it has: {', '.join(sorted(self.info.topics)) or 'no topics'})")
        if topic not in self.raw:
            raise BagError(f"{self.info.path}: topic '{topic}' was not read (read_bag(..., topics))")
        return self.raw[topic]

    def messages(self, topic: str, store: Typestore | None = None) -> list[Any]:
        """The deserialized messages of `topic` (empty if the bag does not hold it)."""
        if not self.has(topic):
            return []
        store, msgtype = store or typestore(), self.info.topics[topic].msgtype
        return [_deserialize(self.info.path, store, data, msgtype) for data in self._data(topic)]

    def blocks(self, topic: str, *, allow_gaps: bool = False) -> Blocks:
        """Every block of `topic`, concatenated per field (see `read_blocks`)."""
        data, msgtype = self._data(topic), self.info.topics[topic].msgtype
        if msgtype not in typestore().fielddefs:
            raise BagTopicError(f"{self.info.path}: topic '{topic}' has type {msgtype}, unknown to the typestore")
        return blocks_from_cdr(topic, msgtype, data, allow_gaps=allow_gaps, bag=self.info.path)

    def run_markers(self) -> list[RunMarker]:
        """Run markers, in time order (empty if the bag has none)."""
        return [RunMarker.from_json(message.data) for message in self.messages(RUN_MARKER_TOPIC)]


def read_bag(bag: str | Path, topics: Sequence[str] | None = None) -> BagContents:
    """Open a bag once: its info and the messages (CDR bytes) of `topics` it holds (None: every topic).

    Topics the bag lacks are skipped (ask `BagContents.has`); reading one of them from the
    contents raises BagTopicError naming the bag's topics.
    """
    reader = _open(bag)
    try:
        info = _info(bag, reader)
        wanted = [t for t in (info.topics if topics is None else topics) if t in info.topics]
        raw: dict[str, list[bytes]] = {topic: [] for topic in wanted}
        connections = [c for c in reader.connections if c.topic in raw]
        if connections:
            for connection, _, data in _messages(bag, reader, connections):
                raw[connection.topic].append(data)
        return BagContents(info, raw)
    finally:
        reader.close()


def read_blocks(bag: str | Path, topic: str, *, run: str | None = None, allow_gaps: bool = False) -> Blocks:
    """Read every block message of `topic`, concatenated per field.

    Parameters
    ----------
    bag
        Bag directory.
    topic
        A topic of SensorVoltageBlock, DriveCommandBlock or WingStateBlock (any block type).
    run
        Keep only the samples of this run (see `read_run_markers`).
    allow_gaps
        False: a first_sample_index discontinuity raises BagContinuityError. True: the gap is
        kept (never filled) and listed in `Blocks.gaps`.

    Raises
    ------
    BagTopicError
        The topic is not in the bag (the message names it and lists the bag's topics).
    BagContinuityError
        Samples skipped or repeated between blocks.
    """
    contents = read_bag(bag, [topic, RUN_MARKER_TOPIC] if run is not None else [topic])
    blocks = contents.blocks(topic, allow_gaps=allow_gaps)
    if run is None:
        return blocks
    markers = {m.run: m for m in contents.run_markers()}
    if run not in markers:
        raise BagError(f"{bag}: no run '{run}' (runs: {', '.join(markers) or 'none marked'})")
    return select_samples(blocks, markers[run].first_sample_index, markers[run].n_samples)


def select_samples(blocks: Blocks, first_sample_index: int, n_samples: int) -> Blocks:
    """The samples of `blocks` with first_sample_index <= index < first_sample_index + n_samples."""
    keep = (blocks.sample_index >= first_sample_index) & (blocks.sample_index < first_sample_index + n_samples)
    block_keep = (blocks.block_first_index >= first_sample_index) & (blocks.block_first_index < first_sample_index + n_samples)
    return dataclasses.replace(
        blocks,
        first_sample_index=int(blocks.sample_index[keep][0]) if keep.any() else first_sample_index,
        fields={name: values[keep] for name, values in blocks.fields.items()},
        sample_index=blocks.sample_index[keep], time_ns=blocks.time_ns[keep],
        block_stamps_ns=blocks.block_stamps_ns[block_keep], block_first_index=blocks.block_first_index[block_keep],
        scalars={name: values[block_keep] for name, values in blocks.scalars.items()},
        gaps=tuple(g for g in blocks.gaps if first_sample_index <= g[1] < first_sample_index + n_samples),
    )


# --------------------------------------------------------------------------------------------
# Run markers
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunMarker:
    """One run in a bag: its name, sample range in the block streams, source file and start time."""

    run: str
    first_sample_index: int
    n_samples: int
    source_file: str
    sample_rate_hz: float
    start_ns: int

    def to_json(self) -> str:
        """The marker as the JSON text carried by a std_msgs/String."""
        return json.dumps(dataclasses.asdict(self))

    @classmethod
    def from_json(cls, text: str) -> RunMarker:
        """Parse a marker's JSON text; the message names a missing or bad key."""
        try:
            values = json.loads(text)
            return cls(run=str(values["run"]), first_sample_index=int(values["first_sample_index"]),
                       n_samples=int(values["n_samples"]), source_file=str(values.get("source_file", "")),
                       sample_rate_hz=float(values.get("sample_rate_hz", "nan")), start_ns=int(values.get("start_ns", 0)))
        except (ValueError, KeyError, TypeError) as exc:
            raise BagError(f"bad run marker {text!r}: {exc!r}") from None


def read_run_markers(bag: str | Path) -> list[RunMarker]:
    """Run markers of a bag, in time order (empty if it has none)."""
    return read_bag(bag, [RUN_MARKER_TOPIC]).run_markers()


# --------------------------------------------------------------------------------------------
# Recovery: scan a damaged or unfinished MCAP file record by record, rebuild the bag (reindex)
# --------------------------------------------------------------------------------------------
MCAP_MAGIC = b"\x89MCAP0\r\n"
RECOVERED_CUSTOM_KEY = "flaair.recovered"  # custom_data of a reindexed bag that lost messages
_RECORD_HEAD = 9          # opcode (1) + record length (8)
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4  # start, end, uncompressed size, CRC, compression-string length
_COMPRESSIONS = ("", "zstd", "lz4")
_ZSTD_PIECE = 1 << 16     # compressed bytes fed to the streaming decompressor at a time
_FOOTER_SIZE = _RECORD_HEAD + 20
_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)


@dataclass
class ScanLog:
    """What a scan of an MCAP file found besides its records (filled in by `scan_mcap`).

    damaged_chunks: (file offset, reason) of every chunk that failed to decompress or its CRC.
    skipped_bytes: (file offset, length) of regions that held no readable record (resynchronised).
    index_counts: messages per channel that the message indexes of damaged chunks list.
    partial_tail: the file ends inside a chunk (its message index was never written).
    statistics: per-channel counts from the summary's Statistics record (None: no usable summary).
    """

    size: int = 0
    complete: bool = False
    damaged_chunks: list[tuple[int, str]] = field(default_factory=list)
    skipped_bytes: list[tuple[int, int]] = field(default_factory=list)
    index_counts: dict[int, int] = field(default_factory=dict)
    partial_tail: bool = False
    statistics: dict[int, int] | None = None
    position: int = 0

    @property
    def damaged(self) -> bool:
        """True if any chunk or region could not be read in full."""
        return bool(self.damaged_chunks or self.skipped_bytes or self.partial_tail)


@dataclass(frozen=True)
class ScannedMessage:
    """A message record found by `scan_mcap`; `verified` is False if its chunk failed its CRC."""

    channel_id: int
    log_time: int
    publish_time: int
    data: bytes
    verified: bool


def _read_record(opcode: int, body: bytes | memoryview) -> Any:
    """One non-chunk record through the mcap library's own parsers (None: not needed here)."""
    readers = {Opcode.SCHEMA: McapSchema.read, Opcode.CHANNEL: McapChannel.read, Opcode.METADATA: McapMetadata.read,
               Opcode.STATISTICS: Statistics.read, Opcode.MESSAGE_INDEX: MessageIndex.read}
    reader = readers.get(opcode)
    return None if reader is None else reader(ReadDataStream(BytesIO(bytes(body))))


def _parse_message(body: memoryview, verified: bool) -> ScannedMessage:
    channel_id, _sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
    return ScannedMessage(channel_id, log_time, publish_time, bytes(body[22:]), verified)


def _decompress_prefix(compression: str, data: memoryview, size: int) -> tuple[bytes, str]:
    """Decompress as much of a chunk's data as decodes: (bytes, '' or why it stopped early).

    zstd goes through the streaming decompressor so that a chunk cut off (or corrupted) part
    way still yields every block before the cut.
    """
    if compression == "":
        return bytes(data[:size]), "" if len(data) >= size else "cut short"
    if compression == "lz4":
        try:
            import lz4.frame as lz4frame
        except ImportError:
            return b"", "lz4 compression (python lz4 not installed)"
        try:
            return lz4frame.decompress(bytes(data)), ""
        except Exception as exc:  # noqa: BLE001 - any lz4 failure: the chunk is damaged
            return b"", f"lz4: {exc}"
    import zstandard

    decompressor = zstandard.ZstdDecompressor().decompressobj()
    parts: list[bytes] = []
    produced = 0
    for start in range(0, len(data), _ZSTD_PIECE):
        try:
            part = decompressor.decompress(bytes(data[start:start + _ZSTD_PIECE]))
        except zstandard.ZstdError as exc:
            return b"".join(parts), f"zstd: {exc}"
        parts.append(part)
        produced += len(part)
        if produced > size:
            return b"".join(parts)[:size], "decompresses to more than its declared size"
    out = b"".join(parts)
    return out, "" if len(out) == size else f"stream ends after {len(out)} of {size} bytes"


def _chunk_records(raw: bytes, verified: bool, start_ns: int, end_ns: int) -> Iterator[Any]:
    """Whole records of decompressed chunk data; stops at the first one that does not parse."""
    view = memoryview(raw)
    position = 0
    while position + _RECORD_HEAD <= len(view):
        opcode = view[position]
        (length,) = struct.unpack_from("<Q", view, position + 1)
        end = position + _RECORD_HEAD + length
        if opcode not in _KNOWN_OPCODES or end > len(view):
            return
        body = view[position + _RECORD_HEAD:end]
        try:
            if opcode == Opcode.MESSAGE:
                message = _parse_message(body, verified)
                if not verified and not start_ns <= message.log_time <= end_ns:
                    return  # decoded garbage past a corruption: stop trusting this chunk
                yield message
            else:
                record = _read_record(opcode, body)
                if record is not None:
                    yield record
        except Exception:  # noqa: BLE001 - a record that does not parse ends the readable part
            return
        position = end


def _plausible_chunk(data: Any, position: int, size: int) -> bool:
    """True if a self-consistent chunk record starts at `position` (used to resynchronise)."""
    if position + _RECORD_HEAD + _CHUNK_FIXED > size or data[position] != Opcode.CHUNK:
        return False
    (length,) = struct.unpack_from("<Q", data, position + 1)
    comp_len = struct.unpack_from("<I", data, position + _RECORD_HEAD + _CHUNK_FIXED - 4)[0]
    if comp_len > 8 or position + _RECORD_HEAD + _CHUNK_FIXED + comp_len + 8 > size:
        return False
    body = position + _RECORD_HEAD + _CHUNK_FIXED
    compression = bytes(data[body:body + comp_len])
    (data_len,) = struct.unpack_from("<Q", data, body + comp_len)
    return (compression.decode("ascii", "replace") in _COMPRESSIONS
            and length == _CHUNK_FIXED + comp_len + 8 + data_len)


def _resync(data: Any, position: int, size: int) -> int:
    """The next offset after `position` where a chunk record plausibly starts (else `size`)."""
    candidate = position
    while True:
        candidate = data.find(b"\x06", candidate + 1)
        if candidate < 0:
            return size
        if _plausible_chunk(data, candidate, size):
            return candidate


def _summary_statistics(data: Any, size: int, log: ScanLog) -> Iterator[Any]:
    """Schemas and channels of an intact summary section; sets log.statistics."""
    if size < len(MCAP_MAGIC) * 2 + _FOOTER_SIZE or bytes(data[size - 8:size]) != MCAP_MAGIC:
        return
    footer = size - 8 - _FOOTER_SIZE
    if data[footer] != Opcode.FOOTER:
        return
    summary_start, _, _ = struct.unpack_from("<QQI", data, footer + _RECORD_HEAD)
    if not 8 <= summary_start < footer:
        return
    position = summary_start
    found: list[Any] = []
    while position + _RECORD_HEAD <= footer:
        opcode = data[position]
        (length,) = struct.unpack_from("<Q", data, position + 1)
        end = position + _RECORD_HEAD + length
        if opcode not in _KNOWN_OPCODES or end > footer:
            return  # a damaged summary: trust none of it
        try:
            record = _read_record(opcode, data[position + _RECORD_HEAD:end])
        except Exception:  # noqa: BLE001
            return
        if record is not None:
            found.append(record)
        position = end
    for record in found:
        if isinstance(record, Statistics):
            log.statistics = dict(record.channel_message_counts)
        elif isinstance(record, (McapSchema, McapChannel)):
            yield record


def scan_mcap(data: bytes | memoryview | Any, log: ScanLog | None = None) -> Iterator[Any]:
    """Every readable record of an MCAP file's bytes, in file order, surviving damage.

    Yields Schema, Channel and Metadata records and `ScannedMessage`s. A chunk is decompressed
    (zstd as a stream) and checked against its CRC; a chunk that fails yields the whole records
    before the failure (unverified), a chunk cut off by the end of the file yields what its
    available bytes decode to, and a region that holds no record is skipped up to the next
    plausible chunk. `log` (a `ScanLog`) receives what was damaged or lost.

    Raises
    ------
    BagError
        The bytes do not start with the MCAP magic.
    """
    log = log if log is not None else ScanLog()
    size = len(data)
    log.size = size
    if size < len(MCAP_MAGIC) or bytes(data[:len(MCAP_MAGIC)]) != MCAP_MAGIC:
        raise BagError("not an MCAP file (no MCAP magic at its start)")
    yield from _summary_statistics(data, size, log)
    position = len(MCAP_MAGIC)
    damaged_chunk = False
    while position < size:
        log.position = position
        if position + _RECORD_HEAD > size:
            log.partial_tail = True
            break
        opcode = data[position]
        (length,) = struct.unpack_from("<Q", data, position + 1)
        end = position + _RECORD_HEAD + length
        if opcode == Opcode.CHUNK and end > size and _plausible_chunk_head(data, position, size):
            yield from _chunk(data, position, end, log)
            log.partial_tail = True
            break
        if opcode not in _KNOWN_OPCODES or end > size or (opcode == Opcode.CHUNK and not _plausible_chunk(data, position, size)):
            following = _resync(data, position, size)
            log.skipped_bytes.append((position, following - position))
            position = following
            damaged_chunk = False
            continue
        body = data[position + _RECORD_HEAD:end]
        if opcode == Opcode.CHUNK:
            damaged_chunk = yield from _chunk(data, position, end, log)
        elif opcode == Opcode.MESSAGE_INDEX and damaged_chunk:
            try:
                index = _read_record(opcode, body)
                log.index_counts[index.channel_id] = log.index_counts.get(index.channel_id, 0) + len(index.records)
            except Exception:  # noqa: BLE001 - a damaged index counts nothing
                pass
        elif opcode == Opcode.FOOTER:
            log.complete = True
            break
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA, Opcode.MESSAGE):
            try:
                yield _parse_message(body, True) if opcode == Opcode.MESSAGE else _read_record(opcode, body)
            except Exception:  # noqa: BLE001 - a damaged record outside chunks
                log.skipped_bytes.append((position, end - position))
        if opcode != Opcode.MESSAGE_INDEX:
            damaged_chunk = damaged_chunk and opcode == Opcode.CHUNK
        position = end
    log.position = position


def _chunk_head(data: Any, body: int) -> tuple[int, int, int, int, str, int]:
    """Chunk fields from the offset of its body: (start ns, end ns, uncompressed size, CRC,
    compression, offset of the compressed data)."""
    start_ns, end_ns, usize, crc, comp_len = struct.unpack_from("<QQQII", data, body)
    compression = bytes(data[body + _CHUNK_FIXED:body + _CHUNK_FIXED + comp_len]).decode("ascii")
    return start_ns, end_ns, usize, crc, compression, body + _CHUNK_FIXED + comp_len + 8


def _plausible_chunk_head(data: Any, position: int, size: int) -> bool:
    try:
        head = _chunk_head(data, position + _RECORD_HEAD)
    except (struct.error, UnicodeDecodeError):
        return False
    return head[4] in _COMPRESSIONS and head[5] <= size


def _chunk(data: Any, position: int, end: int, log: ScanLog) -> Generator[Any, None, bool]:
    """The records of the chunk at `position` (ending at `end`, or cut off by the file's end);
    returns True if it was damaged."""
    start_ns, end_ns, usize, crc, compression, offset = _chunk_head(data, position + _RECORD_HEAD)
    available = memoryview(data[offset:min(end, len(data))])
    raw, why = _decompress_prefix(compression, available, usize)
    if end > len(data):
        why = f"cut off by the end of the file ({why or 'incomplete'})"
    elif not why and crc and zlib.crc32(raw) != crc:
        why = "CRC mismatch"
    if why:
        log.damaged_chunks.append((position, why))
    yield from _chunk_records(raw, not why, start_ns, end_ns)
    return bool(why)


@dataclass(frozen=True)
class TopicRecovery:
    """One topic after `reindex`: messages kept, expected (None: unknown) and lost."""

    kept: int
    expected: int | None

    @property
    def lost(self) -> int | None:
        """Messages the file once held (by its summary, metadata.yaml or message indexes) and lost."""
        return None if self.expected is None else max(0, self.expected - self.kept)


@dataclass(frozen=True)
class ReindexReport:
    """Outcome of `reindex`.

    topics: kept/expected per topic. was_complete: the file had its footer. damage: one line
    per damaged chunk or skipped region. backup: where the damaged original was kept (None if
    nothing was lost and it was replaced). partial_tail: the file ended inside a chunk (what
    that chunk held beyond the cut was never on disk and cannot be counted).
    """

    path: Path
    topics: dict[str, TopicRecovery]
    was_complete: bool
    damage: tuple[str, ...]
    partial_tail: bool
    backup: Path | None
    unverified_dropped: int = 0

    @property
    def counts(self) -> dict[str, int]:
        """Messages kept per topic."""
        return {topic: t.kept for topic, t in self.topics.items()}

    @property
    def lost(self) -> int:
        """Messages known to be lost (unknown counts excluded)."""
        return sum(t.lost or 0 for t in self.topics.values())

    @property
    def stopped_at(self) -> str:
        """How the scan ended, in words."""
        if self.was_complete:
            return "footer (complete file)"
        return "a chunk cut off by the end of the file" if self.partial_tail else "end of file without a footer"


def single_mcap_file(path: Path) -> Path:
    files = sorted(path.glob("*.mcap")) if path.is_dir() else []
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if len(files) != 1:
        raise BagError(f"{path}: expected one .mcap file in the bag directory, found {len(files)}")
    return files[0]


def _metadata_counts(path: Path) -> tuple[dict[str, int] | None, dict[str, str]]:
    """(message count per topic, custom_data) of the bag's metadata.yaml, if it reads."""
    try:
        document = yaml.safe_load((path / "metadata.yaml").read_text(encoding="utf-8"))
        info = document["rosbag2_bagfile_information"]
        counts = {str(t["topic_metadata"]["name"]): int(t["message_count"]) for t in info["topics_with_message_count"]}
        custom = {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}
        return counts, custom
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
        return None, {}


def _decodable(store: Typestore, msgtype: str, data: bytes) -> bool:
    if msgtype not in store.fielddefs:
        return True  # a foreign type: nothing to check it against
    try:
        store.deserialize_cdr(data, msgtype)
    except Exception:  # noqa: BLE001 - garbage decoded past a corruption
        return False
    return True


def _verify_copy(bag: Path, expected: dict[str, int]) -> None:
    """Read a rebuilt bag with rosbags and with the mcap library; both must count `expected`."""
    with Reader(bag) as reader:
        seen: dict[str, int] = {}
        for connection, _, _ in reader.messages():
            seen[connection.topic] = seen.get(connection.topic, 0) + 1
    mcap_seen: dict[str, int] = {}
    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as stream:
        for _, channel, _ in make_reader(stream, validate_crcs=True).iter_messages():
            mcap_seen[channel.topic] = mcap_seen.get(channel.topic, 0) + 1
    wanted = {t: n for t, n in expected.items() if n}
    if seen != wanted or mcap_seen != wanted:
        raise BagError(f"{bag}: the recovered copy does not read back as written "
                       f"(wrote {wanted}, rosbags reads {seen}, mcap reads {mcap_seen}); the original is unchanged")


def reindex(bag: str | Path, progress: Any = None) -> ReindexReport:
    """Rebuild a bag's MCAP summary and metadata.yaml from whatever its MCAP file still holds.

    Every message that can be decoded is kept: complete chunks, the readable part of a chunk
    cut off by the end of the file (a recorder killed mid-write, a copy cut short), and the
    readable part of a corrupt chunk; a region holding no record is skipped up to the next
    chunk. Messages from a chunk that failed its CRC are kept only if their channel is known,
    their time lies in the chunk's range and they deserialize.

    The recovered copy is written to `<bag>/.reindex/`, read back with rosbags and with the mcap
    library, and only then moved over the original. If anything was lost or damaged the
    original file is kept beside it as `<file>.damaged`. The temporary directory never
    outlives the call.

    Parameters
    ----------
    bag
        Bag directory holding one .mcap file.
    progress
        Called with the file offset reached (bytes), for a progress bar; None: silent.
    """
    path = Path(bag)
    source = single_mcap_file(path)
    expected_from_metadata, custom = _metadata_counts(path)
    temporary = path / ".reindex"
    if temporary.exists():
        shutil.rmtree(temporary)
    store = typestore()
    log = ScanLog()
    schemas: dict[int, McapSchema] = {}
    channels: dict[int, McapChannel] = {}
    unverified_dropped = 0
    try:
        compression, chunk_size = storage_settings()
        writer = BagWriter(temporary, compression=compression, chunk_size_bytes=chunk_size, file_name=source.name,
                           store=store)
        with _mapped(source) as data:
            for record in scan_mcap(data, log):
                if progress is not None:
                    progress(log.position)
                if isinstance(record, ScannedMessage):
                    channel = channels.get(record.channel_id)
                    if channel is None or not writer.has_topic(channel.topic):
                        unverified_dropped += 1
                        continue
                    if not record.verified and not _decodable(store, schemas[channel.schema_id].name, record.data):
                        unverified_dropped += 1
                        continue
                    writer.write(channel.topic, record.log_time, record.data, record.publish_time)
                elif isinstance(record, McapSchema):
                    schemas[record.id] = record
                elif isinstance(record, McapChannel):
                    channels[record.id] = record
                    schema = schemas.get(record.schema_id)
                    if schema is not None and not writer.has_topic(record.topic):
                        writer.add_topic(record.topic, schema.name,
                                         qos_from_yaml(record.metadata.get("offered_qos_profiles", "")),
                                         msgdef=schema.data.decode(), type_hash=record.metadata.get("topic_type_hash", ""))
                elif isinstance(record, McapMetadata) and record.name == "rosbag2":
                    try:
                        previous = yaml.safe_load(record.metadata.get("serialized_metadata", "")) or {}
                        custom.update({str(k): str(v) for k, v in (previous.get("custom_data") or {}).items()})
                    except (yaml.YAMLError, AttributeError):
                        pass
        kept = writer.counts
        topics = _recovery_counts(kept, channels, log, expected_from_metadata)
        damage = tuple(damage_lines(log))
        lost_any = log.damaged or any(t.lost for t in topics.values()) or unverified_dropped > 0
        for key, value in custom.items():
            if key != RECOVERED_CUSTOM_KEY:
                writer.set_custom_data(key, value)
        if lost_any:
            writer.set_custom_data(RECOVERED_CUSTOM_KEY, json.dumps({
                "source_file": source.name, "damage": list(damage),
                "topics": {t: {"kept": r.kept, "expected": r.expected, "lost": r.lost} for t, r in sorted(topics.items())},
            }, allow_nan=False))
        writer.close()
        _verify_copy(temporary, kept)
        backup = None
        if lost_any:
            backup = source.with_name(source.name + ".damaged")
            number = 1
            while backup.exists():
                backup, number = source.with_name(f"{source.name}.damaged{number}"), number + 1
            os.link(source, backup)
        os.replace(temporary / source.name, source)
        os.replace(temporary / "metadata.yaml", path / "metadata.yaml")
    finally:
        if temporary.exists():
            shutil.rmtree(temporary, ignore_errors=True)
    return ReindexReport(path, topics, log.complete, damage, log.partial_tail, backup, unverified_dropped)


def _recovery_counts(kept: dict[str, int], channels: dict[int, McapChannel], log: ScanLog,
                     from_metadata: dict[str, int] | None) -> dict[str, TopicRecovery]:
    """Kept and expected messages per topic: from the summary's statistics, else metadata.yaml,
    else the message indexes (unknown when a chunk without an index was cut off)."""
    topic_of = {cid: channel.topic for cid, channel in channels.items()}
    names = set(kept) | set(topic_of.values())
    if log.statistics is not None:
        expected: dict[str, int | None] = {t: 0 for t in names}
        for cid, count in log.statistics.items():
            if cid in topic_of:
                expected[topic_of[cid]] = (expected.get(topic_of[cid]) or 0) + count
    elif from_metadata is not None:
        names |= set(from_metadata)
        expected = {t: from_metadata.get(t) for t in names}
    else:
        expected = {}
        for topic in names:
            indexed = sum(n for cid, n in log.index_counts.items() if topic_of.get(cid) == topic)
            expected[topic] = None if log.partial_tail else kept.get(topic, 0) + indexed
            if log.partial_tail and indexed:
                expected[topic] = None
    return {t: TopicRecovery(kept.get(t, 0), expected.get(t)) for t in sorted(names)}


def damage_lines(log: ScanLog) -> Iterator[str]:
    for offset, why in log.damaged_chunks:
        yield f"chunk at byte {offset}: {why}"
    for offset, length in log.skipped_bytes:
        yield f"bytes {offset}-{offset + length}: no readable record, skipped"


def check_bag(bag: str | Path) -> tuple[ScanLog, dict[str, int]]:
    """Scan a bag's MCAP file for damage without changing it: (scan log, readable messages per channel topic)."""
    source = single_mcap_file(Path(bag))
    log = ScanLog()
    counts: dict[str, int] = {}
    channels: dict[int, str] = {}
    with _mapped(source) as data:
        for record in scan_mcap(data, log):
            if isinstance(record, McapChannel):
                channels[record.id] = record.topic
            elif isinstance(record, ScannedMessage) and record.channel_id in channels:
                topic = channels[record.channel_id]
                counts[topic] = counts.get(topic, 0) + 1
    return log, counts


@contextlib.contextmanager
def _mapped(path: Path) -> Iterator[Any]:
    """A file's bytes, memory-mapped (an empty file: b"")."""
    with open(path, "rb") as stream:
        try:
            data: Any = mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:  # an empty file cannot be mapped
            yield b""
            return
        try:
            yield data
        finally:
            data.close()
