"""Lab files written the way the real writers write them, for the tests and the example session.

- MAT v5 as MATLAB's ``save`` leaves it at a bench: the log (written by scipy.io.savemat) and
  beside it a MATLAB object: an ``mxOPAQUE_CLASS`` element in MCOS layout (array flags,
  the variable's name, the type system ``MCOS``, the class name, then a uint32 6 x 1 matrix
  ``[0xDD000000, 2, 1, 1, object id, class id]``), and the subsystem data MATLAB appends for
  its objects: a uint8 variable with an empty name holding a small MAT stream (version,
  endian mark, a struct whose ``MCOS`` field is a ``FileWrapper__`` object), its offset in
  the header's bytes 116-123. Each variable is zlib-compressed as ``-v7`` does, or not.
- MAT v7.3: the log through hdf5storage, and an object as MATLAB's HDF5 layout stores one (a
  uint32 dataset with ``MATLAB_class`` the object's class and ``MATLAB_object_decode`` 3, and a
  ``#subsystem#`` group).
- DLTdv tracks: DLTdv5-7 (``dlmwrite`` with ``'precision', 6``: ``%.6g``, ``NaN``), DLTdv8a
  before 8.4 (empty cells where untracked), DLTdv8a 8.4 (named points ``NAME_X``, 2D columns
  ``_U``/``_V``, ``%.15g`` and ``NaN`` as ``writematrix`` writes), and the sparse export.
"""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np

MI_INT8, MI_UINT8, MI_INT32, MI_UINT32, MI_MATRIX, MI_COMPRESSED = 1, 2, 5, 6, 14, 15
MX_CELL, MX_STRUCT, MX_UINT8, MX_UINT32, MX_OPAQUE = 1, 2, 9, 13, 17


def _element(kind: int, data: bytes) -> bytes:
    """A data element: small format (<= 4 bytes) or tag + data padded to 8 bytes."""
    if 0 < len(data) <= 4:
        return struct.pack("<HH", kind, len(data)) + data.ljust(4, b"\0")
    return struct.pack("<II", kind, len(data)) + data + b"\0" * (-len(data) % 8)


def _flags(mclass: int) -> bytes:
    return _element(MI_UINT32, struct.pack("<II", mclass, 0))


def _matrix(body: bytes) -> bytes:
    return struct.pack("<II", MI_MATRIX, len(body)) + body


def _numeric(name: str, mclass: int, kind: int, values: np.ndarray) -> bytes:
    dims = np.asarray(values.shape if values.ndim == 2 else (values.size, 1), dtype="<i4")
    return _matrix(
        _flags(mclass)
        + _element(MI_INT32, dims.tobytes())
        + _element(MI_INT8, name.encode())
        + _element(kind, values.tobytes(order="F"))
    )


def mcos_object(name: str, class_name: str, object_id: int = 1, class_id: int = 1) -> bytes:
    """An MCOS object variable (mxOPAQUE_CLASS) as MATLAB writes one."""
    metadata = np.array([0xDD000000, 2, 1, 1, object_id, class_id], dtype="<u4")
    return _matrix(
        _flags(MX_OPAQUE)
        + _element(MI_INT8, name.encode())
        + _element(MI_INT8, b"MCOS")
        + _element(MI_INT8, class_name.encode())
        + _numeric("", MX_UINT32, MI_UINT32, metadata.reshape(6, 1))
    )


def subsystem(class_names: list[str]) -> bytes:
    """MATLAB's subsystem data: an unnamed uint8 variable holding a small MAT stream."""
    names = b"".join(n.encode() + b"\0" for n in class_names)
    header = np.frombuffer(struct.pack("<II", 4, len(class_names)) + names, dtype="u1")
    cell = _matrix(
        _flags(MX_CELL)
        + _element(MI_INT32, np.array([2, 1], "<i4").tobytes())
        + _element(MI_INT8, b"")
        + _numeric("", MX_UINT8, MI_UINT8, header.reshape(-1, 1))
        + _matrix(b"")
    )
    wrapper = _matrix(
        _flags(MX_OPAQUE)
        + _element(MI_INT8, b"")
        + _element(MI_INT8, b"MCOS")
        + _element(MI_INT8, b"FileWrapper__")
        + cell
    )
    fields = _matrix(
        _flags(MX_STRUCT)
        + _element(MI_INT32, np.array([1, 1], "<i4").tobytes())
        + _element(MI_INT8, b"")
        + _element(MI_INT32, struct.pack("<i", 32))
        + _element(MI_INT8, b"MCOS".ljust(32, b"\0"))
        + wrapper
    )
    stream = np.frombuffer(b"\x00\x01IM\0\0\0\0" + fields, dtype="u1")
    return _numeric("", MX_UINT8, MI_UINT8, stream.reshape(1, -1))


