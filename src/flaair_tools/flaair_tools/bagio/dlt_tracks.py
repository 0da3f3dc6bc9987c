"""DLTdv point tracks (DLTdv5 to DLTdv8a): ``*_xyzpts.csv`` (3D, calibration units) and
``*_xypts.csv`` (pixels), flat or sparse.

Flat: one header row, then one row per video frame, the first being DLTdv's frame 1; ``NaN``
or an empty cell where the point was not tracked. Every version's header is read:
``pt1_X,pt1_Y,pt1_Z,pt2_X,...`` and ``pt1_cam1_X,pt1_cam1_Y,...`` (DLTdv5 to DLTdv8a 8.3),
``pt1_cam1_U,pt1_cam1_V`` (DLTdv8a 8.4 and later), and a point the user named as
``NAME_X,NAME_Y,NAME_Z`` or ``NAME_cam1_U,NAME_cam1_V``. A point is its position among the
file's points (from 1) whichever header names it; the rig gives that number or the name.
Sparse (DLTdv8a): recognised by its layout: a first line beginning ``Sparse format`` (``Sparse
format 3D coordinates file``, a 2D export's naming camera coordinates), then the row and column
counts and the number of entries, then one ``row column value`` line per tracked value (from
1), every other cell NaN: read as the flat file it stands for (a 2D one as one camera's). The
title says 3D or 2D (or cameras: 2D); a title saying neither is read as the kind of file asked
for.

Only the points asked for are parsed. Every refusal is a `LabFileError` naming the file and what
is wrong (columns that are not DLTdv's, a point the rig names that the file lacks, with the
file's points, or never tracks, a cell that is not a number with its line).
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from flaair_model.checked_files import CheckedFileError, read_bytes
from flaair_tools.bagio.target_log import LabFileError

__all__ = ["SPARSE_FIRST_LINE", "XYZ_COLUMN", "XY_COLUMN", "read_xy_point", "read_xyz_points"]

XYZ_COLUMN = re.compile(r"(.+)_([XYZ])")
XY_COLUMN = re.compile(r"(.+)_cam(\d+)_([XYUV])")
SPARSE_FIRST_LINE = re.compile(r"\s*sparse format\b.*", re.IGNORECASE)
_SPARSE_3D, _SPARSE_2D = (
    re.compile(r"\b3d\b", re.IGNORECASE),
    re.compile(r"\b2d\b|camera|pixel", re.IGNORECASE),
)
_NUMBERED = re.compile(r"pt(\d+)")
_EMPTY_CELL = re.compile(rb"(?m)(?:^|(?<=,))[ \t]*(?=,|$)")
# a sparse file's announced size, bounded before anything is allocated for it
MAX_SPARSE_ROWS, MAX_SPARSE_COLUMNS = 10_000_000, 30_000  # 1,000 s at 10,000 fps
_AXIS = {"X": "X", "Y": "Y", "Z": "Z", "U": "X", "V": "Y"}


@dataclass(frozen=True)
class _Layout:
    """A track file's points (names by position, from 1) and where their columns are."""

    names: list[str]
    columns: dict[tuple, int]  # (position, axis) or (position, camera, axis) -> column
    width: int  # columns in a row
    sparse: bool

    def listing(self) -> str:
        """The file's points, at most the first ten: ``1 'pt1', 2 'hinge', ...``."""
        shown = ", ".join(f"{k} {name!r}" for k, name in enumerate(self.names[:10], start=1))
        more = f", ... ({len(self.names)} in all)" if len(self.names) > 10 else ""
        return (shown + more) or "none"


def _read_text(path: Path) -> tuple[list[str], bytes]:
    """The header's column names and the body's bytes (kept as bytes: a str copy of a long
    track would cost several times the file in memory).
    """
    try:  # a regular file of a bounded size
        raw = read_bytes(path, "track")
    except CheckedFileError as exc:
        raise LabFileError(str(exc)) from None
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    head, _, body = raw.partition(b"\n")
    try:
        header_text = head.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise LabFileError(
            f"{path}: not a DLTdv8 track file: line 1 is not text (byte {exc.start})"
        ) from None
    header = [cell.strip().strip('"') for cell in header_text.split(",")]
    return header, body.rstrip(b"\n")


