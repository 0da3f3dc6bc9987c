"""Runs and a table of the same robot in one plant fit (`flaair_analysis.tables.joint`,
`identify RUN... --table`, `discrepancy RUN... --table`).

The robot is the configured one with its stroke resonance 6 % higher, its damping 10 % lower,
its gain 8 % higher and its pitch resonance 4 % lower. Its runs are chirps through the
simulator with sensor and tracking noise (`synthesize_measured_run`); its table 3 drive levels x
12 frequencies read as from video (`simulated_table`).
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from flaair_analysis.discrepancy.diagnosis import noise_estimates
from flaair_analysis.discrepancy.identification import identify_plant
from flaair_analysis.discrepancy.runs import Run, check_runs, simulate_runs
from flaair_analysis.exact_score import score_exact, term_label
from flaair_analysis.tables.datasets import simulated_table
from flaair_analysis.tables.fit import PITCH_KEYS, STROKE_KEYS
from flaair_analysis.tables.joint import identify_joint
from flaair_analysis.tables.joint_workflow import analyse_joint
from flaair_model import settings
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_sim.core.drive import chirp
from flaair_sim.core.measured_run import synthesize_measured_run
from flaair_tools.discrepancy.cli import main as discrepancy_main
from flaair_tools.discrepancy.identify import main as identify_main
from flaair_tools.tables.table_io import write_table
from test_discrepancy import write_run_csvs  # the runs as measured-run CSV files

FS_HZ = 20_000.0
KEYS = STROKE_KEYS + PITCH_KEYS
FULL = (("chirp_full", 100.0, 20.0, 200.0, 0.5), ("chirp_half", 50.0, 20.0, 200.0, 0.5))
QUIET = (("quiet", 20.0, 20.0, 80.0, 0.3),)  # 20 V, below 80 Hz: never near the resonance


def robot():
    m = load_model()
    p = m.plant
    plant = replace(
        p,
        stroke_natural_frequency_hz=p.stroke_natural_frequency_hz * 1.06,
        aero_damping_nm_s2=p.aero_damping_nm_s2 * 0.9,
        actuator_gain_nm_per_v=p.actuator_gain_nm_per_v * 1.08,
        pitch_natural_frequency_hz=p.pitch_natural_frequency_hz * 0.96,
    )
    return m, replace(m, plant=plant)


def make_runs(model, specs, seed: int) -> tuple[Run, ...]:
    rng = np.random.default_rng(seed)
    out = []
    for name, amp, f0, f1, dur in specs:
        t = np.arange(round(dur * FS_HZ)) / FS_HZ
        c = synthesize_measured_run(chirp(t, amp, f0, f1, dur), FS_HZ, model, rng)
        out.append(
            Run(
                name,
                FS_HZ,
                c["drive_v"],
                c["stroke_sensor_v"],
                c["pitch_sensor_v"],
                c["stroke_deg"],
                c["pitch_deg"],
            )
        )
    return check_runs(out)


def make_table(model, fn_hz: float, seed: int = 2):
    freqs = np.linspace(0.6 * fn_hz, 1.6 * fn_hz, 12)
    rng = np.random.default_rng(seed)
    return simulated_table(
        model, [25.0, 45.0, 65.0], freqs, settings.tables(), rng, missing_pitch=0.3
    )


def _noise(runs, nominal):
    return noise_estimates(runs, simulate_runs([nominal], runs)[0], nominal)


def _errors(values, truth) -> dict[str, float]:
    return {k: abs(values[k] / getattr(truth.plant, k) - 1.0) for k in KEYS}


@pytest.mark.slow  # a joint fit of runs and a table
@pytest.mark.timeout(240)
def test_the_joint_fit_recovers_the_plant_and_both_sets_agree() -> None:
    nominal, true = robot()
    fn = true.plant.stroke_natural_frequency_hz
    runs = make_runs(true, FULL, 1)
    fit = identify_joint(
        runs, make_table(true, fn), nominal, _noise(runs, nominal), settings.tables()
    )
    err = _errors(fit.values, true)
    assert err["stroke_natural_frequency_hz"] < 0.005 and err["pitch_natural_frequency_hz"] < 0.005
    assert max(err.values()) < 0.03, err  # measured: all below 0.2 %
    for name in ("runs", "table"):
        a = fit.agreement[name]
        assert 0.7 < max(a.noise_ratio.values()) < 1.3, (name, a.noise_ratio)
        assert a.weight == {"stroke": 1.0, "pitch": 1.0}  # both at noise: the plain chi-squares
    assert fit.warnings == ()
    assert set(fit.agreement["runs"].noise_ratio) == {"stroke_deg", "pitch_deg"}
    assert set(fit.agreement["table"].noise_ratio) == {"stroke_pp_deg", "pitch_pp_deg"}
    # the runs' initial states were fitted, the inertias and sensors stay the model's
    assert all(r.mechanical0 is not None for r in fit.runs)
    assert fit.model.plant.stroke_inertia_kg_m2 == nominal.plant.stroke_inertia_kg_m2
    assert fit.model.sensors == nominal.sensors
    json.dumps(fit.as_dict(), allow_nan=False)


@pytest.mark.slow  # two joint fits (runs alone, runs with the table)
@pytest.mark.timeout(240)
def test_quiet_runs_with_a_table_fit_better_than_the_runs_alone() -> None:
    """Runs at 20 V below 80 Hz do not pin the resonance's damping; the table does."""
    nominal, true = robot()
    fn = true.plant.stroke_natural_frequency_hz
    runs = make_runs(true, QUIET, 1)
    noise = _noise(runs, nominal)
    alone = identify_plant(runs, nominal, noise)
    joint = identify_joint(runs, make_table(true, fn), nominal, noise, settings.tables())
    e_alone, e_joint = _errors(alone.values, true), _errors(joint.values, true)
    # measured: aero damping 7.8 % off from the runs alone, 1.0 % jointly; hinge damping 12.6 %
    # and 2.3 %; aero coupling 22 % and 8 %
    assert e_alone["aero_damping_nm_s2"] > 0.05
    assert e_joint["aero_damping_nm_s2"] < 0.02
    assert e_joint["hinge_damping_nm_s_per_rad"] < 0.05 < e_alone["hinge_damping_nm_s_per_rad"]
    assert sum(e_joint.values()) < 0.5 * sum(e_alone.values())
    assert joint.stderr["aero_damping_nm_s2"] < alone.stderr["aero_damping_nm_s2"]
    assert joint.warnings == ()


