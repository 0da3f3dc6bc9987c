"""`discrepancy --table` on tables the simulated robot makes (reading noise, missing pitch cells):
a robot with no missing effect ends `no_discrepancy`, an amplitude-dependent effect is named
and the held-out gap shrinks, a one-level table is fitted but not searched.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from flaair_analysis.tables.datasets import simulated_table
from flaair_analysis.tables.workflow import NOT_SEARCHED, analyse_table
from flaair_model import settings
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.terms import DiscoveredTerm
from flaair_tools.discrepancy.cli import main as discrepancy_main
from flaair_tools.tables.table_io import write_table

FREQS = np.linspace(90.0, 240.0, 14)
LEVELS = (20.0, 40.0, 60.0)


def robot():
    m = load_model()
    plant = replace(
        m.plant,
        stroke_natural_frequency_hz=150.0,
        aero_damping_nm_s2=4.4e-11,
        actuator_gain_nm_per_v=1.8e-7,
    )
    return m, replace(m, plant=plant)


@pytest.mark.slow  # the table workflow's whole search, judged on held-out levels
@pytest.mark.timeout(400)
def test_a_robot_without_a_missing_effect_ends_no_discrepancy() -> None:
    s = settings.tables()
    nominal, true = robot()
    table = simulated_table(true, LEVELS, FREQS, s, np.random.default_rng(11), missing_pitch=0.3)
    r = analyse_table(table, nominal, s)
    assert r.status == "no_discrepancy" and r.accepted == []
    assert r.model_out.plant.stroke_natural_frequency_hz == pytest.approx(150.0, rel=0.005)
    for c in ("stroke_pp_deg", "pitch_pp_deg"):
        assert r.gaps["gap_before"][c] > 0.1  # the configured robot is 7 % off in frequency
        assert r.noise_ratio["gap_identified"][c] < s.gap_ratio


@pytest.mark.slow  # the table discrepancy command end to end
@pytest.mark.timeout(600)
def test_hinge_stiffening_is_named_and_the_heldout_gap_shrinks(tmp_path: Path) -> None:
    s = settings.tables()
    _, true = robot()
    true = with_effects(true, {"hinge_stiffening": {"cubic_per_rad2": 3.0}})
    table = simulated_table(true, LEVELS, FREQS, s, np.random.default_rng(12), missing_pitch=0.3)
    path = tmp_path / "hinge.csv"
    write_table(table, path)
    out = tmp_path / "out"
    assert discrepancy_main(["--table", str(path), "--out", str(out)]) == 0
    doc = json.loads((out / "discrepancy.json").read_text())
    # The right effect at 2.90 (3.3 % off), but on 14 frequencies the pitch's held-out levels keep
    # 1.58x their noise (the gap rule's limit is 1.5x), so the honest status is `unexplained`
    # (the 20-frequency tables of the benchmark end `explained`)
    assert doc["status"] == "unexplained"
    assert [e["name"] for e in doc["effects"]] == ["hinge_stiffening"]
    assert doc["discovered"] == []
    value = doc["effects"][0]["parameters"]["cubic_per_rad2"]["value"]
    assert value == pytest.approx(3.0, rel=0.05)
    gaps = [doc[k]["pitch_pp_deg"] for k in ("gap_before", "gap_identified", "gap_after")]
    assert gaps[0] > gaps[1] > 2 * gaps[2]
    assert set(doc["not_searched"]) >= {"sensor_delay", "charge_amp_highpass", "wing_damage"}
    assert "no time axis" in doc["not_searched"]["sensor_delay"]
    assert load_model(out / "model.yaml").effect("hinge_stiffening") is not None
    html = (out / "report.html").read_text()
    assert "table_response.png" in html and (out / "table_response.png").stat().st_size > 10_000


@pytest.mark.timeout(200)
def test_one_level_is_fitted_not_searched_and_bad_input_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = settings.tables()
    nominal, true = robot()
    table = simulated_table(true, (40.0,), FREQS, s, np.random.default_rng(13))
    r = analyse_table(table, nominal, s)
    assert not r.searched and r.accepted == []
    assert any("needs two or more" in n for n in r.notes)
    assert r.model_out.plant.stroke_natural_frequency_hz == pytest.approx(150.0, rel=0.01)
    assert "sensor_delay" in NOT_SEARCHED and "structural_damping" not in NOT_SEARCHED
    bad = tmp_path / "bad.csv"
    bad.write_text("drive_pp_v,frequency_hz,stroke_pp_deg\n80,150,3\n400,160,4\n")
    out = tmp_path / "out"
    assert discrepancy_main(["--table", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "line 3, column 'drive_pp_v'" in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.slow  # the table workflow's whole search
@pytest.mark.timeout(600)
def test_hinge_stiffening_is_found_where_the_effectless_pitch_fit_runs_far() -> None:
    # Without the effect, this robot's pitch plant fits at ~350 Hz (true 190 Hz) with its
    # couplings on their bounds; the joint fit of the effect must be free to bring them back
    # (before: boxed within x/÷ 1.5 of that fit, it ended at 1.5 +- 0.6, refused)
    s = settings.tables()
    nominal = load_model()
    plant = replace(
        nominal.plant,
        stroke_natural_frequency_hz=134.5,
        aero_damping_nm_s2=3.7e-11,
        actuator_gain_nm_per_v=1.89e-7,
    )
    true = with_effects(
        replace(nominal, plant=plant), {"hinge_stiffening": {"cubic_per_rad2": 3.2}}
    )
    freqs = np.linspace(0.6 * 134.5, 1.6 * 134.5, 20)
    table = simulated_table(true, LEVELS, freqs, s, np.random.default_rng(1), missing_pitch=0.3)
    r = analyse_table(table, nominal, s)
    assert r.identified.plant.pitch_natural_frequency_hz > 300.0  # the effect-less fit ran far
    assert [j.candidate.name for j in r.accepted] == ["hinge_stiffening"]
    j = r.accepted[0]
    # measured 3.256 (1.8 % off)
    assert j.fit.values["effect.hinge_stiffening.cubic_per_rad2"] == pytest.approx(3.2, rel=0.05)
    assert j.z > s.rules.min_z
    assert j.fit.values["plant.pitch_natural_frequency_hz"] == pytest.approx(190.0, rel=0.05)
    assert r.status == "explained"


@pytest.mark.slow  # the table workflow's whole search with the terms
@pytest.mark.timeout(900)
def test_a_strong_dry_friction_wins_over_the_structural_damping_that_also_passes() -> None:
    # Both lower the peak; a dry friction lowers the small drive levels relatively more. The
    # structural damping passes the held-out rule but leaves the stroke a gap, so the terms are
    # judged too and the lowest held-out error wins (before: the damping was kept, the friction
    # never judged)
    s = settings.tables()
    nominal, true = robot()
    friction = DiscoveredTerm("sign_velocity", "stroke_dynamics", -1.5e-6)
    true = replace(true, discovered=(friction,))
    table = simulated_table(true, LEVELS, FREQS, s, np.random.default_rng(14), missing_pitch=0.3)
    r = analyse_table(table, nominal, s)
    assert [j.candidate.name for j in r.accepted] == ["sign_velocity@stroke_dynamics"]
    j = r.accepted[0]
    # measured -1.486e-6 (1.0 % off)
    assert j.fit.values["term.sign_velocity@stroke_dynamics"] == pytest.approx(-1.5e-6, rel=0.02)
    damping = [t for t in r.tried if t.candidate.name == "structural_damping"]
    assert damping and not damping[0].failed  # it passes the rule, and loses on held-out error
    assert damping[0].heldout_error > 2 * j.heldout_error
    assert max(v or 0.0 for v in damping[0].heldout_ratio.values()) > s.gap_ratio
    assert r.noise_ratio["gap_identified"]["stroke_pp_deg"] > 3 * s.gap_ratio
    assert r.noise_ratio["gap_after"]["stroke_pp_deg"] < s.gap_ratio
    # the pitch plant, refitted after the friction within x/÷ 1.5 of its effect-less fit, keeps
    # a gap here (2.4x noise, from 4.0x): the stroke side is what this checks
    assert (
        r.noise_ratio["gap_after"]["pitch_pp_deg"] < r.noise_ratio["gap_identified"]["pitch_pp_deg"]
    )
