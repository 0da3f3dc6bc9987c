"""MAT version 5 files read element by element: the variables' directory, and one variable.

MATLAB's default ``save`` (``-v6``/``-v7``, compressed or not) writes a 128-byte header and
then one element per variable: ``miMATRIX``, or ``miCOMPRESSED`` holding one zlib-compressed
``miMATRIX``. This reader walks those elements itself, so that

- what else the file holds never matters: a MATLAB object (``mxOPAQUE_CLASS``, the MCOS
  objects a plain ``save`` catches beside the log: the target object, ``logsout``, a
  ``Simulink.SimulationOutput``), the subsystem data MATLAB appends for them (a variable with
  an empty name), sparse matrices, cells and functions are listed or skipped, never decoded
  (``scipy.io.whosmat`` fails on the first of them: its header has no dimensions);
- one variable is read, decompressing as it goes, and a struct element can be dropped as soon
  as it is read (`StructHook`): a log of many signals costs the memory of the ones kept, not
  of the whole variable.

Every damaged, cut or unexpected element raises `MatV5Error` (a ValueError) with what was
found; the caller names the file.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, BinaryIO

import numpy as np

__all__ = ["MatV5Error", "Skipped", "StructHook", "V5Variable", "list_variables", "read_variable"]

MI_MATRIX, MI_COMPRESSED = 14, 15
_MI_INT8, _MI_INT32, _MI_UINT32 = 1, 5, 6
_NUMERIC = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 9: "f8", 12: "i8"}
_NUMERIC.update({13: "u8", 16: "u1", 17: "u2", 18: "u4"})  # miUTF8/16/32 hold char data
MX_CELL, MX_STRUCT, MX_OBJECT, MX_CHAR, MX_SPARSE, MX_OPAQUE = 1, 2, 3, 4, 5, 17
_NUMERIC_CLASSES = set(range(6, 16))  # double, single, int8 ... uint64
_CLASS_NAMES = {MX_CELL: "cell", MX_STRUCT: "struct", MX_OBJECT: "object", MX_CHAR: "char"}
_CLASS_NAMES.update({MX_SPARSE: "sparse", 16: "function_handle", MX_OPAQUE: "opaque"})
_HEADER_BYTES = 128
_CHUNK = 1 << 18
_PREALLOCATE = 1 << 26  # bytes of a compressed element allocated before they are seen

# called with each struct element's fields once read; returns them (possibly lightened)
StructHook = Callable[[dict[str, Any]], dict[str, Any]]


class MatV5Error(ValueError):
    """An element that is cut short, damaged or not what MAT v5 allows; says which."""


@dataclass(frozen=True)
class V5Variable:
    """One top-level variable: its name, MATLAB class, dimensions and (structs) field names."""

    name: str
    matlab_class: str  # "struct", "double", ..., or the class of an MCOS object
    dims: tuple[int, ...]
    fields: tuple[str, ...]
    offset: int  # the element's byte offset in the file


@dataclass(frozen=True)
class Skipped:
    """A value not decoded (an object, a cell, a sparse matrix, or numbers a hook dropped)."""

    matlab_class: str
    dims: tuple[int, ...]


class _File:
    """Bytes of one uncompressed element, straight from the file."""

    def __init__(self, handle: BinaryIO, end: int) -> None:
        self.handle, self.end, self.pos = handle, end, 0

    def read(self, n: int) -> bytearray:
        if n > self.end - self.handle.tell():
            raise MatV5Error(f"an element claims {n} bytes past the end of its variable")
        data = bytearray(n)
        if self.handle.readinto(data) != n:
            raise MatV5Error("the file ends inside an element (cut short)")
        self.pos += n
        return data

    def skip(self, n: int) -> None:
        if n > self.end - self.handle.tell():
            raise MatV5Error(f"an element claims {n} bytes past the end of its variable")
        self.handle.seek(n, 1)
        self.pos += n


class _Zlib:
    """The decompressed bytes of one miCOMPRESSED element, produced as they are read."""

    def __init__(self, handle: BinaryIO, compressed_bytes: int) -> None:
        self.handle, self.left, self.pos = handle, compressed_bytes, 0
        self.inflate = zlib.decompressobj()

    def _more(self, limit: int) -> bytes:
        while True:
            if self.inflate.unconsumed_tail:
                data = self.inflate.unconsumed_tail
            elif self.left > 0:
                data = self.handle.read(min(_CHUNK, self.left))
                if not data:
                    raise MatV5Error("the file ends inside a compressed variable (cut short)")
                self.left -= len(data)
            else:
                raise MatV5Error("a compressed variable ends before its elements do")
            try:
                out = self.inflate.decompress(data, limit)
            except zlib.error as exc:
                raise MatV5Error(f"a compressed variable is damaged ({exc})") from None
            if out:
                return out
            if self.inflate.eof:
                raise MatV5Error("a compressed variable ends before its elements do")

    def read(self, n: int) -> bytearray:
        if n > _PREALLOCATE:  # a size the stream may not hold (damage): grown as data comes
            grown = bytearray()
            while len(grown) < n:
                grown += self._more(min(n - len(grown), _CHUNK))
            self.pos += n
            return grown
        data, have = bytearray(n), 0  # filled in place: no second copy of a long signal
        view = memoryview(data)
        while have < n:
            part = self._more(n - have)
            view[have : have + len(part)] = part
            have += len(part)
        self.pos += n
        return data

    def skip(self, n: int) -> None:
        self.pos += n
        while n > 0:
            n -= len(self._more(min(n, _CHUNK)))


class _Reader:
    def __init__(self, endian: str, hook: StructHook | None) -> None:
        self.endian, self.hook = endian, hook

    def tag(self, s: _File | _Zlib) -> tuple[int, int, bytes | None]:
        """(data type, size, the data of a small element or None) of the next element."""
        first, second = struct.unpack(self.endian + "II", s.read(8))
        if first >> 16:  # small data element: type, size and up to 4 bytes in 8
            size = first >> 16
            if size > 4:
                raise MatV5Error(f"a small data element claims {size} bytes (at most 4)")
            return first & 0xFFFF, size, struct.pack(self.endian + "I", second)[:size]
        return first, second, None

    def element(
        self, s: _File | _Zlib, kinds: tuple[int, ...], what: str
    ) -> tuple[int, bytes | bytearray]:
        kind, size, small = self.tag(s)
        if kind not in kinds:
            raise MatV5Error(f"{what}: data type {kind}, expected one of {kinds}")
        if small is not None:
            return kind, small
        data = s.read(size)
        s.skip(-size % 8)
        return kind, data

    def text(self, s: _File | _Zlib, what: str) -> str:
        kind, raw = self.element(s, (_MI_INT8, 2, 16), what)
        return raw.decode("utf-8" if kind == 16 else "latin-1", errors="replace")

    def numbers(self, kind: int, data: bytes | bytearray) -> np.ndarray:
        code = _NUMERIC.get(kind)
        if code is None or len(data) % np.dtype(code).itemsize:
            raise MatV5Error(f"numeric data of type {kind} and {len(data)} bytes")
        return np.frombuffer(data, dtype=np.dtype(code).newbyteorder(self.endian))

    def header(self, s: _File | _Zlib) -> tuple[int, int, tuple[int, ...], str]:
        """(class, flags, dims, name) of a miMATRIX whose tag was read; objects: no dims."""
        flags = self.numbers(_MI_UINT32, self.element(s, (_MI_UINT32,), "array flags")[1])
        if flags.size != 2:
            raise MatV5Error(f"array flags of {flags.size} numbers (2 expected)")
        mclass = int(flags[0]) & 0xFF
        if mclass == MX_OPAQUE:
            return mclass, int(flags[0]), (), self.text(s, "object name")
        kind, raw = self.element(s, (_MI_INT32, _MI_UINT32), "dimensions")
        dims = tuple(int(d) for d in self.numbers(kind, raw))
        if len(dims) < 2 or min(dims) < 0:
            raise MatV5Error(f"dimensions {dims}")
        return mclass, int(flags[0]), dims, self.text(s, "array name")

    def field_names(self, s: _File | _Zlib) -> tuple[str, ...]:
        kind, raw = self.element(s, (_MI_INT32,), "field name length")
        length = int(self.numbers(kind, raw)[0])
        names = self.element(s, (_MI_INT8,), "field names")[1]
        if not names:
            return ()
        if length <= 0 or len(names) % length:
            raise MatV5Error(f"field names of {len(names)} bytes in slots of {length}")
        return tuple(
            names[k : k + length].split(b"\0", 1)[0].decode("latin-1")
            for k in range(0, len(names), length)
        )

    def matrix(self, s: _File | _Zlib) -> Any:
        """The value of the miMATRIX element that comes next in `s`."""
        kind, size, small = self.tag(s)
        if kind != MI_MATRIX or small is not None:
            raise MatV5Error(f"an element of type {kind} where a matrix belongs")
        if size == 0:  # an empty field of a struct array
            return np.empty((0, 0))
        end = s.pos + size
        mclass, flags, dims, _name = self.header(s)
        count = int(np.prod(dims)) if dims else 0
        if mclass in _NUMERIC_CLASSES:
            real = self.numbers(*self.element(s, tuple(_NUMERIC), "real part"))
            if real.size != count:
                raise MatV5Error(f"{real.size} numbers for dimensions {dims}")
            # doubles in a (mutable) buffer of their own: no copy
            value: Any = real.astype(np.float64, copy=False).reshape(dims, order="F")
        elif mclass == MX_CHAR:
            codes = self.numbers(*self.element(s, tuple(_NUMERIC), "characters"))
            value = "".join(map(chr, codes.reshape(dims, order="F").ravel().tolist()))
            if flags & 0x0800:
                raise MatV5Error("complex characters")
        elif mclass == MX_STRUCT:
            value = self.struct_array(s, dims)
        else:
            name = _CLASS_NAMES.get(mclass, f"class {mclass}")
            value = Skipped(name, dims)
        if s.pos > end:
            raise MatV5Error(f"a matrix's parts run {s.pos - end} bytes past its {size} bytes")
        s.skip(end - s.pos)  # imaginary parts, sparse data, objects, cells: not read
        return value

    def struct_array(self, s: _File | _Zlib, dims: tuple[int, ...]) -> list[dict[str, Any]]:
        names = self.field_names(s)
        count = int(np.prod(dims))
        if not names:  # a struct without fields: nothing to read, however many elements
            return [{} for _ in range(min(count, 1))]
        elements = []
        for _ in range(count):
            fields = {name: self.matrix(s) for name in names}
            elements.append(self.hook(fields) if self.hook is not None else fields)
        return elements


def _endian(handle: BinaryIO) -> str:
    header = handle.read(_HEADER_BYTES)
    if len(header) < _HEADER_BYTES:
        raise MatV5Error("the file ends inside its 128-byte header")
    mark = header[126:128]
    if mark not in (b"IM", b"MI"):
        raise MatV5Error(f"endian indicator {mark!r} (expected 'IM' or 'MI')")
    return "<" if mark == b"IM" else ">"


def _open_element(
    handle: BinaryIO, endian: str, offset: int, size: int
) -> tuple[_File | _Zlib | None, int]:
    """The stream of the element at `offset` (None: not a variable) and the next offset."""
    handle.seek(offset)
    raw = handle.read(8)
    if len(raw) < 8:
        raise MatV5Error(f"the file ends inside an element's tag at byte {offset}")
    kind, nbytes = struct.unpack(endian + "II", raw)
    end = offset + 8 + nbytes
    if end > size:
        raise MatV5Error(f"the element at byte {offset} claims {nbytes} bytes past the end")
    if kind == MI_COMPRESSED:
        return _Zlib(handle, nbytes), end
    if kind == MI_MATRIX:
        handle.seek(offset)
        return _File(handle, end), end
    return None, end + (-nbytes % 8)


def _as_mat_error(exc: Exception) -> MatV5Error:
    return exc if isinstance(exc, MatV5Error) else MatV5Error(f"{type(exc).__name__}: {exc}")


_DAMAGE = (ValueError, struct.error, OverflowError, IndexError, MemoryError)


def list_variables(handle: BinaryIO) -> list[V5Variable]:
    """Every top-level variable of the open MAT v5 file (objects too; subsystem data not)."""
    try:
        return _list_variables(handle)
    except _DAMAGE as exc:
        raise _as_mat_error(exc) from None


def _list_variables(handle: BinaryIO) -> list[V5Variable]:
    handle.seek(0, 2)
    size = handle.tell()
    handle.seek(0)
    endian = _endian(handle)
    reader, out, offset = _Reader(endian, None), [], _HEADER_BYTES
    while offset + 8 <= size:
        stream, following = _open_element(handle, endian, offset, size)
        if stream is not None:
            kind, nbytes, small = reader.tag(stream)
            if kind != MI_MATRIX or small is not None:
                raise MatV5Error(f"the variable at byte {offset} is of data type {kind}")
            if nbytes:
                mclass, _flags, dims, name = reader.header(stream)
                fields: tuple[str, ...] = ()
                if mclass == MX_OPAQUE:
                    reader.text(stream, "type system")
                    kind_name = reader.text(stream, "object class")
                elif mclass == MX_STRUCT:
                    fields, kind_name = reader.field_names(stream), "struct"
                else:
                    kind_name = _CLASS_NAMES.get(mclass, _NUMERIC_NAME.get(mclass, "?"))
                if name:  # the empty name: MATLAB's subsystem data for its objects
                    out.append(V5Variable(name, kind_name, dims, fields, offset))
        offset = following
    return out


_NUMERIC_NAME = {6: "double", 7: "single", 8: "int8", 9: "uint8", 10: "int16", 11: "uint16"}
_NUMERIC_NAME.update({12: "int32", 13: "uint32", 14: "int64", 15: "uint64"})


def read_variable(handle: BinaryIO, variable: V5Variable, hook: StructHook | None = None) -> Any:
    """The value of `variable` (from `list_variables`): arrays as float64 in MATLAB's shape,
    char as str, structs as lists of field dicts (column-major), anything else `Skipped`.
    `hook` sees each struct element as soon as it is read.
    """
    try:
        return _read_variable(handle, variable, hook)
    except _DAMAGE as exc:
        raise _as_mat_error(exc) from None


def _read_variable(handle: BinaryIO, variable: V5Variable, hook: StructHook | None) -> Any:
    handle.seek(0, 2)
    size = handle.tell()
    handle.seek(0)
    endian = _endian(handle)
    stream, _ = _open_element(handle, endian, variable.offset, size)
    if stream is None:  # pragma: no cover (list_variables only lists matrices)
        raise MatV5Error(f"no variable at byte {variable.offset}")
    return _Reader(endian, hook).matrix(stream)