def _flat_layout(path: Path, header: list[str], kind: str) -> _Layout:
    """Columns of a flat export, ``pt1_X``/``NAME_X`` (3D) or ``pt1_cam1_X``/``_U`` (2D)."""
    pattern = XYZ_COLUMN if kind == "xyzpts" else XY_COLUMN
    names: list[str] = []
    columns: dict[tuple, int] = {}
    for number, cell in enumerate(header):
        match = pattern.fullmatch(cell)
        if match is None or (kind == "xyzpts" and XY_COLUMN.fullmatch(cell)):
            raise LabFileError(
                f"{path}: column {number + 1} {cell!r} is not a DLTdv8 {kind} "
                f"column (expected names like "
                f"{'pt1_X,pt1_Y,pt1_Z' if kind == 'xyzpts' else 'pt1_cam1_X or pt1_cam1_U'})"
            )
        name = match.group(1)
        if name not in names:
            names.append(name)
        position = names.index(name) + 1
        key: tuple = (
            (position, int(match.group(2)), _AXIS[match.group(3)])
            if kind == "xypts"
            else (position, _AXIS[match.group(2)])
        )
        if key in columns:
            raise LabFileError(f"{path}: column {number + 1} {cell!r} appears twice")
        columns[key] = number
    return _Layout(names, columns, len(header), sparse=False)


