"""Block messages <-> numpy arrays, and validation of incoming blocks.

20 kHz data travels in blocks; a block's header stamp is its first sample's time.
Array fields of rclpy messages are array.array('d'); moving through the buffer protocol
avoids a per-sample Python loop in both directions.
"""

from __future__ import annotations

import array

import numpy as np
from builtin_interfaces.msg import Time


def from_array(values: np.ndarray) -> array.array:
    """A float64[] message field holding `values`."""
    return array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


def stamp_ns_of_sample(index: int, sample_rate_hz: float) -> int:
    """Header stamp (ns) of the block starting at sample `index`: its first sample's time."""
    return round(index / sample_rate_hz * 1e9)


def stamp_from_time_s(time_s: float) -> Time:
    """builtin_interfaces/Time for a time in seconds (sim or wall time)."""
    nanoseconds = round(time_s * 1e9)
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def stamp_from_ns(stamp_ns: int) -> Time:
    """builtin_interfaces/Time for a time in integer nanoseconds (exact)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)