def fixed_header(path: Path, version: str = "5.0") -> None:
    """Replace the header text's creation time (bytes 0-115) by a fixed one, as MATLAB words
    it, so that a file written twice is the same bytes.
    """
    data = bytearray(path.read_bytes())
    text = f"MATLAB {version} MAT-file, Platform: GLNXA64, Created on: Thu Nov 26 10:00:00 2026" + (
        " HDF5 schema 1.00 ." if version == "7.3" else ""
    )
    data[:116] = text.encode().ljust(116, b" ")
    path.write_bytes(bytes(data))


def _compressed(element: bytes) -> bytes:
    data = zlib.compress(element)
    return struct.pack("<II", MI_COMPRESSED, len(data)) + data


def write_v5_with_object(
    path: Path,
    variables: dict,
    objects: dict[str, str],
    compress: bool = True,
) -> Path:
    """`variables` through scipy.io.savemat, then MCOS `objects` (name -> class) and the
    subsystem data appended as MATLAB's ``save`` leaves them (its header pointing to it).
    """
    import scipy.io

    buffer = io.BytesIO()
    scipy.io.savemat(buffer, variables, do_compression=compress)
    data = bytearray(buffer.getvalue())
    wrap = _compressed if compress else (lambda element: element)
    for k, (name, class_name) in enumerate(objects.items(), start=1):
        data += wrap(mcos_object(name, class_name, object_id=k, class_id=k))
    data[116:124] = struct.pack("<Q", len(data))  # the subsystem data's offset
    data += wrap(subsystem(sorted(set(objects.values()))))
    path.write_bytes(bytes(data))
    return path


def write_v73_with_object(path: Path, variables: dict, objects: dict[str, str]) -> Path:
    """`variables` through hdf5storage (MATLAB v7.3), and MCOS `objects` beside them."""
    import h5py
    import hdf5storage

    hdf5storage.savemat(str(path), variables, format="7.3", matlab_compatible=True)
    with h5py.File(path, "a") as f:
        for k, (name, class_name) in enumerate(objects.items(), start=1):
            metadata = np.array([[0xDD000000, 2, 1, 1, k, k]], dtype=np.uint32)
            dataset = f.create_dataset(name, data=metadata)
            dataset.attrs["MATLAB_class"] = np.bytes_(class_name)
            dataset.attrs["MATLAB_object_decode"] = np.int32(3)
        group = f.require_group("#subsystem#")
        group.create_dataset("MCOS", data=np.zeros((1, 4), dtype=np.uint8))
    return path


def _cells(table: np.ndarray, number_format: str, missing: str) -> list[str]:
    return [
        ",".join(missing if not np.isfinite(v) else number_format % v for v in row) for row in table
    ]


def write_track(
    path: Path,
    header: list[str],
    table: np.ndarray,
    writer: str = "DLTdv8a 8.4",
) -> Path:
    """A flat DLTdv track (`table`: frames x columns) as `writer` writes it."""
    number_format, missing = {
        "DLTdv7": ("%.6g", "NaN"),  # dlmwrite(..., 'precision', 6)
        "DLTdv8a 8.3": ("%.6f", ""),
        "DLTdv8a 8.4": ("%.15g", "NaN"),  # writematrix
    }[writer]
    lines = [",".join(header), *_cells(table, number_format, missing)]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_sparse_track(
    path: Path, table: np.ndarray, dimensions: int = 3, title: str | None = None
) -> Path:
    """DLTdv8a's sparse export of `table` (frames x columns): tracked cells only, from 1;
    `title` in place of its first line ``Sparse format 3D coordinates file`` (or 2D).
    """
    rows, columns = np.nonzero(np.isfinite(table))
    order = np.lexsort((columns, rows))
    lines = [
        title or f"Sparse format {dimensions}D coordinates file",
        f"{table.shape[0]} {table.shape[1]} {rows.size}",
        *(
            f"{r + 1} {c + 1} {table[r, c]:.15g}"
            for r, c in zip(rows[order], columns[order], strict=True)
        ),
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def xyz_header(names: list[str]) -> list[str]:
    """``NAME_X,NAME_Y,NAME_Z`` for each point (``pt1`` ... or a name)."""
    return [f"{name}_{axis}" for name in names for axis in "XYZ"]


def xy_header(names: list[str], cameras: int, axes: str = "UV") -> list[str]:
    """``NAME_camC_U,NAME_camC_V`` (DLTdv8a 8.4) or ``_X,_Y`` (earlier), point by point."""
    return [
        f"{name}_cam{camera}_{axis}"
        for name in names
        for camera in range(1, cameras + 1)
        for axis in axes
    ]
