"""The discovery benchmarks' rule for a tie answered by an experiment (bench/separating_run.py):
which ties it measures, the run it asks for, and the figures it prints. Nothing is analysed here:
the workflow's results are stand-ins with the fields the rule reads.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import separating_run as sr  # bench/ is not a package: on the path above

FS_HZ = 20_000.0

pytestmark = pytest.mark.timeout(30)


def _discovered(distinguishable: bool | None, separates: bool = True) -> SimpleNamespace:
    return SimpleNamespace(
        term=SimpleNamespace(kind="cube_angle", acts_on="stroke_dynamics"),
        uncertainty={
            "distinguishable": distinguishable,
            "next_best": {"term": "phi*abs(phi)"},
            "suggested_experiment": {
                "waveform": "sine",
                "drive_amplitude_v": 50.0,
                "frequency_hz": 150.0,
                "duration_s": 0.5,
                "separates": separates,
            },
        },
    )


def _result(*discovered: SimpleNamespace) -> SimpleNamespace:
    return SimpleNamespace(discovered=list(discovered))


def test_a_tie_a_run_can_separate_is_measured_with_the_suggested_sine() -> None:
    drives = []

    def measure(drive_v: np.ndarray) -> str:
        drives.append(drive_v)
        return "the extra run"

    def analyse_with(run: str) -> SimpleNamespace:
        assert run == "the extra run"
        return _result(_discovered(True))

    out = sr.separated_by_suggestion(
        _result(_discovered(False)), FS_HZ, measure, analyse_with, lambda again: True
    )
    assert out == {
        "ambiguous": True,
        "equivalent": False,
        "tied": "cube_angle@stroke_dynamics",
        "tied_with": "phi*abs(phi)",
        "suggested": "50 V at 150 Hz",
        "separated": True,
        "exact_after": True,
    }
    (drive,) = drives
    assert drive.size == round(0.5 * FS_HZ)  # the suggestion's duration
    assert np.max(np.abs(drive)) == pytest.approx(50.0, rel=1e-3)
    # 150 Hz: 75 cycles in 0.5 s, two zero crossings a cycle
    assert np.count_nonzero(np.diff(np.sign(drive[drive != 0.0])) != 0) == pytest.approx(150, abs=2)


def test_a_run_that_leaves_a_form_tied_is_not_separated() -> None:
    out = sr.separated_by_suggestion(
        _result(_discovered(False)),
        FS_HZ,
        lambda drive_v: None,
        lambda run: _result(_discovered(True), _discovered(False)),
        lambda again: False,
    )
    assert out["ambiguous"] and not out["separated"] and not out["exact_after"]


def test_no_tie_and_an_equivalent_tie_run_nothing() -> None:
    def never(_: object) -> None:
        raise AssertionError("no run is measured without a tie a run can separate")

    assert sr.separated_by_suggestion(
        _result(_discovered(True), _discovered(None)), FS_HZ, never, never, never
    ) == {"ambiguous": False, "equivalent": False}
    out = sr.separated_by_suggestion(
        _result(_discovered(False, separates=False)), FS_HZ, never, never, never
    )
    assert out == {
        "ambiguous": False,
        "equivalent": True,
        "tied": "cube_angle@stroke_dynamics",
        "tied_with": "phi*abs(phi)",
    }


def _count(k: int, n: int, noun: str) -> str:
    return f"({k}/{n} {noun})"


def test_the_figures_count_the_tied_robots_and_enforce_more_than_half() -> None:
    tie = {"tied": "a@s", "tied_with": "b", "suggested": "50 V at 150 Hz", "exact_after": False}
    outcomes = [
        {"ambiguous": True, "equivalent": False, "separated": True, "name": "r0"} | tie,
        {"ambiguous": True, "equivalent": False, "separated": False, "name": "r1"} | tie,
        {"ambiguous": False, "equivalent": True, "name": "r2"} | tie,
        {"ambiguous": False, "equivalent": False, "name": "r3"},
    ]
    separated, equivalent = sr.separation_figures(outcomes, "x", _count, lambda o: o["name"])
    assert separated.name == (
        "x: tied forms told apart by the suggested run (1/2 robots tied that a run can tell apart)"
    )
    assert separated.value == 50.0 and separated.target == ">= 50 %" and separated.met
    assert separated.baseline.startswith("exactly right after the run: 0/2; r0: a@s vs b")
    assert "r0: a@s vs b, 50 V at 150 Hz, told apart" in separated.baseline
    assert "r1: a@s vs b, 50 V at 150 Hz, still tied" in separated.baseline
    assert equivalent.value == 1.0 and equivalent.met is None
    assert equivalent.name == "x: tied forms the same on every run tried (1/4 robots)"
    one_of_three = sr.separation_figures(
        outcomes[1:2] + outcomes[1:2] + outcomes[:1], "x", _count, lambda o: o["name"]
    )[0]
    assert one_of_three.value == pytest.approx(100 / 3) and not one_of_three.met


def test_without_a_tie_the_figure_is_info() -> None:
    separated, _ = sr.separation_figures(
        [{"ambiguous": False, "equivalent": False}], "x", _count, str
    )
    assert separated.met is None and math.isnan(separated.value)