@pytest.mark.slow  # a joint fit of two robots' sets
@pytest.mark.timeout(240)
def test_a_table_of_another_robot_is_named_as_disagreeing_not_averaged() -> None:
    """The table's robot resonates 15 % higher than the runs': each set's gap is reported."""
    nominal, true = robot()
    fn = true.plant.stroke_natural_frequency_hz
    other = replace(true, plant=replace(true.plant, stroke_natural_frequency_hz=1.15 * fn))
    runs = make_runs(true, FULL[:1], 3)
    fit = identify_joint(
        runs, make_table(other, fn), nominal, _noise(runs, nominal), settings.tables()
    )
    table = fit.agreement["table"]
    assert max(table.alone.values()) < 1.5  # the table alone is at its noise ...
    assert table.noise_ratio["stroke_pp_deg"] > 5.0  # ... and far from it after the joint fit
    assert table.weight["stroke"] < 0.1  # the set above its noise is down-weighted (Birge)
    (warning,) = fit.warnings
    assert warning.startswith("the table and the runs disagree")
    assert "table: stroke_pp_deg" in warning and "runs: at noise" in warning
    table_fn = fit.table_alone["stroke_natural_frequency_hz"]
    assert table_fn == pytest.approx(1.15 * fn, rel=0.01)  # what the table alone says
    assert f"table alone {table_fn:.1f} Hz" in warning
    assert fit.as_dict()["agree"] is False


@pytest.mark.slow  # the joint workflow with a hidden effect (search, checks, refit)
@pytest.mark.timeout(600)
def test_a_missing_effect_found_on_the_runs_is_kept_when_the_table_confirms_it() -> None:
    """Structural damping 0.05 in the robot: the runs' search names it, the table's held-out
    levels improve with it (chi-square per cell 2.11 -> 1.02 measured), the plant is refitted
    on both with it and both sets end at noise.
    """
    nominal, true = robot()
    true = with_effects(true, {"structural_damping": {"damping_ratio": 0.05}})
    fn = true.plant.stroke_natural_frequency_hz
    runs = make_runs(true, FULL, 5)
    s = settings.tables()
    res = analyse_joint(
        runs,
        make_table(true, fn, seed=6),
        nominal,
        _noise(runs, nominal),
        s,
        settings.discrepancy(),
    )
    assert res.status == "explained" and res.kept
    assert _exact(res, "explained", ["structural_damping"]).right
    assert [e.name for e in res.runs_result.effects] == ["structural_damping"]
    assert res.model_out.effect("structural_damping") is not None
    assert res.table_after.chi2 < res.table_before.chi2 - 2.0 * np.sqrt(2.0 * res.table_before.n)
    assert res.table_after.chi2 / res.table_after.n < 1.3
    assert res.final is not None and res.final.warnings == ()
    assert res.model_out.plant.stroke_natural_frequency_hz == pytest.approx(fn, rel=0.005)


