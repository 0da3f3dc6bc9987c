"""`flaair multisine design|analyze` end to end (../shared/multisine.md): the design's files,
the analysis of runs simulated on the model (nonlinearity.json's fields, strict JSON, the report),
the model comparison locating a film's even distortion, and every refusal of the contract in
one line with nothing written.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from flaair_analysis.multisine.design import realization_drive
from flaair_common.runcsv import read_run, write_run
from flaair_model.config import CONFIG_DIR_ENV
from flaair_model.model_io import load_model
from flaair_sim.core.measured_run import synthesize_measured_run
from flaair_tools.multisine.drives import design_of
from flaair_tools.orchestration.bench_robot import robot_section, write_robot_model
from rosproc import FLAAIR, isolated_env, run, run_offline

ROOT = Path(__file__).resolve().parents[1]
# a short design: N = 5000 at 20 kHz (f0 = 4 Hz), T = 1, P = 2, M = 2
SHORT = ["--base-hz", "4", "--periods", "2", "--realizations", "2", "--seed", "5"]
FILM_TERM = "discovered:\n  - {kind: square_angle_sensor, acts_on: pitch_sensor_v, " + (
    "parameters: {coefficient: 0.05}}\n"
)


def _film_model(path: Path) -> Path:
    text = (ROOT / "config" / "model.yaml").read_text()
    path.write_text(text + FILM_TERM)
    return path


def _lab_runs(design_dir: Path, out: Path, model_path: Path | None, seed: int = 0) -> list[Path]:
    """The design's drives through the model with noise, video every 10th sample (2 kHz)."""
    model = load_model(model_path)
    rng = np.random.default_rng(seed)
    out.mkdir()
    paths = []
    for csv in sorted(design_dir.glob("realization_*.csv")):
        drive = read_run(csv, required=("time_s", "drive_v"))
        cols = synthesize_measured_run(drive["drive_v"], 20000.0, model, rng)
        off_frame = np.arange(cols["time_s"].size) % 10 != 0
        for name in ("stroke_deg", "pitch_deg"):
            cols[name][off_frame] = np.nan
        write_run(out / csv.name, cols)
        paths.append(out / csv.name)
    return paths


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    root = tmp_path_factory.mktemp("ms")
    result = run_offline(
        [FLAAIR, "multisine", "design", "--out", str(root / "design"), *SHORT], isolated_env()
    )
    assert result.returncode == 0, result.stderr
    film = _film_model(root / "film.yaml")
    return {
        "root": root,
        "design": root / "design",
        "nominal": _lab_runs(root / "design", root / "nominal", None),
        "film": _lab_runs(root / "design", root / "film", film),
        "film_model": film,
    }


@pytest.mark.slow  # the design command through bin/flaair, its realizations simulated
@pytest.mark.timeout(120)
def test_design_writes_the_realizations_and_the_design_file(tmp_path: Path) -> None:
    # through bin/flaair in a new process, as a person runs it (other tests: run_offline)
    result = run([FLAAIR, "multisine", "design", "--out", str(tmp_path / "d"), "--seed", "51"],
                 isolated_env(), 110)  # fmt: skip
    assert result.returncode == 0, result.stderr
    doc = yaml.safe_load((tmp_path / "d" / "multisine.yaml").read_text())
    assert doc["period_samples"] == 10000 and doc["base_frequency_hz"] == 2.0
    assert (len(doc["excited_lines"]), len(doc["odd_detection_lines"])) == (26, 12)
    assert doc["files"] == [f"realization_{m}.csv" for m in (1, 2, 3, 4)]
    assert doc["seed"] == 51 and len(doc["phases_rad"]) == 4
    lines = (tmp_path / "d" / "realization_3.csv").read_text().splitlines()
    assert lines[0] == "time_s,drive_v" and len(lines) == 1 + 5 * 10000
    table = np.loadtxt(tmp_path / "d" / "realization_3.csv", delimiter=",", skiprows=1)
    n = np.arange(table.shape[0])
    k = np.array(doc["excited_lines"])[:, None]
    phases = np.array(doc["phases_rad"][2])[:, None]
    expected = doc["amplitude_v"] * np.cos(2 * np.pi * k * n / 10000 + phases).sum(axis=0)
    np.testing.assert_allclose(table[:, 1], expected, atol=1e-6 * 25)
    assert np.sqrt(np.mean(table[:, 1] ** 2)) == pytest.approx(25.0, rel=1e-6)


