"""Bag message types: the typestore (Jazzy + flaair_msgs),
new messages, stamps, bag errors and conventions.

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

import functools
import struct
from importlib.metadata import version as package_version
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from flaair_common.msgdefs import MSG_PACKAGE, MsgDefinitionError, project_types

__all__ = [
    "BAG_VERSION",
    "CONFIG_FILE",
    "HEADER_TYPE",
    "NS_PER_S",
    "ROS_DISTRO",
    "RUNS_CUSTOM_KEY",
    "RUN_MARKER_TOPIC",
    "RUN_MARKER_TYPE",
    "STORAGE_SECTION",
    "TIME_TYPE",
    "WRITER_LIBRARY",
    "BagContinuityError",
    "BagError",
    "BagTopicError",
    "BagUnfinishedError",
    "deserialize",
    "has_leading_stamp",
    "leading_stamp_ns",
    "message_definition",
    "new_message",
    "time_msg",
    "typestore",
]

BAG_VERSION = 9  # rosbag2 metadata version written by ROS 2 Jazzy
ROS_DISTRO = "jazzy"
RUN_MARKER_TOPIC = "/flaair/run_marker"
RUN_MARKER_TYPE = "std_msgs/msg/String"
RUNS_CUSTOM_KEY = "flaair.runs"
# config section holding the storage settings (compression, chunk size)
STORAGE_SECTION = "recorder_node"
CONFIG_FILE = "flaair.yaml"
HEADER_TYPE = "std_msgs/msg/Header"
TIME_TYPE = "builtin_interfaces/msg/Time"
NS_PER_S = 1_000_000_000
WRITER_LIBRARY = (
    f"flaair bagio (mcap {package_version('mcap')}, rosbags {package_version('rosbags')})"
)


class BagError(ValueError):
    """A bag cannot be read or written as asked; the message names the bag (and topic)."""


class BagTopicError(BagError):
    """A needed topic is missing from the bag, or holds an unexpected type."""


class BagContinuityError(BagError):
    """Blocks of a topic skip or repeat samples (first_sample_index discontinuity)."""


class BagUnfinishedError(BagError):
    """The bag has no metadata.yaml: its writer did not
    close it (repair with `bin/flaair bag reindex`).
    """


@functools.cache
def typestore() -> Typestore:
    """Rosbags' ROS 2 Jazzy typestore with flaair_msgs registered from its `.msg` files."""
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
        raise BagTopicError(
            f"message type '{msgtype}' is unknown to the typestore (Jazzy + {MSG_PACKAGE})"
        )
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
        elif (
            node == Nodetype.SEQUENCE
            and detail[0][0] == Nodetype.BASE
            and detail[0][1][0] != "string"
        ):
            kwargs[name] = np.zeros(0, dtype=_numpy_dtype(detail[0][1][0]))
        else:
            kwargs[name] = []
    unknown = set(values) - set(kwargs)
    if unknown:
        raise BagError(f"{msgtype} has no field(s) {', '.join(sorted(unknown))}")
    return cls(**kwargs)


def _numpy_dtype(base: str) -> np.dtype:
    names = {
        "float64": "f8",
        "float32": "f4",
        "bool": "bool",
        "byte": "u1",
        "char": "u1",
        "int8": "i1",
        "uint8": "u1",
        "int16": "i2",
        "uint16": "u2",
        "int32": "i4",
        "uint32": "u4",
        "int64": "i8",
        "uint64": "u8",
    }
    return np.dtype(names[base])


def time_msg(stamp_ns: int, store: Typestore | None = None) -> Any:
    """builtin_interfaces/Time for a time in nanoseconds."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return new_message(TIME_TYPE, store, sec=sec, nanosec=nanosec)


def has_leading_stamp(msgtype: str, store: Typestore | None = None) -> bool:
    """True if the first field of `msgtype` is a std_msgs/Header or a builtin_interfaces/Time."""
    store = store or typestore()
    _, fields = store.fielddefs[msgtype]
    return (
        bool(fields)
        and fields[0][1][0] == Nodetype.NAME
        and fields[0][1][1] in (HEADER_TYPE, TIME_TYPE)
    )


def leading_stamp_ns(data: bytes | memoryview) -> int:
    """Time of the leading Header/Time field of a CDR-serialized message, in nanoseconds.

    The stamp is the first member after the 4-byte encapsulation header in both little- and
    big-endian CDR (int32 sec, uint32 nanosec), so no deserialization is needed.
    """
    if len(data) < 12:
        raise BagError(f"CDR message of {len(data)} bytes is too short to hold a stamp")
    endian = "<" if data[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(endian + "iI", data, 4)
    return sec * NS_PER_S + nanosec


def deserialize(bag: str | Path, store: Typestore, data: bytes, msgtype: str) -> Any:
    """One CDR message, a damaged one reported as a BagError naming the bag."""
    try:
        return store.deserialize_cdr(data, msgtype)
    except Exception as exc:
        raise BagError(f"{bag}: damaged {msgtype} message: {type(exc).__name__}: {exc}") from None
