"""Strict JSON: every file FLAAIR writes parses in any JSON reader (no NaN, no Infinity)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["dumps", "json_safe"]


def json_safe(value: Any) -> Any:
    """JSON-safe copy: NaN/inf -> None, numpy scalars and arrays -> Python, tuples -> lists."""
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return [json_safe(v) for v in value.tolist()]
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (np.floating, float)):
        number = float(value)
        return number if math.isfinite(number) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def dumps(value: Any, indent: int | None = None) -> str:
    """`json.dumps` of `json_safe(value)`, refusing anything that is still not strict JSON."""
    return json.dumps(json_safe(value), indent=indent, allow_nan=False)
