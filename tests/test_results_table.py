"""Published figures are generated: the README's and the guides' tables are the rendering of the
newest results file (bench/results_table.py), and `make test` fails when they are not.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import results_table as rt  # bench/ is not a package: on the path above
import run_all
from benchlib import compare, info

pytestmark = pytest.mark.timeout(60)


def test_the_published_tables_are_the_newest_results_rendered() -> None:
    """README.md and the guides hold exactly what `python bench/results_table.py` renders."""
    assert rt.main(["--check"]) == 0


def _results(tmp_path: Path, figures, name="2026-11-29-abc1234567.json") -> Path:
    times = [(run_all.PARTS[0], 12.0, True)]
    doc = run_all.results_document(
        "make bench-full", [("bench_discrepancy", figures)], times, 600.0, True
    )
    doc["commit"], doc["date"] = "abc1234567", "2026-11-29"
    path = tmp_path / "docs" / "results" / name
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(doc, allow_nan=False))
    return path


def _documents(tmp_path: Path) -> None:
    for block in rt.BLOCKS:
        doc = tmp_path / block.document
        doc.parent.mkdir(parents=True, exist_ok=True)
        text = doc.read_text() if doc.exists() else "# doc\n\ntext before\n"
        begin, end = (m.format(name=block.name) for m in rt.MARKERS)
        doc.write_text(f"{text}{begin}\nold typed numbers\n{end}\ntext after\n")


def test_a_failing_comparison_renders_as_not_met_and_info_is_not_counted(tmp_path: Path) -> None:
    figures = [
        compare("exactly right, offnominal_single (27/30 robots)", 90.0, "%", ">=", 90.0),
        compare("exactly right, offnominal_pair (26/30 robots)", 86.7, "%", ">=", 90.0, "x"),
        info("discovery: right acts_on and form among others (88/90)", 97.8, "%", "y"),
        compare("time per robot (max of 2)", math.inf, "s", "<=", 60.0, "one never ended"),
    ]
    path = _results(tmp_path, figures)
    _documents(tmp_path)
    docs = rt.render_all(path, root=tmp_path)
    readme = docs[tmp_path / "README.md"][1]
    assert "| exactly right, offnominal_pair (26/30 robots) | 86.7 % | >= 90 % | NO |" in readme
    assert "| exactly right, offnominal_single (27/30 robots) | 90 % | >= 90 % | yes |" in readme
    assert "1 of 2 comparisons shown here met" in readme and "old typed numbers" not in readme
    assert f"commit `abc1234567` on 2026-11-29, {os.cpu_count()} cores (" in readme
    guide = docs[tmp_path / "docs" / "DISCREPANCY.md"][1]
    assert "| 97.8 % | info | info | y |" in guide
    # measured infinite (stored "inf") is not "not measured" (stored null)
    assert "| time per robot (max of 2) | infinite s | <= 60 s | NO | one never ended |" in guide
    assert guide.endswith("text after\n") and "text before" in guide


def test_check_fails_when_a_published_number_was_typed(tmp_path: Path, monkeypatch) -> None:
    path = _results(tmp_path, [compare("exactly right, offnominal_null (2/2)", 100, "%", ">=", 90)])
    _documents(tmp_path)
    monkeypatch.setattr(rt, "REPO_ROOT", tmp_path)
    monkeypatch.setattr(rt, "RESULTS_DIR", path.parent)
    real_render = rt.render_all
    monkeypatch.setattr(rt, "render_all", lambda p: real_render(p, root=tmp_path))
    assert rt.main(["--check"]) == 1  # the typed block differs
    assert rt.main([]) == 0  # rendered
    assert rt.main(["--check"]) == 0
    readme = tmp_path / "README.md"
    readme.write_text(readme.read_text().replace("| 100 % |", "| 100.0 % |"))  # typed by hand
    assert rt.main(["--check"]) == 1


def test_a_document_without_its_markers_or_a_bad_results_file_is_refused(
    tmp_path: Path, capsys
) -> None:
    with pytest.raises(rt.ResultsError, match="needs exactly one"):
        rt.replace_block("no markers here", "readme", "x", "README.md")
    bad = tmp_path / "2026-11-29-abc.json"
    bad.write_text("{not json")
    with pytest.raises(rt.ResultsError, match="not a readable results file"):
        rt.load_results(bad)
    bad.write_text(json.dumps({"mode": "make bench"}))
    with pytest.raises(rt.ResultsError, match="missing commit"):
        rt.load_results(bad)


def test_results_file_names_its_run_and_holds_strict_json(tmp_path: Path) -> None:
    figures = [compare("t", float("nan"), "s", "<=", 1.0), info("i", 2.0, "x")]
    doc = run_all.results_document("make bench", [("bench_sim", figures)], [], 60.0, False)
    text = json.dumps(doc, allow_nan=False)  # a NaN figure is null, not NaN
    back = json.loads(text)
    assert back["figures"][0]["value"] is None and back["figures"][0]["met"] is False
    assert back["figures"][1]["met"] is None and back["figures"][1]["target"] == "info"
    assert {"cores", "cpu_model"} <= set(back["machine"]) and back["wall_s"] == 60.0
    assert run_all.results_path(doc, tmp_path).name == f"{doc['date']}-{doc['commit']}-subset.json"
    assert run_all.comparisons_met(figures) == (0, 1)
