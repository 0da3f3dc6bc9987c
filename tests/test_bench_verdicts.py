"""Benchmark verdicts that can fail (bench/benchlib.py): every figure of bench/*.py is made by
`compare` (its printed target rendered from the comparison it enforces) or `info` (no verdict);
each operator fails a value just past its bound, NaN, infinity and a missing value; the strict
JSON table round-trips with its verdicts. Nothing is benchmarked here.
"""

from __future__ import annotations

import ast
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
sys.path.insert(0, str(BENCH))

import benchlib  # bench/ is not a package: on the path above

# bench/run_all.py reads the parts' JSON back into figures and is being moved to
# `benchlib.figure_from_row` on its own branch; until that lands it still builds them by hand

# for each operator: (bound, values that pass, values just past the bound that fail)
NEXT_UP, NEXT_DOWN = math.nextafter(1.0, 2.0), math.nextafter(1.0, 0.0)
CASES = {
    "<=": (1.0, [1.0, NEXT_DOWN, -5.0], [NEXT_UP, 1.5]),
    "<": (1.0, [NEXT_DOWN, 0.0], [1.0, NEXT_UP]),
    ">=": (1.0, [1.0, NEXT_UP, 7.0], [NEXT_DOWN, 0.5]),
    ">": (1.0, [NEXT_UP, 2.0], [1.0, NEXT_DOWN]),
    "==": (1.0, [1.0], [NEXT_UP, NEXT_DOWN]),
}
NOT_A_NUMBER = [math.nan, math.inf, -math.inf, None]


def _bench_scripts() -> list[Path]:
    return sorted(p for p in BENCH.glob("*.py") if p.name != "benchlib.py")


def _benchlib_names(tree: ast.Module, name: str) -> set[str]:
    """The local names under which a module imports `name` from benchlib."""
    return {
        alias.asname or alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and node.module == "benchlib"
        for alias in node.names
        if alias.name == name
    }


def _called(node: ast.Call) -> str:
    return node.func.id if isinstance(node.func, ast.Name) else getattr(node.func, "attr", "")


def _op_argument(call: ast.Call) -> ast.expr | None:
    """The `op` of a compare(name, value, unit, op, bound, baseline) call."""
    keyword = next((k.value for k in call.keywords if k.arg == "op"), None)
    return keyword if keyword is not None else (call.args[3] if len(call.args) > 3 else None)


def test_the_scan_covers_every_benchmark_script() -> None:
    names = {p.name for p in _bench_scripts()}
    assert {"bench_discrepancy.py", "bench_recorder.py", "bench_tables.py"} <= names
    assert len([n for n in names if n.startswith("bench_")]) == len(
        list((ROOT / "bench").glob("bench_*.py"))
    )


