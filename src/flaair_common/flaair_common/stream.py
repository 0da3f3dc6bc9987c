"""Checking an incoming block against the stream it continues (pure: numpy only).

Cores that judge their input stream (the loop supervisor, the collision monitor's replay) and
the nodes share this one check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
        return BlockCheck(
            False,
            "duplicate or out of order: first_sample_index "
            f"{first_sample_index}, expected {expected_index}",
            "stale",
        )
    lengths = {name: len(values) for name, values in arrays.items()}
    if len(set(lengths.values())) > 1:
        return BlockCheck(False, f"array lengths differ: {lengths}", "content")
    length = next(iter(lengths.values()), 0)
    if length == 0:
        return BlockCheck(False, "empty block", "content")
    if expected_length is not None and length != expected_length:
        return BlockCheck(
            False, f"block has {length} samples, expected {expected_length}", "content"
        )
    # np.isclose's rule (atol 1e-8, rtol 1e-9) in plain
    # floats: it runs 2,000 times a second per stream
    if not abs(sample_rate_hz - expected_rate_hz) <= 1e-8 + 1e-9 * abs(expected_rate_hz):
        return BlockCheck(
            False, f"sample_rate_hz {sample_rate_hz} != {expected_rate_hz}", "content"
        )
    for name, values in arrays.items():
        if np.isfinite(values).all():
            continue
        bad = ~np.isfinite(values)
        if bad.any():
            return BlockCheck(
                False,
                f"{name} has {int(bad.sum())} non-finite sample(s), first at {int(np.argmax(bad))}",
                "content",
            )
    if expected_index is not None and first_sample_index > expected_index:
        return BlockCheck(
            False, f"gap: first_sample_index {first_sample_index}, expected {expected_index}", "gap"
        )
    return BlockCheck(True)
