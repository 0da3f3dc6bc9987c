"""Benchmark figures: each one a comparison that can fail, or `info`.

A figure is made by one of two functions, never by hand:
- `compare(name, value, unit, op, bound)`: a verdict. The target printed is rendered from `op`
  and `bound` by `target_text`, and the verdict is `verdict(value, op, bound)`, so the target a
  reader sees is exactly the one enforced (no slack, no second rule). A value that is not a
  finite number fails every comparison;
- `info(name, value, unit)`: printed, never counted as met or not.
`run_all.py` counts comparisons only ("N of M comparisons met").
"""

from __future__ import annotations

import json
import math
import operator
import re
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numba

REPO_ROOT = Path(__file__).resolve().parents[1]
for _package_dir in sorted((REPO_ROOT / "src").iterdir()):
    if (_package_dir / "setup.py").exists() and str(_package_dir) not in sys.path:
        sys.path.insert(0, str(_package_dir))

# The comparisons a target may make: value OP bound.
OPERATORS: dict[str, Callable[[float, float], bool]] = {
    "<=": operator.le,
    "<": operator.lt,
    ">=": operator.ge,
    ">": operator.gt,
    "==": operator.eq,
}


@dataclass(frozen=True)
class Figure:
    """One benchmark figure (made by `compare` or `info`).

    Attributes
    ----------
    name, value, unit : what was measured.
    op, bound : the comparison enforced (`value op bound`); both None for an `info` figure.
    baseline : the same-run baseline or context, printed beside.
    """

    name: str
    value: float
    unit: str
    op: str | None = None
    bound: float | None = None
    baseline: str = ""

    @property
    def is_comparison(self) -> bool:
        """Whether the figure carries a verdict."""
        return self.op is not None

    @property
    def target(self) -> str:
        """The target as printed: rendered from the comparison enforced."""
        return target_text(self.op, self.bound, self.unit) if self.op is not None else "info"

    @property
    def met(self) -> bool | None:
        """The verdict (None for `info`)."""
        if self.op is None or self.bound is None:
            return None
        return verdict(self.value, self.op, self.bound)


def verdict(value: float, op: str, bound: float) -> bool:
    """`value op bound`; a NaN, infinite or missing value never meets a target."""
    if op not in OPERATORS:
        raise ValueError(f"unknown comparison {op!r} (known: {', '.join(OPERATORS)})")
    if value is None or not math.isfinite(float(value)):
        return False
    return bool(OPERATORS[op](float(value), float(bound)))


def target_text(op: str | None, bound: float | None, unit: str) -> str:
    """The printed target of a comparison: '<= 60 s', '>= 90 %', '== 0 cases'."""
    if op is None or bound is None:
        return "info"
    return f"{op} {bound:g} {unit}".strip()


def compare(
    name: str, value: float, unit: str, op: str, bound: float, baseline: str = ""
) -> Figure:
    """A figure with a verdict: met iff `value op bound`.

    The bound is kept as printed (`bound:g`, six significant digits), so the target a reader sees
    is the one enforced to the last digit; a bound that is not a finite number is refused (a
    `<= inf` could never fail).
    """
    if op not in OPERATORS:
        raise ValueError(f"unknown comparison {op!r} (known: {', '.join(OPERATORS)})")
    if not math.isfinite(float(bound)):
        raise ValueError(f"{name}: the bound of a comparison must be a finite number, got {bound}")
    return Figure(name, _number(value), unit, op, float(f"{float(bound):g}"), baseline)


def info(name: str, value: float, unit: str, baseline: str = "") -> Figure:
    """A figure without a verdict: printed, never counted."""
    return Figure(name, _number(value), unit, None, None, baseline)


def _number(value: object) -> float:
    value = value.item() if hasattr(value, "item") else value
    return float(value) if value is not None else math.nan  # type: ignore[arg-type]


def pytest_counts(output: str) -> tuple[int, int]:
    """(passed, failed or errored) from pytest's summary line (the last of `output` that reads
    'N passed, M failed ... in T s'); (0, 0) without one.
    """
    summary = next(
        (
            line
            for line in reversed(output.splitlines())
            if re.search(r"\d+ (passed|failed|errors?|skipped|deselected)\b", line)
            and re.search(r"\bin [\d.]+s\b", line)
        ),
        "",
    )
    counts = {k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|errors?)\b", summary)}
    return counts.get("passed", 0), sum(counts.get(k, 0) for k in ("failed", "error", "errors"))


def passed_pct(passed: int, failed: int, clean_exit: bool = True) -> float:
    """Share of the tests run that passed (%), for a `>= 100 %` comparison.

    NaN (which fails every comparison) when no test ran, or when the run did not end cleanly
    (`clean_exit` False: pytest's exit code not 0) with no failure counted, so an interrupted or
    unparsed run never reads as all passed.
    """
    if passed + failed == 0 or (not clean_exit and failed == 0):
        return math.nan
    return 100.0 * passed / (passed + failed)


def one_numba_thread() -> None:
    """A process pool worker's initializer: numba's parallel loops on one thread (one worker per
    core, each running the plant's batch on every core, would oversubscribe the machine).
    """
    numba.set_num_threads(1)


def best_time_s(fn: Callable[[], object], repeats: int = 3) -> float:
    """Best wall time of `repeats` calls (shared noisy machine: best-of is the stable figure)."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def met_text(figure: Figure) -> str:
    """'yes', 'NO' or 'info'."""
    return "info" if figure.met is None else ("yes" if figure.met else "NO")


def print_table(figures: list[Figure]) -> None:
    """Print figures as an aligned table."""
    print(f"{'benchmark':52s} {'value':>14s} {'unit':10s} {'target':18s} {'met':4s} baseline")
    for f in figures:
        print(
            f"{f.name:52s} {f.value:14.4g} {f.unit:10s} {f.target:18s} "
            f"{met_text(f):4s} {f.baseline}"
        )


def figure_rows(figures: list[Figure]) -> list[dict]:
    """Figures as strict-JSON rows: the stored fields and the rendered target and verdict."""

    def plain(value):
        # strict JSON: an infinite figure (measured: e.g. a latency of a block never answered) as
        # the string "inf" / "-inf", a NaN one (never measured) as null
        if isinstance(value, float) and not math.isfinite(value):
            return None if math.isnan(value) else str(value)
        return value

    return [
        {key: plain(value) for key, value in asdict(f).items()} | {"target": f.target, "met": f.met}
        for f in figures
    ]


def figure_from_row(row: dict) -> Figure:
    """A figure read back from `figure_rows` (a null value is a figure never measured, "inf" or
    "-inf" an infinite one).
    """
    value = row.get("value")
    return Figure(
        str(row["name"]),
        math.nan if value is None else float(value),
        str(row.get("unit", "")),
        row.get("op"),
        None if row.get("bound") is None else float(row["bound"]),
        str(row.get("baseline", "")),
    )


def write_json(figures: list[Figure], path: Path) -> None:
    """Write figures as strict JSON (a list of objects; a NaN figure is null, an infinite one
    "inf" or "-inf").
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(figure_rows(figures), indent=2, allow_nan=False))
