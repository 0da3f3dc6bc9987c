"""Tiny benchmark reporting: each figure beside its target and its same-run baseline."""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
for _package_dir in sorted((REPO_ROOT / "src").iterdir()):
    if (_package_dir / "setup.py").exists() and str(_package_dir) not in sys.path:
        sys.path.insert(0, str(_package_dir))


@dataclass
class Figure:
    """One benchmark figure."""

    name: str
    value: float
    unit: str
    target: str
    met: bool
    baseline: str = ""


def best_time_s(fn: Callable[[], object], repeats: int = 3) -> float:
    """Best wall time of `repeats` calls (shared noisy machine: best-of is the stable figure)."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def print_table(figures: list[Figure]) -> None:
    """Print figures as an aligned table."""
    print(f"{'benchmark':52s} {'value':>14s} {'unit':10s} {'target':18s} {'met':4s} baseline")
    for f in figures:
        print(
            f"{f.name:52s} {f.value:14.4g} {f.unit:10s} {f.target:18s} "
            f"{'yes' if f.met else 'NO':4s} {f.baseline}"
        )


def write_json(figures: list[Figure], path: Path) -> None:
    """Write figures as JSON (a list of objects)."""
    path.parent.mkdir(parents=True, exist_ok=True)

    # numpy scalars (np.bool_ from a comparison, np.float64) are written as plain numbers; strict
    # JSON: a NaN or infinite figure (not measured, never answered) is null
    def plain(value):
        value = value.item() if hasattr(value, "item") else value
        if isinstance(value, float) and not math.isfinite(value):
            return None
        return value if isinstance(value, (str, int, float, bool, type(None))) else str(value)

    rows = [{key: plain(value) for key, value in asdict(f).items()} for f in figures]
    path.write_text(json.dumps(rows, indent=2, allow_nan=False))
