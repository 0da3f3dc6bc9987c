"""A paper experiment recorded over the real graph, then analysed from the bag alone."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run


@pytest.fixture(scope="module")
def chirp_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("exp") / "chirp"
    result = run(
        [FLAAIR, "experiment", "characterization_chirp", "--nominal", "--out", str(bag)],
        isolated_env(),
        300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return bag


@pytest.mark.graph  # ROS 2 processes exchanging data in real time: run after the others
def test_experiment_records_every_block(chirp_bag: Path) -> None:
    from flaair_tools import bagio

    counts = bagio.message_counts(chirp_bag)
    # 1 s of 0.5 ms blocks, then the drive's closing zero block (the plant steps it too)
    for topic in (
        "/flaair/drive",
        "/flaair/sensor_v",
        "/flaair/wing_state",
        "/flaair/wing_state/truth",
    ):
        assert counts[topic] == 2001, (topic, counts)
    # the plant's sim time is in the bag too, one /clock per block (no node of this graph
    # publishes /diagnostics: tests/test_live.py reads a bag's health back)
    assert counts["/clock"] == 2001, counts
    drive = bagio.read_blocks(chirp_bag, "/flaair/drive")
    assert np.all(drive["drive_v"][-10:] == 0.0) and np.abs(drive["drive_v"][-20:-10]).max() > 1.0
    markers = bagio.read_run_markers(chirp_bag)
    assert [(m.run, m.first_sample_index, m.n_samples) for m in markers] == [
        ("chirp_200vpp", 0, 20000)
    ]


@pytest.mark.graph
def test_analyze_reports_paper_figures_from_the_bag(chirp_bag: Path, tmp_path: Path) -> None:
    result = run([FLAAIR, "analyze", str(chirp_bag), "--out", str(tmp_path)], isolated_env(), 120)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["headline"]["stroke_gain_deg_per_v"]["flaair"] == pytest.approx(25.39, rel=0.01)
    assert report["headline"]["stroke_gain_deg_per_v"]["paper"] == 25.5
    chirp = report["bags"][0]["runs"]["chirp_200vpp"]
    peak_hz = chirp["bode"]["stroke"]["frequency_hz"][
        int(np.argmax(chirp["bode"]["stroke"]["truth_amplitude_deg"]))
    ]
    assert 120.0 <= peak_hz <= 150.0
    assert (tmp_path / "report.html").read_text().count("<img") >= 1
    assert report["bags"][0]["diagnostic_events"] == []  # no health published, none listed
    assert (tmp_path / chirp["figure"]).stat().st_size > 10_000


@pytest.mark.slow  # records a bag from the simulated plant, then analyses it
def test_analyze_numbers_follow_the_bag_not_the_simulator(tmp_path: Path) -> None:
    """An imported lab bag with a hidden 0.25 hinge
    strain-transfer efficiency: the report sees it.
    """
    from flaair_common.runcsv import write_run
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.measured_run import synthesize_measured_run
    from flaair_tools import bagio

    model = with_effects(
        load_model(), {"strain_transfer_loss": {"efficiency": 0.25, "channel": "pitch"}}
    )
    drive = drive_record(
        DriveParams(kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=1.0),
        20000.0,
        20000,
    )
    write_run(
        tmp_path / "lab.csv",
        synthesize_measured_run(drive, 20000.0, model, np.random.default_rng(3)),
    )
    assert (
        run(
            [FLAAIR, "import", str(tmp_path / "lab.csv"), "--out", str(tmp_path / "bag")],
            isolated_env(),
            120,
        ).returncode
        == 0
    )
    result = run(
        [FLAAIR, "analyze", str(tmp_path / "bag"), "--out", str(tmp_path / "rep")],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    lab = report["bags"][0]
    # no live estimate in a lab bag: the core ran on the voltages
    assert "offline" in lab["estimate_source"]
    (only_run,) = lab["runs"].values()
    # the hidden 0.25, found
    assert only_run["pitch"]["gain_deg_per_v"] == pytest.approx(4 * 24.87, rel=0.01)
    assert only_run["stroke"]["gain_deg_per_v"] == pytest.approx(25.39, rel=0.01)
    # With the model's gains (the live front end's) the pitch estimate is 4x too small: a large
    # amplitude error; with the fitted gain (the paper's "for this gain") it is gone.
    assert (
        only_run["live"]["pitch"]["amplitude_rmse_deg"]
        > 5.0
        > only_run["live"]["stroke"]["amplitude_rmse_deg"]
    )
    assert only_run["pitch"]["amplitude_rmse_deg"] < 0.5
    assert bagio.message_counts(tmp_path / "bag")["/flaair/sensor_v"] == 2000
