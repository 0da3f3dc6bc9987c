"""`flaair import` on what real lab files hold (docs/LAB_FILES.md, sections 1, 2, 5 and 6):
frames numbered from 1 as DLTdv numbers them, any logging rate (50 Hz, 1 kHz, 20 kHz; the sync
check said to be impossible where it is, never a traceback), a run whose wing points are never
tracked together (warned), a MATLAB object, two Scopes and N x k values beside the log, and the
refusals: one line naming the file, exit 2, no bag.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest
import yaml

import lab_files as lf
import lab_writers as lw

pytestmark = pytest.mark.timeout(240)


@pytest.fixture(scope="module")
def chirp() -> dict[str, np.ndarray]:
    return lf.chirp_run(duration_s=0.5)


def cli(argv: list[str]) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of `flaair import ARGV`, run in this process."""
    from flaair_tools.bagio import import_cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = import_cli.main(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


def argv(s: lf.LabSession, bag: Path, mat: Path | None = None, rig: Path | None = None):
    return [
        str(mat or s.mat),
        "--rig",
        str(rig or s.rig),
        "--tracks",
        str(s.tracks),
        "--tip-track",
        str(s.tip_track),
        "--out",
        str(bag),
    ]


def read(s: lf.LabSession, rig: Path | None = None, mat: Path | None = None):
    from flaair_tools.bagio.lab_import import LabRunFiles, read_lab_run

    return read_lab_run(LabRunFiles(mat or s.mat, rig or s.rig, s.tracks, s.tip_track), 0.002)


def test_the_first_row_is_dltdvs_frame_1(chirp, tmp_path: Path) -> None:
    from flaair_tools.bagio import lab_run
    from flaair_tools.bagio.rig import rig_from_mapping

    rig = rig_from_mapping(lf.rig_mapping(trigger_frame=1), "rig.yaml")
    time_s = np.arange(1000) / lf.FS_HZ
    trigger = np.where(time_s >= 0.01, 5.0, 0.0)
    placed = lab_run.place_frames(5, rig, time_s, trigger, "run.mat")
    # trigger_frame 1: the first row was taken at the edge (0.01 s, sample 200)
    np.testing.assert_allclose(placed.frame_time_s, 0.01 + np.arange(5) / lf.FPS)
    np.testing.assert_array_equal(placed.sample_index, 200 + 2 * np.arange(5))
    # a rig written from what DLTdv's frame slider shows places every frame on its sample
    s = lf.write_lab_run(tmp_path, "bench", chirp)
    got = read(s)
    at = s.frame_sample >= 0
    tracked = np.isfinite(s.stroke_deg[at])
    stroke = got.run["stroke_deg"][s.frame_sample[at]]
    assert np.max(np.abs(stroke[tracked] - s.stroke_deg[at][tracked])) < 1e-3


@pytest.mark.parametrize(
    "log_hz, fps, warned",
    [(50.0, 50.0, True), (1000.0, 500.0, True), (20000.0, 10000.0, False)],
)
def test_any_logging_rate_imports(chirp, tmp_path: Path, log_hz, fps, warned) -> None:
    s = lf.write_lab_run(
        tmp_path, "rate", chirp, log_hz=log_hz, fps=fps, stroke_from="actuator_tip"
    )
    code, stdout, stderr = cli(argv(s, tmp_path / "bag"))
    assert code == 0 and "Traceback" not in stderr, stderr
    assert f"samples at {log_hz:g} Hz" in stdout and f"video {fps:g} fps" in stdout
    message = "the sync check cannot be made at the log's rate"
    assert (message in stderr) == warned, stderr
    if warned:
        assert len(stderr.strip().splitlines()) == 1 and "rate.mat: " in stderr
        assert "video vs stroke sensor" not in stdout
    got = read(s)
    at = s.frame_sample >= 0
    tracked = np.isfinite(s.pitch_deg[at])
    pitch = got.run["pitch_deg"][s.frame_sample[at]]
    assert tracked.sum() > 10 and np.max(np.abs(pitch[tracked] - s.pitch_deg[at][tracked])) < 0.1


def test_wing_points_never_tracked_together_are_warned(chirp, tmp_path: Path) -> None:
    s = lf.write_lab_run(tmp_path, "apart", chirp, never_together=True, stroke_from="actuator_tip")
    got = read(s)
    assert np.isnan(got.run["pitch_deg"]).all() and np.isfinite(got.run["stroke_deg"]).any()
    code, _, stderr = cli(argv(s, tmp_path / "bag"))
    assert code == 0 and (tmp_path / "bag").exists()
    assert "apart_xyzpts.csv: the wing's points (wing_leading_edge_1 = 2, " in stderr
    assert "are never tracked in the same frame: the run's pitch truth is all NaN" in stderr


@pytest.fixture(scope="module")
def bench(chirp, tmp_path_factory) -> tuple[lf.LabSession, dict[str, np.ndarray]]:
    from flaair_tools.bagio.target_log import read_target_log

    s = lf.write_lab_run(tmp_path_factory.mktemp("bench"), "bench", chirp)
    log = read_target_log(s.mat, ["amp_in", "pvdf_act", "pvdf_hinge", "cam_trig"])
    return s, {"time": log.time_s, **log.signals}


def scope(signals: dict[str, np.ndarray], time_s: np.ndarray) -> dict:
    """A Structure-with-time log whose values may be N x k."""
    array = np.zeros(
        (1, len(signals)), dtype=[("values", object), ("label", object), ("blockName", object)]
    )
    for k, (label, values) in enumerate(signals.items()):
        array[0, k] = (values.reshape(time_s.size, -1), label, f"bench/{label}")
    return {"time": time_s.reshape(-1, 1), "signals": array, "blockName": "bench"}


def test_an_object_two_scopes_and_columns_import_as_the_plain_file(bench, tmp_path) -> None:
    s, log = bench
    t = log["time"]
    films = np.column_stack([log["pvdf_hinge"], log["pvdf_act"]])  # one Scope, two inputs
    first = scope({"amp_in": log["amp_in"], "films": films, "cam_trig": log["cam_trig"]}, t)
    second = scope({"amp_in": log["amp_in"] * 0}, t)
    mat = lw.write_v5_with_object(
        tmp_path / "saved.mat",
        {"ScopeData": first, "ScopeData1": second},
        {"tg": "slrealtime.Target", "out": "Simulink.SimulationOutput"},
    )
    mapping = lf.rig_mapping()
    mapping["log_variable"] = "ScopeData"
    mapping["signals"].update(stroke_sensor="films[2]", pitch_sensor="films[1]")
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump(mapping))
    got, plain = read(s, rig=rig, mat=mat), read(s)
    for column in ("drive_v", "stroke_sensor_v", "pitch_sensor_v", "stroke_deg"):
        np.testing.assert_array_equal(got.run[column], plain.run[column])
    assert got.extras["lab_files"]["variable"] == "ScopeData"