def _sparse_layout(path: Path, dimensions: int, body: bytes) -> tuple[_Layout, np.ndarray, int]:
    """A sparse export: its layout, its (entries, 3) ``row column value`` table, its rows."""
    counts_line, _, entries = body.partition(b"\n")
    counts = re.split(rb"[\s,;]+", counts_line.strip())
    try:
        rows, width, n_entries = (int(c) for c in counts)
    except ValueError:
        raise LabFileError(
            f"{path}: line 2 of a sparse track file must give its row count, column count and "
            f"number of entries, got {counts_line[:60].decode('latin-1')!r}"
        ) from None
    per_point = 3 if dimensions == 3 else 2
    if rows > MAX_SPARSE_ROWS or width > MAX_SPARSE_COLUMNS:
        raise LabFileError(
            f"{path}: line 2 announces {rows} rows and {width} columns, more than a track holds "
            f"(at most {MAX_SPARSE_ROWS} frames and {MAX_SPARSE_COLUMNS} columns read)"
        )
    if rows < 1 or width < per_point or width % per_point or n_entries < 0:
        raise LabFileError(
            f"{path}: line 2: {rows} rows and {width} columns is not a {dimensions}D track "
            f"({per_point} columns a point)"
        )
    text = re.sub(rb"[,;\t]", b" ", entries)
    try:
        table = np.loadtxt(io.BytesIO(text), ndmin=2, comments=None, encoding="latin-1")
    except ValueError as exc:
        raise LabFileError(f"{path}: a sparse entry is not 'row column value' ({exc})") from None
    if table.shape[0] != n_entries or (n_entries and table.shape[1] != 3):
        raise LabFileError(
            f"{path}: {table.shape[0]} sparse entries of {table.shape[1] if table.size else 0} "
            f"numbers; line 2 announces {n_entries} of 3 (row column value)"
        )
    table = table.reshape(-1, 3)
    index = table[:, :2]
    if n_entries and (
        np.any(index != np.round(index))
        or index[:, 0].min() < 1
        or index[:, 0].max() > rows
        or index[:, 1].min() < 1
        or index[:, 1].max() > width
    ):
        raise LabFileError(
            f"{path}: a sparse entry's row or column is outside the {rows} x {width} track"
        )
    names = [f"pt{k}" for k in range(1, width // per_point + 1)]
    axes = "XYZ"[:per_point]
    columns: dict[tuple, int] = {}
    for k in range(width):
        position, axis = k // per_point + 1, axes[k % per_point]
        # a 2D sparse file does not say how many cameras it holds: one is read
        columns[(position, axis) if dimensions == 3 else (position, 1, axis)] = k
    return _Layout(names, columns, width, sparse=True), table, rows


def _sparse_columns(table: np.ndarray, rows: int, usecols: list[int]) -> np.ndarray:
    """The flat file's `usecols` (rows x len(usecols)), NaN where no entry."""
    out = np.full((rows, len(usecols)), np.nan)
    for k, column in enumerate(usecols):
        mine = table[:, 1] == column + 1
        out[table[mine, 0].astype(np.int64) - 1, k] = table[mine, 2]
    return out


def _layout_and_rows(path: Path, kind: str) -> tuple[_Layout, Any]:
    """The file's layout and a loader of its columns."""
    header, body = _read_text(path)
    title = ",".join(header).strip().strip(",")
    if SPARSE_FIRST_LINE.fullmatch(title) is None:
        layout = _flat_layout(path, header, kind)
        return layout, lambda usecols: _load(path, body, usecols, layout.width)
    wanted = 3 if kind == "xyzpts" else 2
    says_3d, says_2d = bool(_SPARSE_3D.search(title)), bool(_SPARSE_2D.search(title))
    dimensions = wanted if says_3d == says_2d else (3 if says_3d else 2)
    if dimensions != (3 if kind == "xyzpts" else 2):
        raise LabFileError(
            f"{path}: a sparse {dimensions}D track where {kind} ("
            f"{'3D' if kind == 'xyzpts' else '2D'} points) belongs"
        )
    layout, table, rows = _sparse_layout(path, dimensions, body)
    return layout, lambda usecols: _sparse_columns(table, rows, usecols)


def _position(path: Path, layout: _Layout, point: int | str, label: str) -> int:
    """The position (from 1) of the rig's `point`: a number, a name, or ``ptN``."""
    if isinstance(point, str):
        if point in layout.names:
            return layout.names.index(point) + 1
        numbered = _NUMBERED.fullmatch(point)
        if numbered is not None and 1 <= int(numbered.group(1)) <= len(layout.names):
            return int(numbered.group(1))
    elif 1 <= point <= len(layout.names):
        return point
    raise LabFileError(
        f"{path}: no point {_shown(point)} ({label}); the file has points {layout.listing()}"
    )


def _shown(point: int | str) -> str:
    return repr(point) if isinstance(point, str) else str(point)


def _load(path: Path, body: bytes, usecols: list[int], n_columns: int) -> np.ndarray:
    """Rows x usecols as float64 (NaN where empty); a bad cell is named by line and column."""
    if not body.strip():
        raise LabFileError(f"{path}: no frames (only a header line)")
    filled = _EMPTY_CELL.sub(b"nan", body)
    del body
    try:
        return np.loadtxt(
            io.BytesIO(filled),
            delimiter=",",
            usecols=usecols,
            ndmin=2,
            dtype=np.float64,
            comments=None,
            encoding="latin-1",
        )
    except ValueError as exc:
        text = str(exc)
        row = re.search(r"at row (\d+)", text)
        line = f"line {int(row.group(1)) + 2}: " if row else ""
        if "invalid column index" in text or "number of columns changed" in text:
            # numpy counts this row from 1 (a bad cell's row from 0)
            line = f"line {int(row.group(1)) + 1}: " if row else ""
            raise LabFileError(
                f"{path}: {line}a row without the header's {n_columns} columns"
            ) from None
        cell = re.search(r"could not convert string '([^']*)'", text)
        what = f"not a number: {cell.group(1)!r}" if cell else text
        raise LabFileError(f"{path}: {line}{what}") from None


def read_xyz_points(
    path: Path | str, points: dict[str, int | str], length_unit_m: float
) -> dict[str, np.ndarray]:
    """Each named point's (frames, 3) positions in metres, NaN where untracked.

    `points` maps a name (for messages: the rig's key) to a DLTdv point: its number (its
    position among the file's points, from 1) or its name. Row k is DLTdv's frame k + 1.
    """
    path = Path(path)
    layout, load = _layout_and_rows(path, "xyzpts")
    positions = {name: _position(path, layout, point, name) for name, point in points.items()}
    if len(set(positions.values())) != len(positions):
        raise LabFileError(
            f"{path}: the rig names one point twice: "
            + ", ".join(f"{name} = point {p}" for name, p in positions.items())
        )
    usecols = []
    for name, position in positions.items():
        keys = [(position, axis) for axis in "XYZ"]
        if not all(key in layout.columns for key in keys):
            raise LabFileError(
                f"{path}: point {_shown(points[name])} ({name}) lacks a column of X, Y, Z"
            )
        usecols += [layout.columns[key] for key in keys]
    data = load(usecols) * length_unit_m
    out = {}
    for k, (name, point) in enumerate(points.items()):
        xyz = data[:, 3 * k : 3 * k + 3]
        xyz[~np.isfinite(xyz).all(axis=1)] = np.nan
        if np.isnan(xyz).all():
            raise LabFileError(f"{path}: point {_shown(point)} ({name}) is never tracked")
        out[name] = xyz
    return out


def read_xy_point(path: Path | str, point: int | str, camera: int, name: str) -> np.ndarray:
    """The (frames, 2) pixel positions of DLTdv point `point` (number or name) in `camera`."""
    path = Path(path)
    layout, load = _layout_and_rows(path, "xypts")
    position = _position(path, layout, point, name)
    keys = [(position, camera, axis) for axis in "XY"]
    if not all(key in layout.columns for key in keys):
        cameras = sorted({key[1] for key in layout.columns if key[0] == position})
        if layout.sparse:
            raise LabFileError(
                f"{path}: a 2D sparse track does not say how many cameras it holds and is read "
                f"as one camera's; the rig asks for camera {camera} ({name}): export that "
                "camera's points flat"
            )
        raise LabFileError(
            f"{path}: no point {_shown(point)} in camera {camera} ({name}); the file has "
            f"that point in camera(s) {', '.join(map(str, cameras)) or 'none'}"
        )
    xy = load([layout.columns[key] for key in keys])
    xy[~np.isfinite(xy).all(axis=1)] = np.nan
    if np.isnan(xy).all():
        raise LabFileError(
            f"{path}: point {_shown(point)} in camera {camera} ({name}) is never tracked"
        )
    return xy