@pytest.mark.timeout(30)
@pytest.mark.parametrize("path", _bench_scripts(), ids=lambda p: p.name)
def test_figures_are_made_by_compare_or_info_only(path: Path) -> None:
    """No Figure(...) by hand, no `met=` anywhere, and every compare()'s operator a literal
    that benchlib knows (so the target printed is rendered from what is enforced).
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]
    by_hand = [n.lineno for n in calls if _called(n) == "Figure"]
    assert by_hand == [], f"{path.name}: Figure(...) called by hand at lines {by_hand}"
    met = [n.lineno for n in calls for k in n.keywords if k.arg == "met"]
    assert met == [], f"{path.name}: a verdict passed by hand (met=) at lines {met}"
    compares = _benchlib_names(tree, "compare")
    for call in (n for n in calls if isinstance(n.func, ast.Name) and n.func.id in compares):
        op = _op_argument(call)
        assert isinstance(op, ast.Constant) and op.value in benchlib.OPERATORS, (
            f"{path.name}:{call.lineno}: compare()'s operator must be one of "
            f"{list(benchlib.OPERATORS)} written out, got {ast.unparse(op) if op else 'none'}"
        )
        assert len(call.args) + len(call.keywords) >= 5, f"{path.name}:{call.lineno}: no bound"
    infos = _benchlib_names(tree, "info")
    for call in (n for n in calls if isinstance(n.func, ast.Name) and n.func.id in infos):
        assert len(call.args) <= 4 and not {k.arg for k in call.keywords} & {"op", "bound"}


def test_the_scan_catches_a_verdict_made_by_hand(tmp_path: Path) -> None:
    """The same scan on a script written the old way finds each offence."""
    old = (
        "from benchlib import Figure, compare\n"
        "OP = '<='\n"
        "a = Figure('x', 1.0, 's', '<= 2', True)\n"
        "b = compare('y', 1.0, 's', OP, 2.0)\n"
        "c = compare('z', 1.0, 's', '=<', 2.0)\n"
        "d = dict(met=True)\n"
    )
    tree = ast.parse(old)
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]
    assert [n.lineno for n in calls if _called(n) == "Figure"] == [3]
    assert [n.lineno for n in calls for k in n.keywords if k.arg == "met"] == [6]
    ops = [_op_argument(n) for n in calls if _called(n) in _benchlib_names(tree, "compare")]
    literal = [isinstance(o, ast.Constant) and o.value in benchlib.OPERATORS for o in ops]
    assert literal == [False, False]


@pytest.mark.timeout(10)
@pytest.mark.parametrize("op", list(CASES))
def test_each_operator_fails_a_value_past_its_bound_and_passes_one_within(op: str) -> None:
    bound, passing, failing = CASES[op]
    assert [benchlib.verdict(v, op, bound) for v in passing] == [True] * len(passing)
    assert [benchlib.verdict(v, op, bound) for v in failing] == [False] * len(failing)
    # what is not a finite number never meets a target, whichever way the comparison points
    assert [benchlib.verdict(v, op, bound) for v in NOT_A_NUMBER] == [False] * 4
    assert benchlib.compare("x", math.nan, "s", op, bound).met is False
    assert benchlib.compare("x", None, "s", op, bound).met is False


def test_an_unknown_operator_or_a_bound_that_cannot_fail_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown comparison '=<'"):
        benchlib.compare("x", 1.0, "s", "=<", 2.0)
    with pytest.raises(ValueError, match="unknown comparison"):
        benchlib.verdict(1.0, "!=", 2.0)
    for bound in (math.inf, -math.inf, math.nan):
        with pytest.raises(ValueError, match="x: the bound of a comparison must be a finite"):
            benchlib.compare("x", 1.0, "s", "<=", bound)


@pytest.mark.parametrize(
    ("op", "bound", "unit", "printed"),
    [
        ("<=", 0.04, "", "<= 0.04"),
        ("==", 0, "events", "== 0 events"),
        ("<", 500.0, "us", "< 500 us"),
        (">=", 2e6, "samples/s", ">= 2e+06 samples/s"),
        ("<=", 1e-6, "deg", "<= 1e-06 deg"),
        (">", 1.0, "deg", "> 1 deg"),
        (">=", 100.0, "% of tests", ">= 100 % of tests"),
    ],
)
def test_the_printed_target_is_the_comparison_enforced(
    op: str, bound: float, unit: str, printed: str
) -> None:
    figure = benchlib.compare("x", bound, unit, op, bound)
    assert figure.target == printed == f"{op} {bound:g} {unit}".strip()
    assert figure.is_comparison and (figure.op, figure.bound) == (op, bound)
    # moved past the bound, the verdict flips; at or inside it, it is the operator's
    step = max(abs(bound), 1.0) * 1e-3
    past = {"<=": bound + step, "<": bound, ">=": bound - step, ">": bound, "==": bound + step}
    within = {"<=": bound, "<": bound - step, ">=": bound, ">": bound + step, "==": bound}
    assert benchlib.compare("x", within[op], unit, op, bound).met is True
    assert benchlib.compare("x", past[op], unit, op, bound).met is False


def test_a_bound_is_enforced_as_printed_to_the_last_digit() -> None:
    """2/3 prints as 0.666667: a value between the two is judged against what the reader sees."""
    figure = benchlib.compare("x", 0.6666668, "x", "<=", 2 / 3)
    assert figure.target == "<= 0.666667 x" and figure.bound == 0.666667
    assert figure.met is True  # 0.6666668 <= 0.666667, though above 2/3
    assert benchlib.compare("x", 0.6666671, "x", "<=", 2 / 3).met is False


def test_an_info_figure_has_no_verdict() -> None:
    figure = benchlib.info("wall time", 12.5, "s", "reported")
    assert (figure.met, figure.target, figure.is_comparison) == (None, "info", False)
    assert benchlib.met_text(figure) == "info"
    assert benchlib.info("never measured", None, "s").met is None


def _strict(text: str) -> object:
    def refuse(constant: str) -> None:
        raise ValueError(f"not strict JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.timeout(10)
def test_the_json_table_round_trips_with_its_verdicts(tmp_path: Path) -> None:
    figures = [
        benchlib.compare("lost", 0, "messages", "==", 0, "of 20000"),
        benchlib.compare("late", 0.25, "%", "<=", 0.1),
        benchlib.compare("never measured", math.nan, "s", "<=", 5.0),
        benchlib.compare("infinitely late", math.inf, "wingbeats", "<=", 2.0),
        benchlib.compare("ratio", 1.3, "x", ">", 1.0, "a / b"),
        benchlib.info("rate", 7999.5, "msg/s", "published at 8000/s"),
        benchlib.info("not measured", math.nan, "s"),
    ]
    path = tmp_path / "bench" / "figures.json"
    benchlib.write_json(figures, path)
    rows = _strict(path.read_text())
    assert rows == _strict(json.dumps(benchlib.figure_rows(figures), allow_nan=False))
    assert [r["met"] for r in rows] == [True, False, False, False, True, None, None]
    assert [r["target"] for r in rows] == [
        "== 0 messages",
        "<= 0.1 %",
        "<= 5 s",
        "<= 2 wingbeats",
        "> 1 x",
        "info",
        "info",
    ]
    # never measured: null; measured infinite (a block never answered): "inf", told apart
    assert rows[2]["value"] is None and rows[3]["value"] == "inf" and rows[6]["value"] is None
    back = [benchlib.figure_from_row(r) for r in rows]
    assert [f.met for f in back] == [f.met for f in figures]
    assert [f.target for f in back] == [f.target for f in figures]
    assert [(f.name, f.unit, f.op, f.bound, f.baseline) for f in back] == [
        (f.name, f.unit, f.op, f.bound, f.baseline) for f in figures
    ]
    assert back[0].value == 0.0 and back[4].value == 1.3 and math.isnan(back[2].value)
    assert back[3].value == math.inf


@pytest.mark.parametrize(
    ("output", "counts"),
    [
        ("....\n4 passed in 1.20s\n", (4, 0)),
        ("..F.E\n= 1 failed, 3 passed, 1 error in 2.5s =\n", (3, 2)),
        ("2 errors in 0.31s\n", (0, 2)),
        ("3 passed, 1 skipped, 2 deselected in 61.02s (0:01:01)\n", (3, 0)),
        # a test's own output saying "9 passed" is not the summary
        ("same: 9 passed the check\n5 passed in 3.00s\n", (5, 0)),
        ("no tests ran in 0.01s\n", (0, 0)),
        ("Traceback (most recent call last):\n", (0, 0)),
    ],
)
def test_pytest_counts_reads_the_summary_line(output: str, counts: tuple[int, int]) -> None:
    assert benchlib.pytest_counts(output) == counts


def test_passed_share_fails_a_run_that_did_not_pass_every_test() -> None:
    def met(passed: int, failed: int, clean: bool = True) -> bool | None:
        return benchlib.compare(
            "tests", benchlib.passed_pct(passed, failed, clean), "%", ">=", 100.0
        ).met

    assert met(402, 0) is True
    assert met(401, 1) is False
    assert met(0, 0) is False  # nothing ran
    assert met(12, 0, clean=False) is False  # pytest stopped with no failure counted
    assert benchlib.passed_pct(3, 1, clean_exit=False) == 75.0


def _target_counters(missing: int, stalled: int = 0) -> dict:
    return {
        "fresh_samples": 300_000 - missing,
        "missing_samples": missing,
        "late_samples": 0,
        "stall_missing_samples": stalled,
        "stall_ms": 1.0,
        "stalls": 1 if stalled else 0,
        "max_lag_ms": 2.0,
    }


@pytest.mark.timeout(60)
def test_the_bridge_judges_the_monitors_late_samples_against_a_fixed_bound() -> None:
    """0.15 % late with the health monitor against 0 % without it, in runs whose windows
    scatter by +-0.35 %: 'within the noise' passed it; the fixed 0.1-point bound does not.
    """
    import bench_bridge as bb

    scattered = np.array([0.0, 0.6, 0.0, 0.6])
    with_monitor = {"target": _target_counters(450), "window_pct": scattered, "steal_s": 0.0}
    without = {"target": _target_counters(0), "window_pct": np.zeros(4), "steal_s": 0.0}
    assert bb.difference_noise_pct(scattered, np.zeros(4)) > 0.3  # the old rule's allowance
    figures = {
        f.name.split(", with")[0]: f
        for f in bb.late_figures(with_monitor, without, 0.0, 15.0, "load")
    }
    difference = next(f for f in figures.values() if "minus without" in f.name)
    assert (difference.value, difference.target, difference.met) == (
        pytest.approx(0.15),
        "<= 0.1 % points",
        False,
    )
    assert [f.met for f in figures.values() if "stalls left out" in f.name] == [False, True]
    within = {**with_monitor, "target": _target_counters(240)}  # 0.08 points more
    assert (
        next(
            f
            for f in bb.late_figures(within, without, 0.0, 15.0, "load")
            if "minus without" in f.name
        ).met
        is True
    )


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("published", "lost", "met"), [(20_000, 0, True), (20_000, 3, False), (0, 0, False)]
)
def test_the_recorder_fails_a_lost_message_and_a_scenario_that_measured_nothing(
    monkeypatch: pytest.MonkeyPatch, published: int, lost: int, met: bool
) -> None:
    """Throughput is reported (no rate target: the target is nothing lost); a lost block or
    /clock message fails, and so does a scenario in which nothing was published to count.
    """
    import bench_recorder as br

    def analysed(*_args) -> dict:
        topic = {
            "published": float(published),
            "recorded": float(published - lost),
            "lost": float(lost),
            "duplicates": 0.0,
            "first_index": 0.0,
        }
        stats = {t: dict(topic) for t in (*br.BLOCK_TOPICS, "/clock")}
        rates = {f"rate {t}": 2000.0 for t in stats}
        return stats | {"_span": {"messages": 8e4, "samples": 6e5, "span_s": 10.0, **rates}}

    monkeypatch.setattr(br, "analyse", analysed)
    run = {"crashed": {}, "reported": None, "recorder_cores": 0.4}
    figures = {f.name: f for f in br.report("graph", Path("bag"), run, 10, 20000.0, 3e4)}
    throughput = figures["[graph] recorder throughput (3 block topics + /clock)"]
    assert (throughput.met, throughput.value) == (None, 8000.0)
    for name in ("block", "/clock"):
        lost_figure = figures[f"[graph] {name} messages lost or duplicated"]
        assert (lost_figure.target, lost_figure.met) == ("== 0 messages", met)
    assert figures["[graph] recorder CPU"].met is True