@pytest.mark.slow  # simulates the multisine realizations and analyses them
@pytest.mark.timeout(200)
def test_analyze_the_nominal_robot_writes_the_contracts_document(lab: dict, tmp_path: Path) -> None:
    out = tmp_path / "ms"
    result = run_offline(
        [FLAAIR, "multisine", "analyze", *map(str, lab["nominal"]), "--out", str(out)],
        isolated_env(),
    )
    assert result.returncode == 0, result.stderr
    doc = json.loads((out / "nonlinearity.json").read_text(), parse_constant=pytest.fail)
    design = doc["design"]
    assert design["source"] == "drive" and design["period_samples"] == 5000
    assert (design["periods"], design["realizations"]) == (2, 2)
    assert design["transient_periods"] >= 1
    assert set(doc["channels"]) == {"stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg"}
    assert doc["skipped"] == {} and doc["model"] is None
    for name, entry in doc["channels"].items():
        assert entry["class"] == "odd", name  # the aerodynamic damping is odd
        assert len(entry["bla"]) == len(design["excited_lines"])
        assert entry["levels_db"]["odd"] > entry["levels_db"]["noise"] + 20.0
        assert "model" not in entry and "disagrees" not in entry
    stroke = doc["channels"]["stroke_sensor_v"]
    assert set(stroke["bla"][0]) == {"freq_hz", "mag", "phase_deg", "std_noise", "std_nl"}
    html = (out / "report.html").read_text()
    assert "figure_pitch_deg.png" in html and (out / "figure_stroke_sensor_v.png").stat().st_size
    assert "stroke_sensor_v" in html


@pytest.mark.slow  # two analyses each simulating the model on 2 runs: 11 s on the loaded machine
@pytest.mark.timeout(200)
def test_the_model_comparison_points_to_the_hinge_film(lab: dict, tmp_path: Path) -> None:
    design = lab["design"] / "multisine.yaml"
    out = tmp_path / "film"
    args = [*map(str, lab["film"]), "--design", str(design), "--out", str(out)]
    result = run_offline(
        [FLAAIR, "multisine", "analyze", *args, "--model", str(ROOT / "config" / "model.yaml")],
        isolated_env(),
    )
    assert result.returncode == 0, result.stderr
    doc = json.loads((out / "nonlinearity.json").read_text())
    assert doc["design"]["source"] == "design" and doc["design"]["transient_periods"] == 1
    disagrees = {name: e["disagrees"] for name, e in doc["channels"].items()}
    assert disagrees == {
        "stroke_sensor_v": [],
        "pitch_sensor_v": ["even"],
        "stroke_deg": [],
        "pitch_deg": [],
    }
    findings = doc["localisation"]["findings"]
    assert [(f["distortion"], f["points_to"], f["sites"]) for f in findings] == [
        ("even", "the hinge film (the pitch video does not show it)", ["pitch_sensor_v"])
    ]
    stroke = doc["channels"]["stroke_sensor_v"]["model"]
    assert stroke["levels_db"]["noise"] is None and stroke["class"] == "odd"
    # the model that has the film's term leaves nothing unexplained
    again = run_offline(
        [FLAAIR, "multisine", "analyze", *args[:-1], str(tmp_path / "right"),
         "--model", str(lab["film_model"])],
        isolated_env(),
    )  # fmt: skip
    assert again.returncode == 0, again.stderr
    right = json.loads((tmp_path / "right" / "nonlinearity.json").read_text())
    assert all(e["disagrees"] == [] for e in right["channels"].values())


