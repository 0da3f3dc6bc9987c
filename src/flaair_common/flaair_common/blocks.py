"""Block messages <-> numpy arrays, and validation of incoming blocks.

20 kHz data travels in blocks; a block's header stamp is its first sample's time.
Array fields of rclpy messages are array.array('d'); moving through the buffer protocol
avoids a per-sample Python loop in both directions.
"""
from __future__ import annotations

import array
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time


def to_array(field: object) -> np.ndarray:
    """Copy a float64[] message field to a float64 numpy array."""
    if isinstance(field, array.array):
        return np.frombuffer(field, dtype=np.float64).copy()
    return np.asarray(field, dtype=np.float64)


def from_array(values: np.ndarray) -> array.array:
    """A float64[] message field holding `values`."""
    return array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


def bools_to_field(values: np.ndarray) -> list[bool]:
    """A bool[] message field holding `values`."""
    return np.asarray(values, dtype=bool).tolist()


def stamp_ns_of_sample(index: int, sample_rate_hz: float) -> int:
    """Header stamp (ns) of the block starting at sample `index`: its first sample's time."""
    return int(round(index / sample_rate_hz * 1e9))


def stamp_from_time_s(time_s: float) -> Time:
    """builtin_interfaces/Time for a time in seconds (sim or wall time)."""
    nanoseconds = int(round(time_s * 1e9))
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def time_s_from_stamp(stamp: Time) -> float:
    """Seconds of a builtin_interfaces/Time."""
    return stamp.sec + stamp.nanosec * 1e-9


@dataclass(frozen=True)
class BlockCheck:
    """Outcome of checking one incoming block.

    kind is "ok", "content" (bad values, length or rate: the block's time slot is used but its
    data refused), "stale" (duplicate or out of order: ignore it entirely) or "gap" (blocks
    were lost before this one; the block itself is fine).
    """

    ok: bool
    reason: str = ""
    kind: str = "ok"


def check_block(
    arrays: dict[str, np.ndarray],
    sample_rate_hz: float,
    expected_rate_hz: float,
    first_sample_index: int,
    expected_index: int | None,
    expected_length: int | None = None,
) -> BlockCheck:
    """Check a block before it reaches a core: finite values, lengths, rate and order.

    Parameters
    ----------
    arrays
        The block's sample arrays by field name.
    sample_rate_hz, expected_rate_hz
        Rate the block claims and the rate the node runs at.
    first_sample_index, expected_index
        Index the block claims and the one that continues the stream (None: first block).
    expected_length
        Required samples per block (None: any length, all arrays equal).

    Returns
    -------
    BlockCheck
        `ok` False with a reason naming the field, index or rate that is wrong.
    """
    if expected_index is not None and first_sample_index < expected_index:
        return BlockCheck(False, f"duplicate or out of order: first_sample_index {first_sample_index}, "
                                 f"expected {expected_index}", "stale")
    lengths = {name: len(values) for name, values in arrays.items()}
    if len(set(lengths.values())) > 1:
        return BlockCheck(False, f"array lengths differ: {lengths}", "content")
    length = next(iter(lengths.values()), 0)
    if length == 0:
        return BlockCheck(False, "empty block", "content")
    if expected_length is not None and length != expected_length:
        return BlockCheck(False, f"block has {length} samples, expected {expected_length}", "content")
    if not np.isclose(sample_rate_hz, expected_rate_hz, rtol=1e-9):
        return BlockCheck(False, f"sample_rate_hz {sample_rate_hz} != {expected_rate_hz}", "content")
    for name, values in arrays.items():
        bad = ~np.isfinite(values)
        if bad.any():
            return BlockCheck(False, f"{name} has {int(bad.sum())} non-finite sample(s), first at {int(np.argmax(bad))}", "content")
    if expected_index is not None and first_sample_index > expected_index:
        return BlockCheck(False, f"gap: first_sample_index {first_sample_index}, expected {expected_index}", "gap")
    return BlockCheck(True)
