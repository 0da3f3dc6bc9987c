"""Write a rosbag2 (MCAP) bag: chunked, flushed, killable (every flushed chunk stays readable).

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys.store import Typestore

from flaair_model.config import ConfigError, node_parameters
from flaair_tools.bagio.messages import (
    BAG_VERSION,
    CONFIG_FILE,
    ROS_DISTRO,
    STORAGE_SECTION,
    WRITER_LIBRARY,
    BagError,
    BagTopicError,
    message_definition,
    typestore,
)
from flaair_tools.bagio.qos import qos_to_yaml

__all__ = ["BagWriter", "bag_metadata", "storage_settings"]


def storage_settings() -> tuple[bool, int]:
    """(compression, chunk_size_bytes) for new bags,
    from config/flaair.yaml's recorder_node section.
    """
    try:
        values = node_parameters(CONFIG_FILE, STORAGE_SECTION)
        return bool(values["compression"]), int(values["chunk_size_bytes"])
    except (ConfigError, KeyError) as exc:
        raise BagError(
            f"config/{CONFIG_FILE}: {STORAGE_SECTION}: storage settings missing: {exc}"
        ) from exc


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

    def __init__(
        self,
        path: str | Path,
        *,
        compression: bool | None = None,
        chunk_size_bytes: int | None = None,
        store: Typestore | None = None,
        file_name: str | None = None,
    ) -> None:
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
            raise BagError(
                f"{self.path}: cannot create the bag directory: {exc.strerror}"
            ) from None
        self.file_path = self.path / (file_name or f"{self.path.name}_0.mcap")
        self._stream = open(self.file_path, "xb")  # noqa: SIM115  open until close(): the bag's life
        self._mcap = McapWriter(
            self._stream,
            chunk_size=int(chunk_size_bytes),
            compression=CompressionType.ZSTD if self.compression else CompressionType.NONE,
        )
        self._mcap.start(profile="ros2", library=WRITER_LIBRARY)
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self.custom_data: dict[str, str] = {}
        self.closed = False

    def add_topic(
        self,
        topic: str,
        msgtype: str,
        offered_qos: Sequence[Qos] = (),
        *,
        msgdef: str | None = None,
        type_hash: str | None = None,
    ) -> None:
        """Register `topic` of `msgtype`; its schema comes
        from the typestore unless `msgdef` is given.
        """
        known = self._topics.get(topic)
        if known is not None:
            if known.msgtype != msgtype:
                raise BagTopicError(
                    f"{self.path}: topic '{topic}' is already recorded as "
                    f"{known.msgtype}, not {msgtype}"
                )
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

    def write(
        self,
        topic: str,
        timestamp_ns: int,
        data: bytes | memoryview,
        publish_time_ns: int | None = None,
    ) -> None:
        """Append one CDR-serialized message of a registered topic."""
        entry = self._topics.get(topic)
        if entry is None:
            raise BagTopicError(f"{self.path}: topic '{topic}' was not added before writing")
        timestamp_ns = int(timestamp_ns)
        self._mcap.add_message(
            entry.channel_id,
            timestamp_ns,
            bytes(data),
            timestamp_ns if publish_time_ns is None else int(publish_time_ns),
            entry.count & 0xFFFFFFFF,
        )  # MCAP sequence is uint32
        entry.count += 1
        entry.first_ns = (
            timestamp_ns if entry.first_ns is None else min(entry.first_ns, timestamp_ns)
        )
        entry.last_ns = timestamp_ns if entry.last_ns is None else max(entry.last_ns, timestamp_ns)

    def write_message(
        self, topic: str, timestamp_ns: int, message: Any, offered_qos: Sequence[Qos] = ()
    ) -> None:
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
        """Close the open chunk and hand everything to
        the OS: it survives a kill of this process.
        """
        self._mcap.flush()

    def close(self) -> None:
        """Finish the MCAP file (summary, indexes, rosbag2
        metadata record) and write metadata.yaml.
        """
        if self.closed:
            return
        self.closed = True
        info = self.metadata()
        text = yaml.safe_dump(
            info["rosbag2_bagfile_information"], default_flow_style=False, sort_keys=False
        )
        self._mcap.add_metadata("rosbag2", {"serialized_metadata": text, "ROS_DISTRO": ROS_DISTRO})
        self._mcap.finish()
        self._stream.close()
        temporary = self.path / "metadata.yaml.tmp"
        temporary.write_text(
            yaml.safe_dump(info, default_flow_style=False, sort_keys=False), encoding="utf-8"
        )
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


def bag_metadata(
    file_name: str, topics: dict[str, _Topic], custom_data: dict[str, str]
) -> dict[str, Any]:
    """rosbag2 (version 9) metadata.yaml document for one MCAP file with `topics`."""
    firsts = [t.first_ns for t in topics.values() if t.first_ns is not None]
    lasts = [t.last_ns for t in topics.values() if t.last_ns is not None]
    start = min(firsts) if firsts else 0
    duration = (max(lasts) - start) if lasts else 0
    count = sum(t.count for t in topics.values())
    return {
        "rosbag2_bagfile_information": {
            "version": BAG_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": name,
                        "type": t.msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": dump_qos_v9(t.offered_qos),
                        "type_description_hash": t.type_hash,
                    },
                    "message_count": t.count,
                }
                for name, t in topics.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [file_name],
            "files": [
                {
                    "path": file_name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
            ],
            "custom_data": dict(custom_data) or None,
            "ros_distro": ROS_DISTRO,
        }
    }
