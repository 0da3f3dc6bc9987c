"""mat_bounds: how far a MAT file may expand before it is read.

A compressed MAT v5 element (miCOMPRESSED) or an HDF5 dataset of a v7.3 file can claim far
more memory than the file holds: a 100 kB file of zeros expands to gigabytes. `check_v5` streams
every compressed element through zlib, counting the bytes without keeping them, and refuses a
file that would expand past `expansion_limit_bytes`; `check_dataset` does the same for an HDF5
dataset's declared size. A lab log of real signals compresses a few times at most.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Any

__all__ = [
    "EXPANSION_RATIO",
    "EXPANSION_SLACK_BYTES",
    "MatBoundsError",
    "check_dataset",
    "check_v5",
    "limit_bytes",
]

EXPANSION_RATIO = 64  # a file expands to at most this times its size ...
EXPANSION_SLACK_BYTES = 64 << 20  # ... plus this much (a short log of constant signals)
_MI_COMPRESSED = 15
_CHUNK_BYTES = 1 << 20


class MatBoundsError(ValueError):
    """A MAT file that would expand past its bound; the message names the file."""


def limit_bytes(file_bytes: int) -> int:
    """The most a MAT file of `file_bytes` may expand to."""
    return EXPANSION_RATIO * file_bytes + EXPANSION_SLACK_BYTES


def check_v5(path: Path) -> None:
    """Refuse a MAT v5 file whose compressed elements expand past `limit_bytes` (streamed)."""
    size = path.stat().st_size
    limit, total = limit_bytes(size), 0
    with open(path, "rb") as handle:
        handle.seek(126)
        endian = "<" if handle.read(2) == b"IM" else ">"
        while len(tag := handle.read(8)) == 8:
            kind, nbytes = struct.unpack(endian + "II", tag)
            if kind != _MI_COMPRESSED:
                total += nbytes
                handle.seek(nbytes + (-nbytes % 8), 1)
                continue
            inflate, left = zlib.decompressobj(), nbytes
            while left > 0 and (data := handle.read(min(_CHUNK_BYTES, left))):
                left -= len(data)
                while data:
                    try:
                        total += len(inflate.decompress(data, _CHUNK_BYTES))
                    except zlib.error as exc:
                        raise MatBoundsError(f"{path}: damaged compressed data ({exc})") from None
                    data = inflate.unconsumed_tail
                    if total > limit:
                        raise MatBoundsError(_text(path, size, limit))
                    if inflate.eof:
                        break
            if total > limit:
                raise MatBoundsError(_text(path, size, limit))


def check_dataset(path: Path, dataset: Any) -> None:
    """Refuse an HDF5 dataset whose declared size is past `limit_bytes` of its file."""
    size = path.stat().st_size
    if int(getattr(dataset, "nbytes", 0)) > limit_bytes(size):
        raise MatBoundsError(_text(path, size, limit_bytes(size)))


def _text(path: Path, size: int, limit: int) -> str:
    return (
        f"{path}: its compressed data expands past {limit} bytes ({EXPANSION_RATIO} x its "
        f"{size} bytes + {EXPANSION_SLACK_BYTES >> 20} MiB): not a lab log"
    )