def test_bad_logs_exit_2_with_one_line_and_leave_no_bag(bench, tmp_path: Path) -> None:
    s, log = bench
    t = log["time"]
    four = {k: log[k] for k in ("amp_in", "pvdf_act", "pvdf_hinge", "cam_trig")}
    dup = scope(four, t)  # a fifth signal with the label of the second
    dup["signals"] = np.concatenate([dup["signals"], dup["signals"][:, 1:2]], axis=1)
    nk = scope({**four, "pvdf_act": np.column_stack([log["pvdf_act"], log["pvdf_hinge"]])}, t)
    files = {
        "dup.mat": ({"rt_log": dup}, "2 signals are labelled 'pvdf_act': signals 2, 5 (blockName"),
        "nk.mat": ({"rt_log": nk}, "signal 'pvdf_act' has 2 columns (a Scope with several"),
        "two.mat": (
            {"rt_log": scope(four, t), "rt_log2": scope(four, t)},
            "2 variables in Structure-with-time form ('rt_log', 'rt_log2'): name the log",
        ),
    }
    for name, (variables, message) in files.items():
        mat = lw.write_v5_with_object(tmp_path / name, variables, {"tg": "slrealtime.Target"})
        bag = tmp_path / f"bag_{name}"
        code, _, stderr = cli(argv(s, bag, mat=mat))
        assert code == 2, (name, stderr)
        assert f"{mat}: " in stderr and message in stderr and "Traceback" not in stderr, stderr
        assert len(stderr.strip().splitlines()) == 1, stderr
        assert not bag.exists()
    mapping = lf.rig_mapping()
    mapping["signals"]["drive"] = "amp_in[0]"
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump(mapping))
    code, _, stderr = cli(argv(s, tmp_path / "bag_rig", rig=rig))
    assert code == 2 and "signals.drive: 'amp_in[0]': a column is named as 'label[j]'" in stderr
    # a rig written when frames were counted from 0
    rig.write_text(yaml.safe_dump(lf.rig_mapping(trigger_frame=0)))
    code, _, stderr = cli(argv(s, tmp_path / "bag_rig0", rig=rig))
    assert code == 2 and "video.sync.trigger_frame: 0: DLTdv numbers frames from 1" in stderr
    assert len(stderr.strip().splitlines()) == 1 and not (tmp_path / "bag_rig0").exists()
