"""`flaair analyze` on a lab's imported runs: drive recognition, calibration, partial bags."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run_offline

# CLI runs of import and analyze on 5 s of a lab's runs: `make test`, not the edit-test loop
pytestmark = pytest.mark.slow

FS = 20000.0
# the bench robot's hidden hinge strain transfer: pitch gain 24.87 / 0.23 = 108 deg/V
HINGE_EFFICIENCY = 0.23


def bench_model():
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model

    return with_effects(
        load_model(), {"strain_transfer_loss": {"efficiency": HINGE_EFFICIENCY, "channel": "pitch"}}
    )


@functools.cache
def lab_runs() -> dict[str, dict[str, np.ndarray]]:
    """A lab's typical set: a chirp, a stepped sine (60-200 Hz, 10 Hz, 0.2 s) and a 100 Hz sine.
    Simulated once per test process (read only: the tests write and encode them).
    """
    from flaair_sim.core.drive import (
        DriveParams,
        drive_record,
        stepped_sine,
        stepped_sine_frequencies_hz,
    )
    from flaair_sim.core.measured_run import synthesize_measured_run

    model, rng = bench_model(), np.random.default_rng(7)
    chirp = drive_record(
        DriveParams(kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=1.0),
        FS,
        20000,
    )
    stepped, _ = stepped_sine(FS, 100.0, stepped_sine_frequencies_hz(60.0, 200.0, 10.0), 0.2)
    sine = 75.0 * np.sin(2 * np.pi * 100.0 * np.arange(20000) / FS)
    return {
        name: synthesize_measured_run(drive, FS, model, rng)
        for name, drive in (("chirp_full", chirp), ("stepped", stepped), ("sine100", sine))
    }


@pytest.fixture(scope="module")
def lab_bag(tmp_path_factory) -> Path:
    from flaair_common.runcsv import write_run

    directory = tmp_path_factory.mktemp("lab")
    paths = []
    for name, columns in lab_runs().items():
        write_run(directory / f"{name}.csv", columns)
        paths.append(str(directory / f"{name}.csv"))
    result = run_offline(
        [FLAAIR, "import", *paths, "--out", str(directory / "bag")], isolated_env(), 180
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return directory / "bag"


@pytest.fixture(scope="module")
def uncalibrated(lab_bag: Path, tmp_path_factory) -> dict:
    from flaair_tools.analysis.analyze import analyze

    return analyze([lab_bag], tmp_path_factory.mktemp("rep"), progress=False)


def calibration_file(directory: Path) -> Path:
    """The bench robot's true gains, as `flaair calibrate` writes them."""
    path = directory / "calibration.yaml"
    path.write_text(
        "reference_voltage_v: 1.25\nstroke: "
        f"{{gain_deg_per_v: 25.39, polarity: -1, offset_v: 0.0, lag_s: 0.0}}\npitch: "
        f"{{gain_deg_per_v: {24.87 / HINGE_EFFICIENCY:.4f}, polarity: -1, "
        "offset_v: 0.0, lag_s: 0.0}\n"
    )
    return path


def test_each_imported_run_is_recognised_and_analysed_by_its_drive(uncalibrated: dict) -> None:
    (bag,) = uncalibrated["bags"]
    runs = bag["runs"]
    assert {name: r["drive"]["kind"] for name, r in runs.items()} == {
        "chirp_full": "chirp",
        "stepped": "stepped_sine",
        "sine100": "sine",
    }
    steps = [s["frequency_hz"] for s in runs["stepped"]["drive"]["steps"]]
    assert steps == pytest.approx(list(range(60, 201, 10)), abs=0.02)
    # stepped sine: one Bode point per step, at the step frequency (no jagged chirp-style Bode)
    assert runs["stepped"]["method"] == "stepped"
    assert runs["stepped"]["bode"]["pitch"]["frequency_hz"] == pytest.approx(steps)
    # the sine: gain and phase at its one frequency
    sine = runs["sine100"]
    assert sine["frequency_hz"] == pytest.approx(100.0, abs=1e-3) and sine["bode"]["stroke"][
        "frequency_hz"
    ] == pytest.approx([100.0], abs=1e-3)
    assert sine["stroke"]["gain_deg_per_v"] == pytest.approx(25.39, rel=0.02)
    assert sine["pitch"]["gain_deg_per_v"] == pytest.approx(24.87 / HINGE_EFFICIENCY, rel=0.03)


