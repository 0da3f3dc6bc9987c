"""validation_file: a saved validation.json (`--validation FILE`), checked before any analysis.

The file goes through the checked reader (regular, at most `LIMIT_BYTES["validation"]`), its
JSON is strict and at most `MAX_DEPTH` levels deep, and its layout is the one
`write_validation` writes: a confusion table (`columns`, `rows`, `counts`) and the cases'
outcomes. Anything else is one `ValidationFileError` line naming the file and the key.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from flaair_model.checked_files import CheckedFileError, bracket_depth, quote, read_text

__all__ = ["MAX_DEPTH", "ValidationFileError", "read_validation"]

MAX_DEPTH = 16
_CASE_TEXT = ("case", "true", "found", "status")


class ValidationFileError(ValueError):
    """A --validation file that is not a validation.json; one line naming file and key."""


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not strict JSON")


def read_validation(path: Path) -> dict[str, Any]:
    """The validation document in `path`, checked (see module docstring)."""
    try:
        text = read_text(path, "validation")
    except CheckedFileError as exc:
        raise ValidationFileError(f"--validation {exc}") from None
    if bracket_depth(text) > MAX_DEPTH:
        raise ValidationFileError(f"--validation {path}: nested deeper than {MAX_DEPTH} levels")
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except ValueError as exc:
        raise ValidationFileError(
            f"--validation {path}: not a validation JSON file ({quote(str(exc), 80)})"
        ) from None
    _check(path, doc)
    return doc


def _fail(path: Path, key: str, what: str) -> ValidationFileError:
    return ValidationFileError(f"--validation {path}: {key}: {what}")


def _check(path: Path, doc: Any) -> None:
    if not isinstance(doc, dict) or not isinstance(doc.get("confusion"), dict):
        raise _fail(path, "confusion", "a validation.json holds a confusion table (a mapping)")
    table = doc["confusion"]
    for key in ("columns", "rows"):
        if not _strings(table.get(key)):
            raise _fail(path, f"confusion.{key}", "must be a list of texts")
    counts = table.get("counts")
    width = len(table["columns"])
    if not (
        isinstance(counts, list)
        and len(counts) == len(table["rows"])
        and all(
            isinstance(row, list) and len(row) == width and all(_count(n) for n in row)
            for row in counts
        )
    ):
        raise _fail(path, "confusion.counts", "must be one row of counts per row, per column")
    for key in ("correct", "total"):
        if not (isinstance(table.get(key), int) and _count(table[key])):
            raise _fail(path, f"confusion.{key}", "must be a count")
    cases = doc.get("cases", [])
    if not isinstance(cases, list):
        raise _fail(path, "cases", "must be a list")
    for k, case in enumerate(cases):
        _check_case(path, f"cases[{k}]", case)


def _check_case(path: Path, where: str, case: Any) -> None:
    if not isinstance(case, dict):
        raise _fail(path, where, "must be a mapping")
    for key in (*_CASE_TEXT, "correct"):
        if key not in case or not isinstance(case[key], (str, int, float, type(None))):
            raise _fail(path, f"{where}.{key}", "must be a text or a number")
    for key in ("parameter_errors", "gap_reduction"):
        value = case.get(key)
        if value is not None and not _numbers(value):
            raise _fail(path, f"{where}.{key}", "must map names to finite numbers")
    if case.get("problems") is not None and not _strings(case["problems"]):
        raise _fail(path, f"{where}.problems", "must be a list of texts")
    elapsed = case.get("elapsed_s")
    if elapsed is not None and not (_number(elapsed)):
        raise _fail(path, f"{where}.elapsed_s", "must be a finite number")


def _strings(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def _number(value: Any) -> bool:
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and math.isfinite(value)
        and abs(value) < 1e300
    )


def _count(value: Any) -> bool:
    return value is None or (isinstance(value, int) and not isinstance(value, bool) and value >= 0)


def _numbers(value: Any) -> bool:
    return isinstance(value, Mapping) and all(
        isinstance(k, str) and _number(v) for k, v in value.items()
    )
