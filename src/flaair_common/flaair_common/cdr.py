"""CDR (little-endian, XCDR1) encoding and decoding of the block messages with numpy.

Why: at 2000 blocks/s per stream, rclpy's conversion of a message to and from a Python object
costs about as much as the transport (bench/bench_closed_loop.py: a raw ping-pong takes half
the CPU of a typed one). The hot nodes therefore subscribe with ``raw=True`` and publish bytes,
and this module turns those bytes into numpy views and back. The layout of each message is
derived from its .msg definition, the field definitions the bag typestore registers too
(`flaair_common.msgdefs`, parsed by rosbags on first use), and tested byte-for-byte against
rclpy's own serialization (tests/test_cdr.py).

Layout rules (OMG CDR as Fast DDS writes it for ROS 2): a 4-byte encapsulation header
(00 01 00 00, CDR little-endian), then every primitive aligned to its own size (at most 8)
counted from the end of that header; a sequence is a uint32 count followed by its elements;
a string is a uint32 length including the terminating NUL, then the bytes and the NUL.
An empty sequence is not padded to its element's alignment. Padding bytes are written as
zeros here; Fast DDS leaves them uninitialised and, for messages with empty sequences, appends
a few unused bytes (its size estimate pads them), so equal messages need not be equal bytes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
from rosbags.interfaces import Nodetype

from flaair_common import msgdefs
from flaair_common.msgdefs import MsgDefinitionError

ENCAPSULATION = b"\x00\x01\x00\x00"

# Field kinds: name -> (numpy dtype of one element, is a sequence)
KINDS: dict[str, tuple[np.dtype, bool]] = {
    "float64": (np.dtype("<f8"), False),
    "uint64": (np.dtype("<u8"), False),
    "uint8": (np.dtype("u1"), False),
    "bool": (np.dtype("?"), False),
    "float64[]": (np.dtype("<f8"), True),
    "bool[]": (np.dtype("?"), True),
}


class CdrError(ValueError):
    """Bytes that are not a CDR encoding of the expected message."""


@dataclass(frozen=True)
class Layout:
    """One message type: a std_msgs/Header first (``stamp_ns``, ``frame_id``), then `fields`.

    fields: (name, kind) in .msg order; kind is one of float64, uint64, uint8, bool,
    float64[], bool[], string.
    """

    type_name: str
    fields: tuple[tuple[str, str], ...]

    def __post_init__(self) -> None:
        for name, kind in self.fields:
            if kind not in KINDS and kind != "string":
                raise ValueError(f"{self.type_name}.{name}: unsupported CDR kind {kind!r}")


def _pad(offset: int, size: int) -> int:
    return (-offset) % size


def encode(layout: Layout, stamp_ns: int, frame_id: str, values: dict) -> bytes:
    """Serialize one message: header stamp (ns) and frame_id, then `values` by field name.

    Sequences take any array-like (converted to the field's dtype); missing fields are zero or
    empty.
    """
    out = bytearray(ENCAPSULATION)
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    frame = frame_id.encode() + b"\x00"
    out += struct.pack("<iII", sec, nanosec, len(frame)) + frame
    for name, kind in layout.fields:
        value = values.get(name)
        body = len(out) - 4
        if kind == "string":
            text = ("" if value is None else str(value)).encode() + b"\x00"
            out += b"\x00" * _pad(body, 4) + struct.pack("<I", len(text)) + text
            continue
        dtype, sequence = KINDS[kind]
        if sequence:
            array = np.ascontiguousarray(() if value is None else value, dtype=dtype)
            out += b"\x00" * _pad(body, 4) + struct.pack("<I", array.size)
            if array.size:
                out += b"\x00" * _pad(len(out) - 4, dtype.itemsize) + array.tobytes()
        else:
            out += (
                b"\x00" * _pad(body, dtype.itemsize)
                + np.array(0 if value is None else value, dtype=dtype).tobytes()
            )
    return bytes(out)


def decode(layout: Layout, data: bytes | memoryview) -> dict:
    """Deserialize one message into a dict: ``stamp_ns``, ``frame_id`` and every field.

    Sequences are read-only numpy views into `data` (no copy); scalars are Python numbers.

    Raises
    ------
    CdrError
        Wrong encapsulation, or the bytes end before the layout does.
    """
    buffer = memoryview(data)
    if bytes(buffer[:4]) != ENCAPSULATION:
        raise CdrError(
            f"{layout.type_name}: not little-endian CDR (encapsulation {bytes(buffer[:4]).hex()})"
        )
    try:
        sec, nanosec, frame_len = struct.unpack_from("<iII", buffer, 4)
        offset = 16
        frame_id = bytes(buffer[offset : offset + frame_len - 1]).decode()
        offset += frame_len
        out: dict = {
            "stamp_ns": sec * 1_000_000_000 + nanosec,
            "sec": sec,
            "nanosec": nanosec,
            "frame_id": frame_id,
        }
        for name, kind in layout.fields:
            if kind == "string":
                offset += _pad(offset - 4, 4)
                (length,) = struct.unpack_from("<I", buffer, offset)
                offset += 4
                out[name] = bytes(buffer[offset : offset + length - 1]).decode()
                offset += length
                continue
            dtype, sequence = KINDS[kind]
            if sequence:
                offset += _pad(offset - 4, 4)
                (count,) = struct.unpack_from("<I", buffer, offset)
                offset += 4
                if count:  # an empty sequence is not padded to its element alignment
                    offset += _pad(offset - 4, dtype.itemsize)
                end = offset + count * dtype.itemsize
                if end > len(buffer):
                    raise CdrError(
                        f"{layout.type_name}.{name}: {count} elements run past the end "
                        f"({len(buffer)} bytes)"
                    )
                out[name] = np.frombuffer(buffer, dtype=dtype, count=count, offset=offset)
                offset = end
            else:
                offset += _pad(offset - 4, dtype.itemsize)
                out[name] = np.frombuffer(buffer, dtype=dtype, count=1, offset=offset)[0].item()
                offset += dtype.itemsize
    except (struct.error, UnicodeDecodeError, ValueError) as exc:
        if isinstance(exc, CdrError):
            raise
        raise CdrError(f"{layout.type_name}: malformed CDR ({exc})") from exc
    return out


def stamp_ns(decoded) -> int:
    """Header stamp in ns of a decoded message (record
    fields are int32/uint32: no overflow here).
    """
    return int(decoded["sec"]) * 1_000_000_000 + int(decoded["nanosec"])


class FixedCodec:
    """Encode/decode one layout at a fixed block size and frame_id with a numpy structured dtype.

    The hot path of a block stream: every message has the same sizes, so the whole message is
    one record of a structured dtype with constant offsets (one ``frombuffer`` to decode, one
    ``tobytes`` to encode, a few microseconds instead of tens). Messages of another size are
    handed to the general `decode`.
    """

    def __init__(self, layout: Layout, block_size: int, frame_id: str = "") -> None:
        self.layout, self.block_size, self.frame_id = layout, block_size, frame_id
        frame = frame_id.encode() + b"\x00"
        names: list[str] = ["encapsulation", "sec", "nanosec", "frame_len", "frame"]
        formats: list = [("u1", (4,)), "<i4", "<u4", "<u4", ("S1", (len(frame),))]
        offsets: list[int] = [0, 4, 8, 12, 16]
        offset = 16 + len(frame)
        self.counts: list[str] = []
        for name, kind in layout.fields:
            if kind == "string":
                raise ValueError(f"{layout.type_name}.{name}: a string field has no fixed size")
            dtype, sequence = KINDS[kind]
            if sequence:
                offset += _pad(offset - 4, 4)
                names.append(f"{name}__count"), formats.append("<u4"), offsets.append(offset)
                self.counts.append(f"{name}__count")
                offset += 4
                if block_size:
                    offset += _pad(offset - 4, dtype.itemsize)
                names.append(name), formats.append((dtype, (block_size,))), offsets.append(offset)
                offset += dtype.itemsize * block_size
            else:
                offset += _pad(offset - 4, dtype.itemsize)
                names.append(name), formats.append(dtype), offsets.append(offset)
                offset += dtype.itemsize
        self.dtype = np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": offset}
        )
        # A record over zeroed bytes holding the constant parts (encapsulation, frame, counts):
        # encode() fills the rest in place. (A structured array's copy() would leave the padding
        # uninitialised, hence a view on a bytearray.)
        self._record = np.frombuffer(bytearray(offset), dtype=self.dtype)
        self._record["encapsulation"] = np.frombuffer(ENCAPSULATION, dtype="u1")
        self._record["frame_len"] = len(frame)
        self._record["frame"] = np.frombuffer(frame, dtype="S1")
        for count in self.counts:
            self._record[count] = block_size
        self.fields = [name for name, _ in layout.fields]
        self._frame_len = len(frame)

    def encode(self, stamp_ns: int, values: dict) -> bytes:
        """Serialize one message of exactly `block_size` samples per sequence field."""
        record = self._record
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        record["sec"], record["nanosec"] = sec, nanosec
        for name in self.fields:
            record[name] = values.get(name, 0)
        return record.tobytes()

    def decode(self, data: bytes | memoryview):
        """As `decode`, indexable by field name and ``sec``/``nanosec``: a read-only record of the
        fixed layout when the message fits it (no copy), else the general decoder's dict.
        """
        if len(data) >= self.dtype.itemsize:
            record = np.frombuffer(data, dtype=self.dtype, count=1)[0]
            if (
                record["frame_len"] == self._frame_len
                and data[:4] == ENCAPSULATION
                and all(record[count] == self.block_size for count in self.counts)
            ):
                return record
        return decode(self.layout, data)


class GeneralCodec:
    """`FixedCodec`'s encode/decode for a layout with
    strings or variable sizes (the general path).
    """

    def __init__(self, layout: Layout, frame_id: str = "") -> None:
        self.layout, self.frame_id = layout, frame_id

    def encode(self, stamp_ns: int, values: dict) -> bytes:
        return encode(self.layout, stamp_ns, self.frame_id, values)

    def decode(self, data: bytes | memoryview) -> dict:
        return decode(self.layout, data)


def encode_fields(layout: Layout, fields, codecs: dict) -> tuple[int, bytes]:
    """(stamp ns, CDR bytes) of a block handed over in-process (fields by name with sec, nanosec,
    frame_id), as its DDS message would be; `codecs` caches a FixedCodec per (block size, frame_id).
    """
    stamp_ns = int(fields["sec"]) * 1_000_000_000 + int(fields["nanosec"])
    lengths = {len(fields[name]) for name, kind in layout.fields if kind.endswith("[]")}
    if len(lengths) != 1:
        return stamp_ns, encode(layout, stamp_ns, fields["frame_id"], fields)
    key = (lengths.pop(), fields["frame_id"])
    codec = codecs.get(key) or codecs.setdefault(key, FixedCodec(layout, *key))
    return stamp_ns, codec.encode(stamp_ns, fields)


def layout_of(type_name: str) -> Layout:
    """The layout of a flaair_msgs type from its .msg definition (std_msgs/Header first).

    Raises
    ------
    ValueError
        The type is unknown, does not start with a header, or has a field this codec lacks.
    """
    types = msgdefs.project_types()  # read through the module: a test swaps it
    if type_name not in types:
        raise MsgDefinitionError(
            f"{type_name}: not a flaair_msgs type (known: {', '.join(sorted(types))})"
        )
    _, fields = types[type_name]
    if not fields or fields[0][1] != (Nodetype.NAME, "std_msgs/msg/Header"):
        raise MsgDefinitionError(
            f"{type_name}: the CDR codec needs a std_msgs/Header as the first field"
        )
    kinds: list[tuple[str, str]] = []
    for name, (node, detail) in fields[1:]:
        if node == Nodetype.BASE:
            kinds.append((name, detail[0]))
        elif node == Nodetype.SEQUENCE and detail[0][0] == Nodetype.BASE and detail[1] == 0:
            kinds.append((name, f"{detail[0][1][0]}[]"))
        else:
            raise MsgDefinitionError(
                f"{type_name}.{name}: unsupported field type for the CDR codec"
            )
    return Layout(type_name, tuple(kinds))


# The block streams' layouts, derived on first use (module attributes, PEP 562).
_LAYOUT_TYPES = {
    "SENSOR_VOLTAGE_BLOCK": "flaair_msgs/msg/SensorVoltageBlock",
    "WING_STATE_BLOCK": "flaair_msgs/msg/WingStateBlock",
    "DRIVE_COMMAND_BLOCK": "flaair_msgs/msg/DriveCommandBlock",
    "CONTROLLER_STATE": "flaair_msgs/msg/ControllerState",
    "HEALTH_STATUS": "flaair_msgs/msg/HealthStatus",
}


def __getattr__(name: str):
    if name in _LAYOUT_TYPES:
        value = globals()[name] = layout_of(_LAYOUT_TYPES[name])
        return value
    if name == "LAYOUTS":
        value = globals()[name] = {t: __getattr__(n) for n, t in _LAYOUT_TYPES.items()}
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def decode_batch(
    layout: Layout, datas, codecs: dict | None = None
) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[int]]:
    """Many messages of one block layout decoded at
    once: one structured-array view per message size.

    Returns ([(message numbers, records of the fixed layout)] by first arrival of each size,
    numbers of the messages that fit no fixed layout: decode those one by one with `decode`).
    A size's layout comes from its first message (block size, frame_id), stretched to the
    message size (DDS pads to 4 bytes); `codecs` caches it by size across calls.
    """
    codecs = {} if codecs is None else codecs
    sizes = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
    groups, unfit = [], []
    unique, first_seen = np.unique(sizes, return_index=True)
    for size in unique[np.argsort(first_seen)].tolist():  # the sizes in order of arrival
        numbers = np.flatnonzero(sizes == size)
        if size not in codecs:
            codecs[size] = _sized_dtype(layout, datas[numbers[0]])
        if codecs[size] is None:
            unfit += numbers.tolist()
            continue
        codec, dtype = codecs[size]
        records = np.frombuffer(b"".join([datas[i] for i in numbers]), dtype=dtype)
        fits = np.all(records["encapsulation"] == np.frombuffer(ENCAPSULATION, dtype="u1"), axis=1)
        fits &= records["frame_len"] == codec._frame_len
        for count in codec.counts:
            fits &= records[count] == codec.block_size
        unfit += numbers[~fits].tolist()
        if fits.any():
            groups.append((numbers[fits], records[fits]))
    return groups, sorted(unfit)


def _sized_dtype(layout: Layout, data: bytes) -> tuple[FixedCodec, np.dtype] | None:
    try:
        first = decode(layout, data)
    except CdrError:
        return None
    sequences = [name for name, kind in layout.fields if kind.endswith("[]")]
    codec = FixedCodec(layout, len(first[sequences[0]]) if sequences else 0, first["frame_id"])
    if codec.dtype.itemsize > len(data):
        return None
    names = codec.dtype.names
    return codec, np.dtype(
        {
            "names": names,
            "formats": [codec.dtype.fields[n][0] for n in names],
            "offsets": [codec.dtype.fields[n][1] for n in names],
            "itemsize": len(data),
        }
    )
