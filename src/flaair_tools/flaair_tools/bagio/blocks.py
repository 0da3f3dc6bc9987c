"""Block streams: a topic's block messages joined into whole arrays, continuity checked.

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

from flaair_common import cdr
from flaair_tools.bagio.messages import (
    NS_PER_S,
    BagContinuityError,
    BagError,
    BagTopicError,
    deserialize,
    typestore,
)

__all__ = ["Blocks", "assemble_blocks", "block_array_fields", "blocks_from_cdr", "select_samples"]


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
        raise BagTopicError(
            f"{msgtype} is not a block message (needs header, sample_rate_hz, "
            "first_sample_index and arrays)"
        )
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
    # first message whose arrays differ in length
    bad_lengths: tuple[int, dict[str, int]] | None = None


def _columns_from_messages(
    messages: Sequence[Any], arrays: list[str], scalars: list[str]
) -> _BlockColumns:
    """Deserialized block messages in columns (a message
    whose arrays differ in length contributes none).
    """
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
        stamp_ns=np.array(
            [m.header.stamp.sec * NS_PER_S + m.header.stamp.nanosec for m in messages],
            dtype=np.int64,
        ),
        lengths=np.array([next(iter(row.values())).size for row in rows], dtype=np.int64),
        arrays={
            name: np.concatenate([row[name] for row in rows]) if rows else np.zeros(0)
            for name in arrays
        },
        scalars={name: np.asarray([getattr(m, name) for m in messages]) for name in scalars},
        bad_lengths=bad,
    )


def _damaged(bag: str | Path, msgtype: str, exc: Exception) -> BagError:
    return BagError(f"{bag}: damaged {msgtype} message: {type(exc).__name__}: {exc}")


def _decode_by_size(
    layout: cdr.Layout, datas: Sequence[bytes], bag: str | Path
) -> list[tuple[np.ndarray, Any]]:
    """(message numbers, records) per message size (`cdr.decode_batch`), each message that fits no
    fixed layout decoded alone (a dict); a message that is no CDR of its type is a damaged bag.
    """
    groups, unfit = cdr.decode_batch(layout, datas)
    for number in unfit:
        try:
            message = cdr.decode(layout, datas[number])
        except cdr.CdrError as exc:
            raise _damaged(bag, layout.type_name, exc) from None
        groups.append(
            (
                np.array([number]),
                {k: np.asarray(v)[None] for k, v in message.items() if k != "frame_id"},
            )
        )
    return groups


def _columns_from_cdr(layout: cdr.Layout, datas: Sequence[bytes], bag: str | Path) -> _BlockColumns:
    """CDR bytes of the project's block messages in columns,
    decoded with numpy (no per-message objects).
    """
    sequences = [name for name, kind in layout.fields if kind.endswith("[]")]
    scalars = [
        (name, kind)
        for name, kind in layout.fields
        if not kind.endswith("[]") and name not in ("sample_rate_hz", "first_sample_index")
    ]
    n = len(datas)
    groups = _decode_by_size(layout, datas, bag)
    lengths, bad = np.zeros(n, dtype=np.int64), None
    for numbers, records in groups:
        found = {name: records[name].shape[1] for name in sequences}
        if len(set(found.values())) != 1:  # only a message decoded alone can disagree
            bad = min(bad or (n, found), (int(numbers[0]), found), key=lambda b: b[0])
        else:
            lengths[numbers] = found[sequences[0]]
    starts = np.cumsum(lengths) - lengths
    rate, first, stamp = np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    scalar_out = {
        name: np.zeros(
            n, dtype=bool if kind == "bool" else float if kind == "float64" else np.int64
        )
        for name, kind in scalars
    }
    array_out = {
        name: np.zeros(int(lengths.sum()), dtype=cdr.KINDS[kind][0].newbyteorder("="))
        for name, kind in layout.fields
        if kind.endswith("[]")
    }
    for numbers, records in groups:
        rate[numbers] = records["sample_rate_hz"]
        first[numbers] = records["first_sample_index"].astype(np.int64)
        stamp[numbers] = records["sec"].astype(np.int64) * NS_PER_S + records["nanosec"].astype(
            np.int64
        )
        for name in scalar_out:
            scalar_out[name][numbers] = records[name]
        width = int(lengths[numbers[0]])
        if width:
            where = (starts[numbers][:, None] + np.arange(width)).ravel()
            for name in array_out:
                array_out[name][where] = records[name].ravel()
    return _BlockColumns(rate, first, stamp, lengths, array_out, scalar_out, bad)


def _assemble(
    topic: str, msgtype: str, columns: _BlockColumns, allow_gaps: bool, bag: str | Path
) -> Blocks:
    """Blocks from columns: same sample rate throughout,
    retransmitted blocks dropped, continuity checked.
    """
    where = f"{bag}: topic '{topic}'" if bag else f"topic '{topic}'"
    if columns.rate_hz.size == 0:
        raise BagTopicError(f"{where}: no messages")
    rate_hz = float(columns.rate_hz[0])
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise BagError(f"{where}: block 0: sample_rate_hz {rate_hz} is not positive")
    # (message, check order within a message, error, text)
    errors: list[tuple[int, int, type, str]] = []
    differs = np.flatnonzero(columns.rate_hz != rate_hz)
    if differs.size:
        errors.append(
            (
                int(differs[0]),
                0,
                BagError,
                f"sample_rate_hz {float(columns.rate_hz[differs[0]])} differs from {rate_hz}",
            )
        )
    if columns.bad_lengths is not None:
        errors.append(
            (columns.bad_lengths[0], 1, BagError, f"array lengths differ: {columns.bad_lengths[1]}")
        )
    first, lengths = columns.first, columns.lengths
    starts = np.cumsum(lengths) - lengths
    keep = np.ones(first.size, dtype=bool)
    for number in np.flatnonzero((first[1:] == first[:-1]) & (lengths[1:] == lengths[:-1])) + 1:
        now, before = (
            slice(starts[number], starts[number] + lengths[number]),
            slice(starts[number - 1], starts[number - 1] + lengths[number - 1]),
        )
        keep[number] = not all(np.array_equal(v[now], v[before]) for v in columns.arrays.values())
    # a retransmission (a controller's start-up retry) is the same block again: dropped
    kept = np.flatnonzero(keep)
    expected = first[kept[:-1]] + lengths[kept[:-1]]
    jumps = np.flatnonzero(first[kept[1:]] != expected)
    if jumps.size and not allow_gaps:
        number, want, got = (
            int(kept[jumps[0] + 1]),
            int(expected[jumps[0]]),
            int(first[kept[jumps[0] + 1]]),
        )
        kind = f"{got - want} samples missing" if got > want else f"{want - got} samples repeated"
        errors.append(
            (
                number,
                2,
                BagContinuityError,
                f"block {number} has first_sample_index {got}, expected {want} ({kind})",
            )
        )
    if errors:
        number, _, error, text = min(errors)
        raise error(
            f"{where}: {text}"
            if error is BagContinuityError
            else f"{where}: block {number}: {text}"
        )
    gaps = tuple(
        (int(e), int(f)) for e, f in zip(expected[jumps], first[kept[jumps + 1]], strict=True)
    )
    sample_keep = np.repeat(keep, lengths)
    lengths_arr, firsts_arr, stamps_arr = lengths[kept], first[kept], columns.stamp_ns[kept]
    offsets = np.arange(int(lengths_arr.sum()), dtype=np.int64) - np.repeat(
        np.cumsum(lengths_arr) - lengths_arr, lengths_arr
    )
    sample_index = np.repeat(firsts_arr, lengths_arr) + offsets
    time_ns = np.repeat(stamps_arr, lengths_arr) + np.round(offsets * (NS_PER_S / rate_hz)).astype(
        np.int64
    )
    return Blocks(
        topic=topic,
        msgtype=msgtype,
        sample_rate_hz=rate_hz,
        first_sample_index=int(firsts_arr[0]),
        fields={
            name: values if keep.all() else values[sample_keep]
            for name, values in columns.arrays.items()
        },
        sample_index=sample_index,
        time_ns=time_ns,
        block_stamps_ns=stamps_arr,
        block_first_index=firsts_arr,
        scalars={name: values[kept] for name, values in columns.scalars.items()},
        gaps=gaps,
    )


def assemble_blocks(
    topic: str,
    msgtype: str,
    messages: Sequence[Any],
    *,
    allow_gaps: bool = False,
    bag: str | Path = "",
    store: Typestore | None = None,
) -> Blocks:
    """Concatenate deserialized block messages (pure: no file access); see `read_blocks`."""
    arrays, scalars = block_array_fields(msgtype, store)
    return _assemble(
        topic, msgtype, _columns_from_messages(messages, arrays, scalars), allow_gaps, bag
    )


def blocks_from_cdr(
    topic: str,
    msgtype: str,
    datas: Sequence[bytes],
    *,
    allow_gaps: bool = False,
    bag: str | Path = "",
    store: Typestore | None = None,
) -> Blocks:
    """`assemble_blocks` of CDR bytes: the project's block types
    decoded with numpy (flaair_common.cdr), thousands of messages
    at once; any other block type through the typestore.
    """
    arrays, scalars = block_array_fields(msgtype, store)
    layout = cdr.LAYOUTS.get(msgtype)
    if (
        layout is not None
        and datas
        and {name for name, kind in layout.fields if kind.endswith("[]")} == set(arrays)
        and {name for name, kind in layout.fields if not kind.endswith("[]")} >= set(scalars)
    ):
        return _assemble(topic, msgtype, _columns_from_cdr(layout, datas, bag), allow_gaps, bag)
    store = store or typestore()
    messages = [deserialize(bag, store, data, msgtype) for data in datas]
    return _assemble(
        topic, msgtype, _columns_from_messages(messages, arrays, scalars), allow_gaps, bag
    )


def select_samples(blocks: Blocks, first_sample_index: int, n_samples: int) -> Blocks:
    """The samples of `blocks` with first_sample_index <= index < first_sample_index + n_samples."""
    keep = (blocks.sample_index >= first_sample_index) & (
        blocks.sample_index < first_sample_index + n_samples
    )
    block_keep = (blocks.block_first_index >= first_sample_index) & (
        blocks.block_first_index < first_sample_index + n_samples
    )
    return dataclasses.replace(
        blocks,
        first_sample_index=int(blocks.sample_index[keep][0]) if keep.any() else first_sample_index,
        fields={name: values[keep] for name, values in blocks.fields.items()},
        sample_index=blocks.sample_index[keep],
        time_ns=blocks.time_ns[keep],
        block_stamps_ns=blocks.block_stamps_ns[block_keep],
        block_first_index=blocks.block_first_index[block_keep],
        scalars={name: values[block_keep] for name, values in blocks.scalars.items()},
        gaps=tuple(
            g for g in blocks.gaps if first_sample_index <= g[1] < first_sample_index + n_samples
        ),
    )
