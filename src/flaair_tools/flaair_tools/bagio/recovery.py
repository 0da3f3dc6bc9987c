"""Recover a damaged or unfinished bag: `reindex` rebuilds
it (verified first), `check_bag` reports damage.

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

import contextlib
import json
import mmap
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import make_reader
from mcap.records import Channel as McapChannel
from mcap.records import Metadata as McapMetadata
from mcap.records import Schema as McapSchema
from rosbags.rosbag2 import Reader
from rosbags.typesys.store import Typestore

from flaair_tools.bagio.messages import BagError, typestore
from flaair_tools.bagio.qos import qos_from_yaml
from flaair_tools.bagio.scan import RECOVERED_CUSTOM_KEY, ScanLog, ScannedMessage, scan_mcap
from flaair_tools.bagio.writer import BagWriter, storage_settings

__all__ = [
    "ReindexReport",
    "TopicRecovery",
    "check_bag",
    "damage_lines",
    "reindex",
    "single_mcap_file",
]


@dataclass(frozen=True)
class TopicRecovery:
    """One topic after `reindex`: messages kept, expected (None: unknown) and lost."""

    kept: int
    expected: int | None

    @property
    def lost(self) -> int | None:
        """Messages the file once held (by its summary,
        metadata.yaml or message indexes) and lost.
        """
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
        return (
            "a chunk cut off by the end of the file"
            if self.partial_tail
            else "end of file without a footer"
        )


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
        counts = {
            str(t["topic_metadata"]["name"]): int(t["message_count"])
            for t in info["topics_with_message_count"]
        }
        custom = {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}
        return counts, custom
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
        return None, {}


def _decodable(store: Typestore, msgtype: str, data: bytes) -> bool:
    if msgtype not in store.fielddefs:
        return True  # a foreign type: nothing to check it against
    try:
        store.deserialize_cdr(data, msgtype)
    except Exception:
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
        raise BagError(
            f"{bag}: the recovered copy does not read back as written (wrote {wanted}, "
            f"rosbags reads {seen}, mcap reads {mcap_seen}); the original is unchanged"
        )


def _copy_records(
    data: Any,
    log: ScanLog,
    writer: BagWriter,
    store: Any,
    custom: dict[str, str],
    progress: Any,
) -> tuple[dict[int, McapChannel], int]:
    """Every record the scan of `data` finds, written to `writer` where it can be trusted (the
    custom data of an earlier rosbag2 metadata record merged into `custom`); the channels seen
    and the count of messages dropped as unverifiable.
    """
    schemas: dict[int, McapSchema] = {}
    channels: dict[int, McapChannel] = {}
    dropped = 0
    for record in scan_mcap(data, log):
        if progress is not None:
            progress(log.position)
        if isinstance(record, ScannedMessage):
            channel = channels.get(record.channel_id)
            if channel is None or not writer.has_topic(channel.topic):
                dropped += 1
                continue
            if not record.verified and not _decodable(
                store, schemas[channel.schema_id].name, record.data
            ):
                dropped += 1
                continue
            writer.write(channel.topic, record.log_time, record.data, record.publish_time)
        elif isinstance(record, McapSchema):
            schemas[record.id] = record
        elif isinstance(record, McapChannel):
            channels[record.id] = record
            schema = schemas.get(record.schema_id)
            if schema is not None and not writer.has_topic(record.topic):
                writer.add_topic(
                    record.topic,
                    schema.name,
                    qos_from_yaml(record.metadata.get("offered_qos_profiles", "")),
                    msgdef=schema.data.decode(),
                    type_hash=record.metadata.get("topic_type_hash", ""),
                )
        elif isinstance(record, McapMetadata) and record.name == "rosbag2":
            try:
                previous = yaml.safe_load(record.metadata.get("serialized_metadata", "")) or {}
                custom.update(
                    {str(k): str(v) for k, v in (previous.get("custom_data") or {}).items()}
                )
            except (yaml.YAMLError, AttributeError):
                pass
    return channels, dropped


def _damaged_backup(source: Path) -> Path:
    """The original file kept beside the recovered one (`<file>.damaged`, numbered if taken)."""
    backup = source.with_name(source.name + ".damaged")
    number = 1
    while backup.exists():
        backup, number = source.with_name(f"{source.name}.damaged{number}"), number + 1
    os.link(source, backup)
    return backup


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
    try:
        compression, chunk_size = storage_settings()
        writer = BagWriter(
            temporary,
            compression=compression,
            chunk_size_bytes=chunk_size,
            file_name=source.name,
            store=store,
        )
        with _mapped(source) as data:
            channels, unverified_dropped = _copy_records(data, log, writer, store, custom, progress)
        kept = writer.counts
        topics = _recovery_counts(kept, channels, log, expected_from_metadata)
        damage = tuple(damage_lines(log))
        lost_any = log.damaged or any(t.lost for t in topics.values()) or unverified_dropped > 0
        for key, value in custom.items():
            if key != RECOVERED_CUSTOM_KEY:
                writer.set_custom_data(key, value)
        if lost_any:
            writer.set_custom_data(
                RECOVERED_CUSTOM_KEY,
                json.dumps(
                    {
                        "source_file": source.name,
                        "damage": list(damage),
                        "topics": {
                            t: {"kept": r.kept, "expected": r.expected, "lost": r.lost}
                            for t, r in sorted(topics.items())
                        },
                    },
                    allow_nan=False,
                ),
            )
        writer.close()
        _verify_copy(temporary, kept)
        backup = _damaged_backup(source) if lost_any else None
        os.replace(temporary / source.name, source)
        os.replace(temporary / "metadata.yaml", path / "metadata.yaml")
    finally:
        if temporary.exists():
            shutil.rmtree(temporary, ignore_errors=True)
    return ReindexReport(
        path, topics, log.complete, damage, log.partial_tail, backup, unverified_dropped
    )


def _recovery_counts(
    kept: dict[str, int],
    channels: dict[int, McapChannel],
    log: ScanLog,
    from_metadata: dict[str, int] | None,
) -> dict[str, TopicRecovery]:
    """Kept and expected messages per topic: from the summary's statistics, else metadata.yaml,
    else the message indexes (unknown when a chunk without an index was cut off).
    """
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
    """Scan a bag's MCAP file for damage without changing
    it: (scan log, readable messages per channel topic).
    """
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