@pytest.mark.slow  # the joint workflow with a finding the table refuses
@pytest.mark.timeout(600)
def test_a_finding_that_worsens_the_table_beyond_noise_is_refused() -> None:
    """The runs' robot has structural damping, the table's (same plant) has none: the runs'
    search names it, the table's held-out chi-square rises far beyond noise with it (534 over 61
    cells measured, noise allows 22): refused, the model is the joint plant alone.
    """
    nominal, plain = robot()
    damped = with_effects(plain, {"structural_damping": {"damping_ratio": 0.05}})
    fn = plain.plant.stroke_natural_frequency_hz
    runs = make_runs(damped, FULL, 5)
    s = settings.tables()
    res = analyse_joint(
        runs,
        make_table(plain, fn, seed=6),
        nominal,
        _noise(runs, nominal),
        s,
        settings.discrepancy(),
    )
    assert [e.name for e in res.runs_result.effects] == ["structural_damping"]
    assert res.status == "unexplained" and not res.kept and res.final is None
    assert _exact(res, "unexplained", []).right  # nothing named, nothing discovered
    assert res.model_out.effect("structural_damping") is None
    assert res.model_out.plant == res.joint.model.plant
    assert res.notes[0].startswith("the table refused the runs' findings (structural_damping)")
    # the rise the findings made, beyond what noise allows (2 sqrt(2 N)); the model written is
    # the joint plant, so the table's held-out check after is the one before
    rise = re.search(r"rose by ([\d.]+) over (\d+) cells \(noise allows ([\d.]+)", res.notes[0])
    assert rise and float(rise.group(1)) > float(rise.group(3))
    assert float(rise.group(3)) == pytest.approx(2.0 * np.sqrt(2.0 * res.table_before.n), rel=1e-3)
    assert res.table_after == res.table_before
    # the runs' damping is not in the model written: their gap is reported, not hidden
    assert any(n.startswith("with the model written the runs keep a gap") for n in res.notes)
    assert res.joint.warnings  # and the joint fit already said neither set reaches its noise


# slow: the joint workflow: the runs' search, then the table's, each judged on held-out data
@pytest.mark.slow
@pytest.mark.timeout(600)
def test_an_effect_only_the_table_shows_is_found_by_the_tables_search_and_kept() -> None:
    """A stop at 25 deg: the quiet runs (stroke below 6 deg) never reach it, the table's drive
    levels do. The runs' search adds nothing, the table keeps a held-out gap, the table's own
    search names the collision, and the runs do not object (their chi-square unchanged).
    """
    nominal, true = robot()
    true = with_effects(true, {"collision": {"stroke_limit_deg": 25.0}})
    fn = true.plant.stroke_natural_frequency_hz
    runs = make_runs(true, QUIET, 1)
    assert max(np.nanmax(np.abs(r.stroke_deg)) for r in runs) < 10.0
    s = settings.tables()
    table = make_table(true, fn, seed=6)
    # the runs' term discovery is off: it is what takes long here, and no term is missing
    quick = replace(settings.discrepancy(), discover=False)
    res = analyse_joint(runs, table, nominal, _noise(runs, nominal), s, quick)
    assert res.runs_result.effects == () and res.kept
    assert max(res.table_before.noise_ratio.values()) > 3.0  # measured 4.9
    found = res.model_out.effect("collision")
    assert found is not None and found.stroke_limit_deg == pytest.approx(25.0, abs=1.0)
    assert any(n.startswith("the table's own search found collision") for n in res.notes)
    assert max(res.table_after.noise_ratio.values()) < 1.5  # measured 1.01
    assert res.final is not None and res.final.warnings == ()
    assert res.status == "explained"
    assert _exact(res, "explained", ["collision"]).right


def _exact(res, status: str, names: list[str]):
    """The joint outcome scored by the one exact rule: status, the model's effects and terms."""
    return score_exact(
        status=res.status,
        names=res.model_out.effect_names,
        terms=[term_label(t.kind, t.acts_on) for t in res.model_out.discovered],
        expected_status=status,
        expected_names=names,
        expected_terms=[],
    )