def test_lab_runs_get_the_paper_headline_figures(uncalibrated: dict) -> None:
    h = uncalibrated["headline"]
    assert h["stroke_gain_deg_per_v"]["flaair"] == pytest.approx(25.39, rel=0.01)
    assert h["stroke_gain_deg_per_v"]["source"].endswith("/chirp_full")
    assert h["pitch_gain_deg_per_v"]["flaair"] == pytest.approx(24.87 / HINGE_EFFICIENCY, rel=0.02)
    assert h["pitch_gain_deg_per_v"]["source"].endswith("/stepped")
    # The session's robot is the model's plant read through its sensors and a tracked camera, so
    # the sensor-vs-truth errors are noise-level: measured 0.013-0.021 deg in amplitude, 0.26-0.28
    # deg in phase, 0.37 deg in time; the bounds are about 3x those, each far below the paper's.
    bounds = {
        "stroke_amplitude_rmse_deg": 0.06,
        "stroke_phase_rmse_deg": 0.8,
        "pitch_amplitude_rmse_deg": 0.06,
        "pitch_amplitude_rmse_band_deg": 0.06,
        "pitch_phase_rmse_deg": 0.8,
        "pitch_time_rmse_lag_corrected_band_deg": 1.0,
    }
    for key, bound in bounds.items():
        assert 0.0 < h[key]["flaair"] < bound, (key, h[key])
        assert h[key]["flaair"] < h[key]["paper"] / 3, (key, h[key])
    # fitted gain: the hidden 0.23 is absorbed
    assert h["pitch_amplitude_rmse_band_deg"]["flaair"] < 1.0
    assert (
        h["pitch_gain_deg_per_v"]["label"] == "Pitch (hinge) sensor gain"
        and h["pitch_gain_deg_per_v"]["unit"] == "deg/V"
    )