@pytest.mark.slow  # a whole discrepancy workflow on the set's runs: 9 s here
@pytest.mark.timeout(200)
def test_identify_and_discrepancy_take_the_set_as_spectra_and_its_lines_point_to_the_film(
    lab: dict, tmp_path: Path
) -> None:
    """The set told by its drive; the plant fitted on its line spectra; the search's finding
    checked on them; the even distortion the joint plant does not predict points to the film,
    and the model written predicts it.
    """
    runs = [str(p) for p in lab["film"]]
    ident = run_offline([FLAAIR, "identify", *runs, "--out", str(tmp_path / "id")], isolated_env())
    assert ident.returncode == 0, ident.stderr
    assert "a multisine set of 2 realization(s)" in ident.stdout
    fit = json.loads((tmp_path / "id" / "identification.json").read_text())
    assert fit["multisine_runs"] == ["realization_1", "realization_2"] and fit["runs"] == []
    assert list(fit["data_sets"]) == ["spectra"]
    stroke_hz = fit["parameters"]["stroke_natural_frequency_hz"]
    assert abs(stroke_hz["value"] - 140.0) < 3.0 * stroke_hz["stderr"]

    out = tmp_path / "d"
    result = run_offline([FLAAIR, "discrepancy", *runs, "--out", str(out)], isolated_env())
    assert result.returncode == 0, result.stderr
    doc = json.loads((out / "discrepancy.json").read_text())
    reading = doc["joint"]["multisine"]
    before = [
        (f["distortion"], f["channels"]) for f in reading["before"]["localisation"]["findings"]
    ]
    assert ("even", ["pitch_sensor_v"]) in before
    film = next(
        f for f in reading["before"]["localisation"]["findings"] if f["distortion"] == "even"
    )
    assert film["points_to"].startswith("the hinge film") and film["sites"] == ["pitch_sensor_v"]
    assert reading["after"]["channels"]["pitch_sensor_v"]["disagrees"] in ([], ["odd"])
    assert "even" not in reading["after"]["channels"]["pitch_sensor_v"]["disagrees"]
    written = (out / "model.yaml").read_text()
    assert "square_angle_sensor" in written and "pitch_sensor_v" in written
    spectra = doc["joint"]["spectra_before"], doc["joint"]["spectra_after"]
    assert spectra[1]["chi2_per_cell"] < spectra[0]["chi2_per_cell"]


def _refused(args: list[str], out: Path) -> str:
    result = run_offline([FLAAIR, "multisine", "analyze", *args, "--out", str(out)], isolated_env())
    assert result.returncode == 2, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    return result.stderr.strip()


@pytest.mark.timeout(200)
def test_the_contracts_bad_inputs_are_refused_in_one_line_with_nothing_written(
    lab: dict, tmp_path: Path
) -> None:
    runs = [str(p) for p in lab["nominal"]]
    out = tmp_path / "never"
    one = read_run(lab["nominal"][0])
    t = one["time_s"]

    def variant(name: str, **cols: np.ndarray) -> str:
        path = tmp_path / name
        write_run(path, {**one.columns, **cols})
        return str(path)

    chirp = variant("chirp.csv", drive_v=50 * np.sin(2 * np.pi * (20 * t + 90 * t * t)))
    assert "chirp.csv: no periodic excitation" in _refused([chirp], out)
    short = tmp_path / "short.csv"
    write_run(short, {k: v[: 2 * 5000 + 7] for k, v in one.columns.items()})
    assert "short.csv: holds fewer than 2 whole periods" in _refused([runs[1], str(short)], out)
    even = variant("even.csv", drive_v=one["drive_v"] + 5 * np.cos(2 * np.pi * 8 * t))
    assert "even.csv: not an odd multisine (even line 2 excited)" in _refused([even], out)
    assert f"{runs[0]}: repeats the realization" in _refused([runs[1], runs[0], runs[0]], out)
    other = variant("other.csv", drive_v=one["drive_v"] + 5 * np.cos(2 * np.pi * 44 * t))  # k 11
    assert "other.csv: another design than the first run" in _refused([runs[0], other], out)
    stuck = one["stroke_sensor_v"].copy()
    stuck[9000:9010] = stuck[5000:15000].max()
    sat = variant("sat.csv", stroke_sensor_v=stuck)
    assert "sat.csv: stroke_sensor_v saturated" in _refused([sat, runs[1]], out)
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,drive_v,stroke_sensor_v,pitch_sensor_v\n0,1,1,1\n5e-05,1,x,1\n")
    assert "bad.csv: line 3, column stroke_sensor_v" in _refused([str(bad)], out)
    (tmp_path / "model.yaml").write_text("plant: [")
    message = _refused([*runs, "--model", str(tmp_path / "model.yaml")], out)
    assert message.startswith("flaair multisine analyze: --model") and "model.yaml" in message
    assert not out.exists()
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine")
    assert "exists and is not empty" in _refused(runs, full)
    assert [p.name for p in full.iterdir()] == ["keep.txt"]


