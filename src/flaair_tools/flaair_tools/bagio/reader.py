"""Read a bag through rosbags: info, raw and decoded messages, whole block streams, run markers.

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.interfaces import Qos
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from rosbags.typesys.store import Typestore

from flaair_tools.bagio.blocks import Blocks, blocks_from_cdr, select_samples
from flaair_tools.bagio.markers import RunMarker
from flaair_tools.bagio.messages import (
    RUN_MARKER_TOPIC,
    BagError,
    BagTopicError,
    BagUnfinishedError,
    deserialize,
    typestore,
)

__all__ = [
    "BagContents",
    "BagInfo",
    "TopicInfo",
    "bag_info",
    "iter_messages",
    "iter_raw",
    "message_counts",
    "read_bag",
    "read_blocks",
    "read_run_markers",
]


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
                f"{path}: no metadata.yaml (the recorder did not close the "
                f"bag); recover it with: bin/flaair bag reindex {path}"
            )
        raise BagError(f"{path}: not a rosbag2 bag (no metadata.yaml, no .mcap file)")
    try:
        reader = Reader(path)
        reader.open()
    except FileNotFoundError as exc:
        raise BagError(f"{path}: cannot open bag: {exc}") from None
    except ReaderError as exc:
        raise BagError(
            f"{path}: cannot open bag: {exc}; if it is damaged, recover what is left "
            f"with: bin/flaair bag reindex {path}"
        ) from None
    except Exception as exc:
        raise BagError(
            f"{path}: damaged bag, cannot open it: {type(exc).__name__}: {exc}; "
            f"recover what is left with: bin/flaair bag reindex {path}"
        ) from None
    return reader


def _messages(
    bag: str | Path, reader: Reader, connections: Sequence[Any]
) -> Iterator[tuple[Any, int, bytes]]:
    """reader.messages, with any failure to decode the file reported as a damaged bag."""
    try:
        yield from reader.messages(connections=connections)
    except BagError:
        raise
    except Exception as exc:
        raise BagError(
            f"{bag}: damaged bag, cannot read its messages: {type(exc).__name__}: {exc}"
        ) from None


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
    custom = (
        dict(reader.storage.metadata.custom or {}) if hasattr(reader.storage, "metadata") else {}
    )
    return BagInfo(
        Path(bag), topics, reader.start_time, reader.end_time, reader.message_count, custom
    )


def message_counts(bag: str | Path) -> dict[str, int]:
    """Messages per topic, counted by reading every message of the bag."""
    counts: dict[str, int] = {}
    for topic, _, _, _ in iter_raw(bag):
        counts[topic] = counts.get(topic, 0) + 1
    return counts


def iter_raw(
    bag: str | Path, topics: Sequence[str] | None = None
) -> Iterator[tuple[str, str, int, bytes]]:
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


def iter_messages(
    bag: str | Path, topics: Sequence[str] | None = None, store: Typestore | None = None
) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time ns, deserialized message) of
    every message (of `topics`) in log-time order.
    """
    store = store or typestore()
    for topic, msgtype, timestamp, data in iter_raw(bag, topics):
        yield topic, timestamp, deserialize(bag, store, data, msgtype)


def _require_topics(bag: str | Path, reader: Reader, topics: Sequence[str]) -> None:
    present = reader.topics
    missing = [t for t in topics if t not in present]
    if missing:
        raise BagTopicError(
            f"{bag}: no topic {', '.join(repr(t) for t in missing)} in the bag "
            f"(it has: {', '.join(sorted(present)) or 'no topics'})"
        )


@dataclass(frozen=True)
class BagContents:
    """A bag read once: what it holds (`info`) and the CDR
    bytes of the topics asked for, in log-time order.
    """

    info: BagInfo
    raw: dict[str, list[bytes]]

    def has(self, topic: str) -> bool:
        """True if the bag holds `topic` (read or not)."""
        return topic in self.info.topics

    def _data(self, topic: str) -> list[bytes]:
        if topic not in self.info.topics:
            raise BagTopicError(
                f"{self.info.path}: no topic '{topic}' in the bag "
                f"(it has: {', '.join(sorted(self.info.topics)) or 'no topics'})"
            )
        if topic not in self.raw:
            raise BagError(
                f"{self.info.path}: topic '{topic}' was not read (read_bag(..., topics))"
            )
        return self.raw[topic]

    def messages(self, topic: str, store: Typestore | None = None) -> list[Any]:
        """The deserialized messages of `topic` (empty if the bag does not hold it)."""
        if not self.has(topic):
            return []
        store, msgtype = store or typestore(), self.info.topics[topic].msgtype
        return [deserialize(self.info.path, store, data, msgtype) for data in self._data(topic)]

    def blocks(self, topic: str, *, allow_gaps: bool = False) -> Blocks:
        """Every block of `topic`, concatenated per field (see `read_blocks`)."""
        data, msgtype = self._data(topic), self.info.topics[topic].msgtype
        if msgtype not in typestore().fielddefs:
            raise BagTopicError(
                f"{self.info.path}: topic '{topic}' has type {msgtype}, unknown to the typestore"
            )
        return blocks_from_cdr(topic, msgtype, data, allow_gaps=allow_gaps, bag=self.info.path)

    def run_markers(self) -> list[RunMarker]:
        """Run markers, in time order (empty if the bag has none)."""
        return [RunMarker.from_json(message.data) for message in self.messages(RUN_MARKER_TOPIC)]


def read_bag(bag: str | Path, topics: Sequence[str] | None = None) -> BagContents:
    """Open a bag once: its info and the messages
    (CDR bytes) of `topics` it holds (None: every topic).

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


def read_blocks(
    bag: str | Path, topic: str, *, run: str | None = None, allow_gaps: bool = False
) -> Blocks:
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


def read_run_markers(bag: str | Path) -> list[RunMarker]:
    """Run markers of a bag, in time order (empty if it has none)."""
    return read_bag(bag, [RUN_MARKER_TOPIC]).run_markers()
