"""DLTdv8 point tracks: ``*_xyzpts.csv`` (3D, calibration units) and ``*_xypts.csv`` (pixels).

One header row (``pt1_X,pt1_Y,pt1_Z,pt2_X,...`` or ``pt1_cam1_X,pt1_cam1_Y,...``), then one row
per video frame from frame 0; ``NaN`` or an empty cell where the point was not tracked. Only the
points asked for are parsed. Every refusal is a `LabFileError` naming the file and what is wrong
(columns that are not DLTdv8's, a point the rig names that the file lacks or never tracks, a
cell that is not a number with its line).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np

from flaair_model.checked_files import CheckedFileError, read_bytes
from flaair_tools.bagio.target_log import LabFileError

__all__ = ["XYZ_COLUMN", "XY_COLUMN", "read_xy_point", "read_xyz_points"]

XYZ_COLUMN = re.compile(r"pt(\d+)_([XYZ])")
XY_COLUMN = re.compile(r"pt(\d+)_cam(\d+)_([XY])")
_EMPTY_CELL = re.compile(rb"(?m)(?:^|(?<=,))[ \t]*(?=,|$)")


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


def _columns(path: Path, header: list[str], pattern: re.Pattern, kind: str) -> dict[tuple, int]:
    columns: dict[tuple, int] = {}
    for number, name in enumerate(header):
        match = pattern.fullmatch(name)
        if match is None:
            raise LabFileError(
                f"{path}: column {number + 1} {name!r} is not a DLTdv8 {kind} "
                f"column (expected names like "
                f"{'pt1_X,pt1_Y,pt1_Z' if kind == 'xyzpts' else 'pt1_cam1_X'})"
            )
        key = tuple(int(g) if g.isdigit() else g for g in match.groups())
        if key in columns:
            raise LabFileError(f"{path}: column {number + 1} {name!r} appears twice")
        columns[key] = number
    return columns


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
    path: Path | str, points: dict[str, int], length_unit_m: float
) -> dict[str, np.ndarray]:
    """Each named point's (frames, 3) positions in metres, NaN where untracked.

    `points` maps a name (for messages: the rig's key) to a DLTdv8 point number (1-based).
    """
    path = Path(path)
    header, body = _read_text(path)
    columns = _columns(path, header, XYZ_COLUMN, "xyzpts")
    available = sorted({key[0] for key in columns})
    usecols = []
    for name, point in points.items():
        keys = [(point, axis) for axis in "XYZ"]
        if not all(key in columns for key in keys):
            raise LabFileError(
                f"{path}: no point {point} ({name}); the file has point(s) "
                f"{', '.join(map(str, available)) or 'none'}"
            )
        usecols += [columns[key] for key in keys]
    data = _load(path, body, usecols, len(header)) * length_unit_m
    out = {}
    for k, (name, point) in enumerate(points.items()):
        xyz = data[:, 3 * k : 3 * k + 3]
        xyz[~np.isfinite(xyz).all(axis=1)] = np.nan
        if np.isnan(xyz).all():
            raise LabFileError(f"{path}: point {point} ({name}) is never tracked")
        out[name] = xyz
    return out


def read_xy_point(path: Path | str, point: int, camera: int, name: str) -> np.ndarray:
    """The (frames, 2) pixel positions of DLTdv8 point `point` in camera `camera`."""
    path = Path(path)
    header, body = _read_text(path)
    columns = _columns(path, header, XY_COLUMN, "xypts")
    keys = [(point, camera, axis) for axis in "XY"]
    if not all(key in columns for key in keys):
        have = ", ".join(f"point {p} camera {c}" for p, c in sorted({k[:2] for k in columns}))
        raise LabFileError(
            f"{path}: no point {point} in camera {camera} ({name}); the file has "
            f"{have or 'no points'}"
        )
    xy = _load(path, body, [columns[key] for key in keys], len(header))
    xy[~np.isfinite(xy).all(axis=1)] = np.nan
    if np.isnan(xy).all():
        raise LabFileError(f"{path}: point {point} in camera {camera} ({name}) is never tracked")
    return xy
