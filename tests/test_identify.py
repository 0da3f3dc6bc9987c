"""Grey-box identification of an off-nominal robot's plant (`flaair identify`), and runs that
start while the wing still moves.

Robots are fixed draws of the project's randomized generator (`random_robot`): plant
parameters a few per cent off nominal, noise 1-2x, truth at the DAQ or a video rate.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from flaair_analysis.discrepancy import (
    analyse,
    check_runs,
    initial_mechanical_state,
    noise_estimates,
    simulate_runs,
)
from flaair_analysis.discrepancy.datasets import make_runs, run_set_drives
from flaair_analysis.discrepancy.identification import frequency_domain_start, identify_plant
from flaair_analysis.discrepancy.offnominal import random_robot, true_plant
from flaair_common.runcsv import write_run
from flaair_model.model_io import load_model
from flaair_model.settings import discrepancy as discrepancy_settings
from flaair_sim.core.plant import simulate, simulate_batch_from
from flaair_tools.discrepancy import identify
from flaair_tools.discrepancy.run_inputs import runs_from_csv
from rosproc import FLAAIR, isolated_env, run, run_offline
from test_discrepancy import write_case_csvs  # the case's runs as measured-run CSV files

REPO = Path(__file__).resolve().parents[1]
FREQUENCIES = ("stroke_natural_frequency_hz", "pitch_natural_frequency_hz")


@pytest.fixture(scope="module")
def model():
    return load_model()


def _fit(case, model):
    runs = check_runs(make_runs(case, model))
    noise = noise_estimates(runs, simulate_runs([model], runs)[0], model)
    return runs, identify_plant(runs, model, noise)


@pytest.mark.slow  # a plant fit on an off-nominal robot's runs
@pytest.mark.parametrize("draw", [0, 1])  # draw 0: 2 kHz video truth; draw 1: 20 kHz truth
def test_identification_recovers_an_off_nominal_plant(draw: int, model) -> None:
    case = random_robot("offnominal_null", draw)
    assert case.video_every == (10 if draw == 0 else 1)
    truth = true_plant(case, model)
    # really off nominal
    assert any(abs(truth[k] / getattr(model.plant, k) - 1) > 0.05 for k in truth)
    _runs, fit = _fit(case, model)
    for k in FREQUENCIES:
        assert fit.values[k] == pytest.approx(truth[k], rel=0.005), k
    for k in truth:
        assert fit.values[k] == pytest.approx(truth[k], rel=0.03), k
        # the reported standard error is honest: the truth within 6 standard errors
        assert abs(fit.values[k] - truth[k]) < 6 * fit.stderr[k] + 1e-3 * truth[k], k
    assert fit.cost_after < fit.cost_before
    corr = fit.correlation
    stroke = [
        fit.keys.index(k)
        for k in ("stroke_natural_frequency_hz", "aero_damping_nm_s2", "actuator_gain_nm_per_v")
    ]
    block = corr[np.ix_(stroke, stroke)]
    assert np.allclose(np.diag(block), 1.0) and np.allclose(block, block.T)
    # inertias, sensors stay
    assert fit.model.plant.stroke_inertia_kg_m2 == model.plant.stroke_inertia_kg_m2
    assert fit.model.sensors == model.sensors


def test_frequency_domain_start_is_near_the_robot(model) -> None:
    case = random_robot("offnominal_null", 2)
    truth = true_plant(case, model)
    start = frequency_domain_start(check_runs(make_runs(case, model)), model)
    for k in FREQUENCIES:
        assert start[k] == pytest.approx(truth[k], rel=0.02), k
    assert start["actuator_gain_nm_per_v"] == pytest.approx(
        truth["actuator_gain_nm_per_v"], rel=0.05
    )


@pytest.mark.slow  # a plant fit with the inertias free
def test_inertia_fitted_with_damping_and_gain_is_reported_inseparable(model) -> None:
    """Motion fixes only Gamma / I and G_a / I: with the
    inertia fitted too, the runs cannot separate them.
    """
    case = random_robot("offnominal_null", 1)
    runs = check_runs(make_runs(case, model))
    noise = noise_estimates(runs, simulate_runs([model], runs)[0], model)
    fit = identify_plant(
        runs,
        model,
        noise,
        keys=(
            "stroke_natural_frequency_hz",
            "aero_damping_nm_s2",
            "actuator_gain_nm_per_v",
            "stroke_inertia_kg_m2",
        ),
    )
    assert any("stroke_inertia_kg_m2" in note for note in fit.inseparable), fit.inseparable


def test_back_to_back_runs_are_simulated_from_their_measured_initial_state(model) -> None:
    """The second half of a chirp starts with the wing moving: from rest it would leave a gap."""
    drive = dict(run_set_drives())["chirp_full"]
    case = random_robot("offnominal_null", 1)
    whole = make_runs(case, model)[0]
    h = whole.n // 2
    second = replace(
        whole,
        name="second",
        drive_v=whole.drive_v[h:],
        stroke_sensor_v=whole.stroke_sensor_v[h:],
        pitch_sensor_v=whole.pitch_sensor_v[h:],
        stroke_deg=whole.stroke_deg[h:],
        pitch_deg=whole.pitch_deg[h:],
    )
    first = replace(
        whole,
        name="first",
        drive_v=whole.drive_v[:h],
        stroke_sensor_v=whole.stroke_sensor_v[:h],
        pitch_sensor_v=whole.pitch_sensor_v[:h],
        stroke_deg=whole.stroke_deg[:h],
        pitch_deg=whole.pitch_deg[:h],
    )
    # the state measured from the first frames is near the robot's true state at the split (a
    # start), and the state fitted with the plant is on it
    from flaair_analysis.discrepancy.datasets import true_model

    robot = replace(true_model(case, model), effects=())
    sim = simulate(drive, whole.fs_hz, robot)
    rate = (sim.stroke_rad[h + 1] - sim.stroke_rad[h - 1]) * whole.fs_hz / 2
    x_measured = initial_mechanical_state(second.stroke_deg, second.pitch_deg, second.fs_hz)
    assert abs(x_measured[0]) > math.radians(5)  # the wing is moving at the split
    assert x_measured[0] == pytest.approx(sim.stroke_rad[h], abs=math.radians(1.5))
    runs = check_runs([first, second])
    fit = identify_plant(runs, model, noise_estimates(runs, simulate_runs([model], runs)[0], model))
    x_fit = fit.runs[1].mechanical0
    assert x_fit[0] == pytest.approx(sim.stroke_rad[h], abs=math.radians(0.5))
    assert x_fit[1] == pytest.approx(rate, abs=0.03 * abs(rate) + 1.0)
    # simulated from it, the robot's own model matches the moving start; from rest it does not
    moving = simulate_batch_from(second.drive_v, second.fs_hz, [robot], x_fit)
    rest = simulate_batch_from(second.drive_v, second.fs_hz, [robot], np.zeros(4))
    err_moving = np.nanstd(np.degrees(moving.stroke_rad[0]) - second.stroke_deg)
    err_rest = np.nanstd(np.degrees(rest.stroke_rad[0]) - second.stroke_deg)
    assert err_moving < 1.2 * case.noise_scale * model.noise.tracking_noise_deg_rms < err_rest
    result = analyse([first, second], model, discrepancy_settings())
    assert result.status == "no_discrepancy", result.summary
    assert result.effects == ()


@pytest.mark.slow  # through bin/flaair in a new process, as a person runs it (imports and the fit)
def test_bin_flaair_identify_writes_the_fitted_model_and_strict_json(tmp_path: Path, model) -> None:
    case = random_robot("offnominal_null", 1)
    (tmp_path / "runs").mkdir()
    paths = write_case_csvs(case, model, tmp_path / "runs")
    out = tmp_path / "out"
    # through bin/flaair in a new process, as a person runs it (other tests: run_offline)
    proc = run([FLAAIR, "identify", *map(str, paths), "--out", str(out)], isolated_env(), 600)
    assert proc.returncode == 0, proc.stderr
    assert "stroke_natural_frequency_hz" in proc.stdout
    fitted = load_model(out / "model.yaml")  # same layout as config/model.yaml
    doc = json.loads(
        (out / "identification.json").read_text(),
        parse_constant=lambda c: pytest.fail(f"non-strict JSON {c}"),
    )
    truth = true_plant(case, model)
    for k in FREQUENCIES:
        assert getattr(fitted.plant, k) == pytest.approx(truth[k], rel=0.005)
        assert doc["parameters"][k]["value"] == pytest.approx(getattr(fitted.plant, k), rel=1e-12)
        assert doc["parameters"][k]["nominal"] == getattr(model.plant, k)
        assert doc["parameters"][k]["stderr"] > 0
    assert doc["correlation"]["order"] == list(doc["parameters"])
    assert fitted.sensors == model.sensors and fitted.effects == model.effects


@pytest.mark.parametrize("kind", ["missing", "no_truth"])
def test_bin_flaair_identify_bad_input_exits_2_without_traceback(kind: str, tmp_path: Path) -> None:
    if kind == "missing":
        args = [str(tmp_path / "nope.csv")]
        words = "nope.csv"
    else:
        n = 2000
        t = np.arange(n) / 20000.0
        p = tmp_path / "no_truth.csv"
        write_run(
            p,
            {
                "time_s": t,
                "drive_v": 100 * np.sin(2 * np.pi * 100 * t),
                "stroke_sensor_v": np.full(n, 1.25),
                "pitch_sensor_v": np.full(n, 1.25),
                "stroke_deg": np.full(n, np.nan),
                "pitch_deg": np.full(n, np.nan),
            },
        )
        args = [str(p)]
        words = "ground truth"
    proc = run_offline(
        [FLAAIR, "identify", *args, "--out", str(tmp_path / "out")], dict(os.environ), 300
    )
    assert proc.returncode == 2
    assert words in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out" / "model.yaml").exists()


@pytest.mark.slow  # three identify commands (runs, a table, both)
@pytest.mark.timeout(120)
def test_one_identification_document_whatever_the_mix(tmp_path: Path) -> None:
    """Runs alone, a table alone and both: one command, one document with the same keys; each
    lone set keeps its own fit (the runs' equal to `identify_plant` on them), the mix is fitted
    on both.
    """
    run_csv = REPO / "examples" / "runs" / "run01.csv"
    table_csv = REPO / "examples" / "sweep_table" / "robot_sweep.csv"
    docs = {}
    for name, inputs in (
        ("runs", [run_csv]),
        ("table", [table_csv]),
        ("both", [run_csv, table_csv]),
    ):
        out = tmp_path / name
        assert identify.main([*map(str, inputs), "--out", str(out)]) == 0
        docs[name] = json.loads((out / "identification.json").read_text())
    assert len({tuple(d) for d in docs.values()}) == 1, {n: list(d) for n, d in docs.items()}
    assert list(docs["runs"]["data_sets"]) == ["runs"] and docs["runs"]["table"] is None
    assert list(docs["table"]["data_sets"]) == ["table"] and docs["table"]["runs"] == []
    assert set(docs["both"]["data_sets"]) == {"runs", "table"}
    model = load_model()
    runs = check_runs([runs_from_csv(run_csv)])
    direct = identify_plant(
        runs, model, noise_estimates(runs, simulate_runs([model], runs)[0], model)
    )
    for k, p in docs["runs"]["parameters"].items():
        assert p["value"] == direct.values[k]  # the runs' own fit, to the last digit
