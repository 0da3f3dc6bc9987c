"""Scan an MCAP file record by record, through cut-off and corrupt chunks (what recovery reads).

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from typing import Any

import lz4.frame as lz4frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel as McapChannel
from mcap.records import MessageIndex, Statistics
from mcap.records import Metadata as McapMetadata
from mcap.records import Schema as McapSchema

from flaair_tools.bagio.messages import BagError

__all__ = ["MCAP_MAGIC", "RECOVERED_CUSTOM_KEY", "ScanLog", "ScannedMessage", "scan_mcap"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
RECOVERED_CUSTOM_KEY = "flaair.recovered"  # custom_data of a reindexed bag that lost messages
_RECORD_HEAD = 9  # opcode (1) + record length (8)
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4  # start, end, uncompressed size, CRC, compression-string length
_COMPRESSIONS = ("", "zstd", "lz4")
_ZSTD_PIECE = 1 << 16  # compressed bytes fed to the streaming decompressor at a time
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
    readers = {
        Opcode.SCHEMA: McapSchema.read,
        Opcode.CHANNEL: McapChannel.read,
        Opcode.METADATA: McapMetadata.read,
        Opcode.STATISTICS: Statistics.read,
        Opcode.MESSAGE_INDEX: MessageIndex.read,
    }
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
            return lz4frame.decompress(bytes(data)), ""
        except Exception as exc:
            return b"", f"lz4: {exc}"
    decompressor = zstandard.ZstdDecompressor().decompressobj()
    parts: list[bytes] = []
    produced = 0
    for start in range(0, len(data), _ZSTD_PIECE):
        try:
            part = decompressor.decompress(bytes(data[start : start + _ZSTD_PIECE]))
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
        body = view[position + _RECORD_HEAD : end]
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
        except Exception:
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
    compression = bytes(data[body : body + comp_len])
    (data_len,) = struct.unpack_from("<Q", data, body + comp_len)
    return (
        compression.decode("ascii", "replace") in _COMPRESSIONS
        and length == _CHUNK_FIXED + comp_len + 8 + data_len
    )


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
    if size < len(MCAP_MAGIC) * 2 + _FOOTER_SIZE or bytes(data[size - 8 : size]) != MCAP_MAGIC:
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
            record = _read_record(opcode, data[position + _RECORD_HEAD : end])
        except Exception:
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
    if size < len(MCAP_MAGIC) or bytes(data[: len(MCAP_MAGIC)]) != MCAP_MAGIC:
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
        if (
            opcode not in _KNOWN_OPCODES
            or end > size
            or (opcode == Opcode.CHUNK and not _plausible_chunk(data, position, size))
        ):
            following = _resync(data, position, size)
            log.skipped_bytes.append((position, following - position))
            position = following
            damaged_chunk = False
            continue
        body = data[position + _RECORD_HEAD : end]
        if opcode == Opcode.CHUNK:
            damaged_chunk = yield from _chunk(data, position, end, log)
        elif opcode == Opcode.MESSAGE_INDEX and damaged_chunk:
            try:
                index = _read_record(opcode, body)
                log.index_counts[index.channel_id] = log.index_counts.get(
                    index.channel_id, 0
                ) + len(index.records)
            except Exception:
                pass
        elif opcode == Opcode.FOOTER:
            log.complete = True
            break
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA, Opcode.MESSAGE):
            try:
                yield (
                    _parse_message(body, True)
                    if opcode == Opcode.MESSAGE
                    else _read_record(opcode, body)
                )
            except Exception:
                log.skipped_bytes.append((position, end - position))
        if opcode != Opcode.MESSAGE_INDEX:
            damaged_chunk = damaged_chunk and opcode == Opcode.CHUNK
        position = end
    log.position = position


def _chunk_head(data: Any, body: int) -> tuple[int, int, int, int, str, int]:
    """Chunk fields from the offset of its body: (start ns, end ns, uncompressed size, CRC,
    compression, offset of the compressed data).
    """
    start_ns, end_ns, usize, crc, comp_len = struct.unpack_from("<QQQII", data, body)
    compression = bytes(data[body + _CHUNK_FIXED : body + _CHUNK_FIXED + comp_len]).decode("ascii")
    return start_ns, end_ns, usize, crc, compression, body + _CHUNK_FIXED + comp_len + 8


def _plausible_chunk_head(data: Any, position: int, size: int) -> bool:
    try:
        head = _chunk_head(data, position + _RECORD_HEAD)
    except (struct.error, UnicodeDecodeError):
        return False
    return head[4] in _COMPRESSIONS and head[5] <= size


def _chunk(data: Any, position: int, end: int, log: ScanLog) -> Generator[Any, None, bool]:
    """The records of the chunk at `position` (ending at `end`, or cut off by the file's end);
    returns True if it was damaged.
    """
    start_ns, end_ns, usize, crc, compression, offset = _chunk_head(data, position + _RECORD_HEAD)
    available = memoryview(data[offset : min(end, len(data))])
    raw, why = _decompress_prefix(compression, available, usize)
    if end > len(data):
        why = f"cut off by the end of the file ({why or 'incomplete'})"
    elif not why and crc and zlib.crc32(raw) != crc:
        why = "CRC mismatch"
    if why:
        log.damaged_chunks.append((position, why))
    yield from _chunk_records(raw, not why, start_ns, end_ns)
    return bool(why)