@pytest.mark.graph  # ROS 2 processes exchanging data in lockstep: run after the others
@pytest.mark.slow  # 2 realizations of 2.25 s through the lockstep graph
@pytest.mark.timeout(900)
def test_experiment_multisine_recorded_as_a_bag_analyses_like_the_csvs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`flaair experiment multisine` on the simulated bench robot, then `multisine analyze` on
    the bag: the same design found and the same classes and levels as CSVs of the same
    realizations simulated offline through the same robot model. The experiment as configured,
    shortened to 2 realizations of 1 + 3 periods (4.5 s of signal through the graph).
    """
    config = tmp_path / "config"
    shutil.copytree(ROOT / "config", config)
    experiments = yaml.safe_load((config / "experiments.yaml").read_text())
    experiments["multisine"]["multisine"].update(realizations=2, periods=3)
    (config / "experiments.yaml").write_text(yaml.safe_dump(experiments, sort_keys=False))
    monkeypatch.setenv(CONFIG_DIR_ENV, str(config))
    bag = tmp_path / "bag"
    env = {**isolated_env(), CONFIG_DIR_ENV: str(config)}
    result = run([FLAAIR, "experiment", "multisine", "--out", str(bag)], env, 850)
    assert result.returncode == 0, result.stderr[-3000:]
    from_bag = run_offline(
        [FLAAIR, "multisine", "analyze", str(bag), "--out", str(tmp_path / "bag_ms")],
        isolated_env(),
    )
    assert from_bag.returncode == 0, from_bag.stderr
    bag_doc = json.loads((tmp_path / "bag_ms" / "nonlinearity.json").read_text())
    design = design_of(experiments["multisine"]["multisine"], 20000.0)
    model = load_model(write_robot_model(tmp_path / "robot.yaml"))
    every = int(robot_section()["video_frame_every"])
    rng = np.random.default_rng(1)
    csvs = []
    for m in range(design.realizations):
        cols = synthesize_measured_run(realization_drive(design, m), 20000.0, model, rng)
        for name in ("stroke_deg", "pitch_deg"):
            cols[name][np.arange(cols[name].size) % every != 0] = np.nan
        csvs.append(tmp_path / f"realization_{m + 1}.csv")
        write_run(csvs[-1], cols)
    from_csv = run_offline(
        [FLAAIR, "multisine", "analyze", *map(str, csvs), "--out", str(tmp_path / "csv_ms")],
        isolated_env(),
    )
    assert from_csv.returncode == 0, from_csv.stderr
    csv_doc = json.loads((tmp_path / "csv_ms" / "nonlinearity.json").read_text())
    assert bag_doc["runs"] == [f"{bag}:realization_{m}" for m in (1, 2)]
    for key, value in bag_doc["design"].items():  # a CSV's rate: from times written to 9 digits
        if key not in ("transient_periods", "source"):
            assert csv_doc["design"][key] == pytest.approx(value, rel=1e-9), key
    assert bag_doc["design"]["excited_lines"] == list(design.excited_lines)
    assert set(bag_doc["channels"]) == set(csv_doc["channels"]) == {
        "stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg"
    }  # fmt: skip
    for name, entry in bag_doc["channels"].items():
        other = csv_doc["channels"][name]
        assert entry["class"] == other["class"] == "odd", name
        for level in ("signal", "noise", "odd"):
            assert entry["levels_db"][level] == pytest.approx(other["levels_db"][level], abs=1.5)
        mags = np.array([b["mag"] for b in entry["bla"]])
        np.testing.assert_allclose(mags, [b["mag"] for b in other["bla"]], rtol=0.03)