def test_without_calibration_pitch_reads_small_and_analyze_says_so(
    uncalibrated: dict, lab_bag: Path, tmp_path: Path
) -> None:
    assert uncalibrated["model_gains_warning"] and "4.3x" in uncalibrated["model_gains_warning"]
    # With the model's gains the estimate's pitch is 0.23x
    # the truth: the collision metric shrinks with it.
    from flaair_tools.analysis.analyze import analyze

    calibrated = analyze(
        [lab_bag], tmp_path / "cal", progress=False, calibration_file=calibration_file(tmp_path)
    )
    assert calibrated["model_gains_warning"] is None
    assert "calibration" in calibrated["bags"][0]["estimate_source"]
    small = uncalibrated["bags"][0]["runs"]["sine100"]["collision_metric"]["time_rmse_deg"]
    right = calibrated["bags"][0]["runs"]["sine100"]["collision_metric"]["time_rmse_deg"]
    assert right / small == pytest.approx(1 / HINGE_EFFICIENCY, rel=0.1)
    html = (tmp_path / "cal" / "report.html").read_text()
    assert "Front end on model gains" not in html
    result = run_offline(
        [FLAAIR, "analyze", str(lab_bag), "--out", str(tmp_path / "cli")], isolated_env(), 240
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "WARNING: the front end runs on the model's gains" in result.stderr
    assert "Front end on model gains" in (tmp_path / "cli" / "report.html").read_text()


def test_a_bad_calibration_file_is_named_exit_2(lab_bag: Path, tmp_path: Path) -> None:
    bad = tmp_path / "calibration.yaml"
    bad.write_text(
        calibration_file(tmp_path)
        .read_text()
        .replace("gain_deg_per_v: 25.39", "gain_deg_per_v: abc")
    )
    result = run_offline(
        [
            FLAAIR,
            "analyze",
            str(lab_bag),
            "--out",
            str(tmp_path / "rep"),
            "--calibration",
            str(bad),
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 2
    assert str(bad) in result.stderr and "Traceback" not in result.stderr


def test_import_kind_is_used_and_a_disagreeing_drive_is_warned(tmp_path: Path) -> None:
    from flaair_common.runcsv import write_run
    from flaair_tools.analysis.analyze import analyze

    write_run(tmp_path / "sweep.csv", lab_runs()["chirp_full"])
    result = run_offline(
        [
            FLAAIR,
            "import",
            str(tmp_path / "sweep.csv"),
            "--out",
            str(tmp_path / "bag"),
            "--kind",
            "chirp",
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    report = analyze([tmp_path / "bag"], tmp_path / "rep", progress=False)
    assert (
        report["bags"][0]["runs"]["sweep"]["drive"]["kind"] == "chirp"
        and not report["bags"][0]["warnings"]
    )
    result = run_offline(
        [
            FLAAIR,
            "import",
            str(tmp_path / "sweep.csv"),
            "--out",
            str(tmp_path / "bag2"),
            "--kind",
            "free",
        ],
        isolated_env(),
        120,
    )
    report = analyze([tmp_path / "bag2"], tmp_path / "rep2", progress=False)
    assert "marked 'free' but its drive looks like 'chirp'" in report["bags"][0]["warnings"][0]


def truncated_bag(columns: dict[str, np.ndarray], out: Path, fraction: float) -> None:
    """A bag holding the first `fraction` of a run's
    messages, as a recovered bag does (marker intact).
    """
    from flaair_common.runcsv import MeasuredRun
    from flaair_tools import bagio
    from flaair_tools.bagio.import_runs import (
        DRIVE_TYPE,
        SENSOR_TYPE,
        WING_TYPE,
        encode_run,
        run_marker,
    )

    run = MeasuredRun("stepped", FS, columns)
    with bagio.BagWriter(out) as writer:
        messages = list(
            encode_run(
                run,
                start_ns=0,
                first_sample_index=0,
                block_size=10,
                frame_id="robot",
                truth_source=writer.store.types[WING_TYPE].SOURCE_GROUND_TRUTH,
            )
        )
        writer.write_message(
            bagio.RUN_MARKER_TOPIC,
            0,
            bagio.new_message(
                bagio.RUN_MARKER_TYPE,
                writer.store,
                data=run_marker(
                    run, source_file="stepped.csv", start_ns=0, first_sample_index=0
                ).to_json(),
            ),
        )
        for topic, msgtype in (
            ("/flaair/drive", DRIVE_TYPE),
            ("/flaair/sensor_v", SENSOR_TYPE),
            ("/flaair/wing_state/truth", WING_TYPE),
        ):
            writer.add_topic(topic, msgtype)
        for topic, stamp_ns, data in messages[: int(len(messages) * fraction)]:
            writer.write(topic, stamp_ns, data)


def test_partial_bag_names_what_is_missing_and_exits_3_unless_allowed(tmp_path: Path) -> None:
    truncated_bag(lab_runs()["stepped"], tmp_path / "bag", 0.16)
    result = run_offline(
        [FLAAIR, "analyze", str(tmp_path / "bag"), "--out", str(tmp_path / "rep")],
        isolated_env(),
        120,
    )
    assert result.returncode == 3, result.stderr[-2000:]
    assert "run 'stepped' holds 16% of its marked samples (0.48 of 3 s)" in result.stderr
    assert (
        "steps found: 60, 70, 80 Hz, the steps after them are missing" in result.stderr
        and "--allow-partial" in result.stderr
    )
    assert "Incomplete data" in (tmp_path / "rep" / "report.html").read_text()
    result = run_offline(
        [
            FLAAIR,
            "analyze",
            str(tmp_path / "bag"),
            "--out",
            str(tmp_path / "rep2"),
            "--allow-partial",
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "incomplete: " in result.stderr
    report = json.loads((tmp_path / "rep2" / "report.json").read_text())
    assert len(report["partial"]) == 1
    full = tmp_path / "full"
    truncated_bag(lab_runs()["stepped"], full, 1.0)
    assert (
        run_offline(
            [FLAAIR, "analyze", str(full), "--out", str(tmp_path / "rep3")], isolated_env(), 120
        ).returncode
        == 0
    )
