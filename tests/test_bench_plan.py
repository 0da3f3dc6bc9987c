"""The benchmark's plan: `make bench` and `make bench-full` run every part with a budget, the
discrepancy subset is the one docs/TESTING.md names, and no figure of the full run is missing
from the subset run (bench/run_all.py, bench/bench_discrepancy.py). Nothing is analysed here.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import bench_discrepancy as bd  # bench/ is not a package: on the path above
import bench_tables as bt
import run_all
from flaair_analysis.discrepancy.datasets import dataset_cases
from flaair_analysis.discrepancy.offnominal import (
    DISCOVER_KINDS,
    FAMILIES,
    random_robot,
)
from flaair_analysis.discrepancy.scoring import CaseOutcome

TESTING_MD = ROOT / "docs" / "TESTING.md"
# The discrepancy figures `make bench` printed before it had a subset (names without counts).
DISCREPANCY_FIGURES = {
    "exactly right, offnominal_null",
    "exactly right, offnominal_single",
    "exactly right, offnominal_pair",
    "exactly right, offnominal_outside",
    "exactly right, offnominal_discover",
    "exactly right, parameters within 10 %, offnominal_own",
    "discovery: tied forms told apart by the suggested run",
    "discovery: tied forms the same on every run tried",
    "discovery: composed forms ranked in a step",
    "discovery: right acts_on and form among others",
    "robots with a term the truth lacks, every family",
    "discovery: ending explained",
    "discovery: time per robot",
    "false discoveries of terms on no-effect robots",
    "false discoveries on no-effect robots",
    "out-of-vocabulary robots flagged unexplained",
    "named effects with parameters within 10 %",
    "stroke_natural_frequency_hz within 0.5 %",
    "pitch_natural_frequency_hz within 0.5 %",
    "time per robot data set",
    "hidden-effect dataset cases right",
}


def test_every_benchmark_is_a_part_with_a_budget_in_both_modes() -> None:
    scripts = sorted(p.stem for p in (ROOT / "bench").glob("bench_*.py"))
    names = [p.name for p in run_all.PARTS]
    assert sorted(names) == scripts
    assert len(set(names)) == len(names)
    assert all(p.budget_s > 0 and p.full_budget_s >= p.budget_s for p in run_all.PARTS)
    assert sum(p.budget_s for p in run_all.PARTS) <= run_all.BENCH_BUDGET_S == 20 * 60


def test_only_the_discrepancy_parts_and_the_live_runs_differ_between_the_modes() -> None:
    """Every other part prints the same figures in both modes because it runs the same (the
    tables' part runs one robot of every family in both: its right-effect and false-discovery
    figures are over the whole family set); the independent truth's runs one robot of each kind
    in `make bench`; the live runs are three pairs of 60 s in `make bench-full` (each judged by
    the same targets as `make bench`'s one pair of 15 s); the plant's cold numba compile (an
    `info` figure, about a minute) is timed in `make bench-full` only.
    """
    differ = {p.name: (p.args, p.full_args) for p in run_all.PARTS if p.args != p.full_args}
    assert differ == {
        "bench_discrepancy": (("--subset", "--sweep"), ("--sweep",)),
        "bench_truth": (("--subset",), ()),
        "bench_bridge": (("--duration", "15"), ("--duration", "60", "--runs", "3")),
        "bench_sim": ((), ("--cold-compile",)),
    }
    tables = next(p for p in run_all.PARTS if p.name == "bench_tables")
    assert "--families" not in tables.args  # every family of bench_tables.FAMILIES
    assert {"none", "drive_cube@drive", "sign_velocity@stroke_dynamics"} <= set(bt.FAMILIES)


def _documented_subset() -> tuple[dict[str, tuple[int, ...]], tuple[str, ...], int]:
    text = TESTING_MD.read_text()
    rows = re.findall(r"^\| `(offnominal_\w+)` \| ([\d, ]+) \|", text, flags=re.M)
    cases = re.search(r"Hidden-effect cases in `make bench`: (.+?) \(", text, flags=re.S)
    baseline = re.search(r"baseline runs on each family's first subset robot \((\d+) per", text)
    assert rows and cases and baseline, "docs/TESTING.md no longer lists the subset"
    return (
        {family: tuple(int(d) for d in draws.split(",")) for family, draws in rows},
        tuple(re.findall(r"`(\w+)`", cases.group(1))),
        int(baseline.group(1)),
    )


def test_the_subset_is_the_one_the_docs_name() -> None:
    draws, cases, baseline = _documented_subset()
    assert draws == bd.SUBSET
    assert cases == bd.SWEEP_SUBSET
    assert baseline == bd.SUBSET_BASELINE


def test_the_subset_is_drawn_by_its_seed_from_every_family() -> None:
    """Not chosen around a known miss: each family's robots and the hidden-effect cases are the
    seed's draw from the full run's, and another seed draws others.
    """
    assert bd.draw_subset(bd.SUBSET_SEED) == bd.SUBSET
    assert set(bd.SUBSET) == set(FAMILIES) == set(bd.FULL_DRAWS)
    for family, draws in bd.SUBSET.items():
        assert len(draws) == bd.SUBSET_SIZES[family] == len(set(draws))
        assert all(0 <= d < bd.FULL_DRAWS[family] for d in draws)
    assert bd.FULL_DRAWS["offnominal_discover"] == 10 * len(DISCOVER_KINDS)
    all_cases = tuple(c.name for c in dataset_cases())
    own = tuple(c.name for c in dataset_cases() if "actuator_hysteresis" in c.effect_names)
    assert own == ("hysteresis_0p3_10v",) and len(bd.SWEEP_POOL) == 45
    assert tuple(c for c in all_cases if c not in own) == bd.SWEEP_POOL
    assert bd.draw_sweep_subset(bd.SWEEP_POOL, bd.SUBSET_SEED) == bd.SWEEP_SUBSET
    assert len(bd.SWEEP_SUBSET) == bd.SWEEP_SUBSET_SIZE and set(bd.SWEEP_SUBSET) <= set(all_cases)
    assert bd.draw_subset(bd.SUBSET_SEED + 1) != bd.SUBSET


def test_the_jobs_of_each_mode() -> None:
    families = list(FAMILIES)
    subset = bd.select_jobs(families, 30, 60, 5, subset=True)
    assert [(f, d) for f, d, _ in subset] == [(f, d) for f in FAMILIES for d in bd.SUBSET[f]]
    assert sum(b for *_, b in subset) == bd.SUBSET_BASELINE * (len(FAMILIES) - 1)
    full = bd.select_jobs(families, 30, 60, 5, subset=False)
    assert len(full) == 5 * 30 + 60 and sum(b for *_, b in full) == 5 * 5
    assert bd.select_cases(subset=True) == bd.SWEEP_SUBSET
    assert len(bd.select_cases(subset=False)) == len(dataset_cases()) == 46


def _outcome(family: str, draw: int) -> dict:
    """A robot's outcome as `analyse_robot` returns it, every answer right."""
    case = random_robot(family, draw)
    terms = [f"{t.kind}@{t.acts_on}" for t in case.terms]
    return {
        "family": family,
        "case": case.name,
        "exact": True,
        "problems": [],
        "found": sorted(case.effect_names),
        "status": case.expected_status,
        "outside": case.outside,
        "true_terms": terms,
        "discovered": terms,
        "term_errors": {f"{t.kind}.coefficient": 0.01 for t in case.terms},
        "effect_parameters_ok": dict.fromkeys(case.effect_names, True),
        "parameter_errors": {f"{n}.x": 0.01 for n in case.effect_names},
        "frequency_errors": dict.fromkeys(bd.FREQUENCIES, 0.001),
        "elapsed_s": 1.0,
    }


def _case_outcome(name: str) -> CaseOutcome:
    return CaseOutcome(name, "x", "x", "explained", "explained", (), {}, {}, True, (), 1.0)


@pytest.mark.parametrize("subset", [True, False], ids=["make bench", "make bench-full"])
def test_every_figure_of_today_is_printed_in_both_modes(subset: bool) -> None:
    jobs = bd.select_jobs(list(FAMILIES), 30, 60, 5, subset)
    figures = bd.build_figures(
        [_outcome(f, d) for f, d, _ in jobs],
        [{"family": f, "exact": False} for f, _, b in jobs if b],
        [_case_outcome(name) for name in bd.select_cases(subset)],
        families=list(FAMILIES),
        jobs=2,
        wall_s=60.0,
        t_sim_s=0.003,
        subset=subset,
    )
    stems = {bd.figure_stem(f.name) for f in figures}
    # today's figures, and per discovery kind (right form, explained, error, time)
    assert stems >= DISCREPANCY_FIGURES
    assert {s for s in stems - DISCREPANCY_FIGURES if not s.startswith("discovery, kind ")} == set()
    # one more per discovery kind in the run (make bench: the subset's kinds)
    kinds = {
        (t.kind, t.acts_on)
        for f, d, _ in jobs
        if f == "offnominal_discover"
        for t in random_robot(f, d).terms
    }
    assert len(kinds) == (
        len(
            {
                (t.kind, t.acts_on)
                for d in bd.SUBSET["offnominal_discover"]
                for t in random_robot("offnominal_discover", d).terms
            }
        )
        if subset
        else len(DISCOVER_KINDS)
    )
    assert len(stems - DISCREPANCY_FIGURES) == len(kinds)
    # every percentage says how many it is of, and a subset says so
    for f in figures:
        if f.unit.startswith("%"):
            assert re.search(r"\(\d+/\d+[ ,)]", f.name), f.name
        assert f.name.endswith(", subset)") == subset, f.name


@pytest.mark.timeout(30)
def test_compare_runs_meets_the_same_figure_in_both_modes(tmp_path: Path, capsys) -> None:
    import compare_runs

    quick = [
        {
            "name": "exactly right, offnominal_single (9/9 robots, subset)",
            "value": 100.0,
            "unit": "%",
            "target": ">= 90 %",
            "met": True,
        },
        {
            "name": "discovery: time per robot (max of 9, subset)",
            "value": 100.0,
            "unit": "s",
            "target": "<= 120 s",
            "met": True,
        },
        {"name": "sim step", "value": 1.0, "unit": "ms", "target": "< 2", "met": True},
    ]
    full = [
        {**quick[0], "name": "exactly right, offnominal_single (29/30 robots)", "value": 96.7},
        {**quick[1], "name": "discovery: time per robot (max of 60)", "value": 130.0, "met": False},
        {"name": "only full", "value": 1.0, "unit": "", "target": "", "met": True},
    ]
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(quick))
    b.write_text(json.dumps(full))
    assert compare_runs.main([str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("2 figures in both; 3 moved")
    assert "discovery: time per robot: 100.0 s (met;" in out and "-> 130.0 s (NOT met;" in out
    assert "only in the first: sim step" in out and "only in the second: only full" in out
    # within 5 %: not reported
    assert "exactly right, offnominal_single:" not in out
    a.write_text("{not json")
    assert compare_runs.main([str(a), str(b)]) == 2
    assert "a.json: not a readable benchmark table" in capsys.readouterr().err


def test_the_whole_runs_wall_time_is_a_figure_against_its_target() -> None:
    """`make bench` compares its wall time with 15 min (the figure is counted: a miss shows);
    `make bench-full` only reports it.
    """
    assert run_all.BENCH_TARGET_S == 15 * 60
    over, under = run_all.wall_figure(16 * 60.0, False), run_all.wall_figure(14 * 60.0, False)
    assert (over.value, over.met, under.met) == (16.0, False, True)
    assert run_all.wall_figure(16 * 60.0, True).met is None