def _strict(text: str):
    def refuse(name: str):
        raise ValueError(f"non-strict JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.timeout(300)
def test_identify_with_runs_and_a_table_prints_one_summary_line_and_writes_strict_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, true = robot()
    fn = true.plant.stroke_natural_frequency_hz
    runs = write_run_csvs(make_runs(true, FULL[:1], 1), tmp_path)
    table = tmp_path / "robot.csv"
    write_table(make_table(true, fn), table)
    out = tmp_path / "out"
    # the table among the runs is told apart by its content
    assert identify_main([*map(str, runs), str(table), "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("flaair identify: 1 run(s) + table ")
    assert "plant fitted on both" in lines[0] and "the sets agree" in lines[0]
    doc = _strict((out / "identification.json").read_text())
    fn_fit = doc["parameters"]["stroke_natural_frequency_hz"]
    assert fn_fit["value"] == pytest.approx(fn, rel=0.005)
    assert set(doc["data_sets"]) == {"runs", "table"} and doc["agree"] is True
    assert load_model(out / "model.yaml").plant.stroke_natural_frequency_hz == fn_fit["value"]
    # a malformed table with good runs: refused by line, nothing written
    bad = tmp_path / "bad.csv"
    bad.write_text("drive_pp_v,frequency_hz,stroke_pp_deg\n120,150,3\n120,abc,4\n")
    nothing = tmp_path / "nothing"
    assert identify_main([*map(str, runs), "--table", str(bad), "--out", str(nothing)]) == 2
    err = capsys.readouterr().err
    assert "line 3" in err and "frequency_hz" in err and err.count("\n") == 1
    assert not nothing.exists()
    # the same through discrepancy
    assert discrepancy_main([*map(str, runs), "--table", str(bad), "--out", str(nothing)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flaair discrepancy:") and "line 3" in err and err.count("\n") == 1
    assert not nothing.exists()


@pytest.mark.slow  # the joint workflow end to end (five runs and a table)
@pytest.mark.timeout(600)
def test_discrepancy_with_runs_and_a_table_of_a_robot_missing_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, true = robot()
    fn = true.plant.stroke_natural_frequency_hz
    runs = write_run_csvs(make_runs(true, FULL, 5), tmp_path)
    table = tmp_path / "robot.csv"
    write_table(make_table(true, fn, seed=6), table)
    out = tmp_path / "out"
    assert discrepancy_main([*map(str, runs), str(table), "--out", str(out)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("flaair discrepancy: 2 run(s) + table ")
    assert "status no_discrepancy" in first
    doc = _strict((out / "discrepancy.json").read_text())
    joint = doc["joint"]
    assert doc["status"] == "no_discrepancy" and joint["findings_kept"] is True
    assert joint["joint_identification"]["agree"] is True
    assert joint["table_heldout_before"]["chi2_per_cell"] < 1.5  # held-out levels at noise
    fitted = load_model(out / "model.yaml").plant
    assert fitted.stroke_natural_frequency_hz == pytest.approx(fn, rel=0.005)
    assert (out / "report.html").exists()


class _MeasuredResonance:
    """A test-only kind of evidence: the stroke's natural frequency measured on its own (a lab's
    ring-down), value and standard error. Only its own module is written: the joint
    identification takes it through `extra` as it takes a table or a multisine set.
    """

    name = "resonance"
    n_nuisance = 0
    sites = ("stroke_deg",)

    def __init__(self, frequency_hz: float, stderr_hz: float) -> None:
        self.frequency_hz, self.stderr_hz = frequency_hz, stderr_hz

    def nuisance_start(self) -> np.ndarray:
        return np.zeros(0)

    def nuisance_steps(self) -> np.ndarray:
        return np.zeros(0)

    def residuals(self, models, nuisance) -> np.ndarray:
        f = np.array([m.plant.stroke_natural_frequency_hz for m in models])
        return ((f - self.frequency_hz) / self.stderr_hz)[:, None]

    def linearised(self, models, nuisance, h):
        rows = self.residuals(models, nuisance)
        return rows, np.zeros((1, 0))

    def heldout(self):
        return ()

    def site_index(self):
        return {"stroke_deg": np.arange(1)}

    def stage_piece(self, side: str, channel: str):
        return self if side == "stroke" else None

    def set_scores(self, model):
        r = self.residuals([model], np.zeros(0))[0]
        ratio = {"stroke_deg": float(abs(r[0]))}
        nrmse = {"stroke_deg": float(abs(r[0]) * self.stderr_hz / self.frequency_hz)}
        return ratio, nrmse, 1, float(r @ r)


@pytest.mark.slow  # two table fits
@pytest.mark.timeout(240)
def test_a_new_kind_of_evidence_joins_the_identification_with_nothing_else_written() -> None:
    """A measured natural frequency beside a table: fitted with it (the stroke's frequency then
    known to its own 0.02 Hz, not the table's ~0.2 Hz), scored among the data sets, written in
    the identification's JSON.
    """
    from flaair_analysis.evidence import Evidence, EvidenceSet
    from flaair_analysis.tables.joint import identify_evidence

    nominal, true = robot()
    fn = true.plant.stroke_natural_frequency_hz
    table, s = make_table(true, fn), settings.tables()
    measured = _MeasuredResonance(fn, 0.02)
    assert isinstance(measured, Evidence) and isinstance(measured, EvidenceSet)
    alone = identify_evidence([], table, nominal, {}, s)
    both = identify_evidence([], table, nominal, {}, s, extra=[measured])
    key = "stroke_natural_frequency_hz"
    assert list(both.agreement) == ["table", "resonance"]
    assert both.agreement["resonance"].weight == {"stroke": 1.0}
    assert both.agreement["resonance"].noise_ratio["stroke_deg"] < 2.0
    assert abs(both.values[key] - fn) < 0.05
    assert both.stderr[key] < 0.3 * alone.stderr[key]
    doc = both.as_dict()
    assert doc["data_sets"]["resonance"]["residuals"] == 1
    json.dumps(doc, allow_nan=False)


class _ResonanceFileError(ValueError):
    pass


def _read_resonance(path: Path) -> _MeasuredResonance:
    """The test-only kind's file: `resonance_hz,stderr_hz` and one row."""
    lines = path.read_text().splitlines()
    try:
        f, se = (float(x) for x in lines[1].split(","))
    except (IndexError, ValueError):
        raise _ResonanceFileError(f"{path}: not one row of two numbers") from None
    return _MeasuredResonance(f, se)


def test_a_new_kind_of_evidence_file_reaches_identify_by_one_row(tmp_path, monkeypatch) -> None:
    """Given one row of `run_inputs.EVIDENCE_FILES`, `identify` takes the new kind's file among
    the others by its header, fits with it and scores it; a bad one is refused in one line.
    """
    from flaair_tools.discrepancy import run_inputs

    row = run_inputs.EvidenceFile(
        frozenset({"resonance_hz", "stderr_hz"}), _read_resonance, (_ResonanceFileError,)
    )
    monkeypatch.setattr(run_inputs, "EVIDENCE_FILES", (row,))
    _, true = robot()
    fn = true.plant.stroke_natural_frequency_hz
    table, resonance = tmp_path / "sweep.csv", tmp_path / "ringdown.csv"
    write_table(make_table(true, fn), table)
    resonance.write_text(f"resonance_hz,stderr_hz\n{fn},0.02\n")
    out = tmp_path / "out"
    assert identify_main([str(resonance), str(table), "--out", str(out)]) == 0
    doc = json.loads((out / "identification.json").read_text())
    assert list(doc["data_sets"]) == ["table", "resonance"]
    assert doc["data_sets"]["resonance"]["residuals"] == 1
    fitted = load_model(out / "model.yaml").plant.stroke_natural_frequency_hz
    assert abs(fitted - fn) < 0.05
    resonance.write_text("resonance_hz,stderr_hz\nfast,slow\n")
    nothing = tmp_path / "nothing"
    assert identify_main([str(resonance), str(table), "--out", str(nothing)]) == 2
    assert not nothing.exists()


@pytest.mark.slow  # the joint workflow on runs beside the new kind of set
@pytest.mark.timeout(300)
def test_a_new_kind_of_evidence_checks_the_runs_findings_as_the_spectra_do() -> None:
    """The same test-only measured resonance beside runs in `discrepancy`: fitted with the joint
    plant, its check (refitted on itself, in sample) made before and after, written under
    `other_sets`.
    """
    from flaair_analysis.tables.joint_workflow import analyse_evidence

    nominal, true = robot()
    runs = make_runs(true, FULL, 1)
    measured = _MeasuredResonance(true.plant.stroke_natural_frequency_hz, 0.05)
    res = analyse_evidence(
        runs, None, nominal, settings.tables(), settings.discrepancy(), extra=[measured]
    )
    assert list(res.joint.agreement) == ["runs", "resonance"]
    before, after = res.others["resonance"]
    assert before.n == after.n == 1 and before.kind == "resonance, in sample"
    doc = res.as_dict()
    assert doc["other_sets"]["resonance"]["before"]["cells"] == 1
    json.dumps(doc, allow_nan=False)
