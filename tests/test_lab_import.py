"""A lab's own files into bags (`flaair import RUN.mat --rig --tracks`): a simulated bench run put
through a camera geometry and written as MAT v5, MAT v7.3 and DLTdv8 CSVs (tests/lab_files.py)
comes back with the generator's angles, calibrates to the bench robot's gains, and analyses;
bad files are refused by name with exit 2 and leave no bag.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lab_files as lf
from rosproc import FLAAIR, isolated_env, run_offline


@pytest.fixture(scope="module")
def chirp() -> dict[str, np.ndarray]:
    return lf.chirp_run()


@pytest.fixture(scope="module")
def session(chirp, tmp_path_factory) -> dict[str, lf.LabSession]:
    root = tmp_path_factory.mktemp("lab")
    return {
        version: lf.write_lab_run(root, f"bench_{version.replace('.', '')}", chirp, version)
        for version in ("v5", "v7.3")
    }


def read(s: lf.LabSession, **changes):
    from flaair_tools.bagio.lab_import import LabRunFiles, read_lab_run

    files = LabRunFiles(s.mat, s.rig, s.tracks, s.tip_track)
    for key, value in changes.items():
        files = LabRunFiles(**{**files.__dict__, key: value})
    return read_lab_run(files, 0.002)


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_the_generators_angles_come_back_within_0_1_deg_at_the_frames(session, version) -> None:
    s = session[version]
    got = read(s)
    placed = s.frame_sample >= 0
    for column, want in (("stroke_deg", s.stroke_deg), ("pitch_deg", s.pitch_deg)):
        at_frames = got.run[column][s.frame_sample[placed]]
        tracked = np.isfinite(want[placed])
        assert np.max(np.abs(at_frames[tracked] - want[placed][tracked])) < 0.1
        assert np.isnan(at_frames[~tracked]).all()  # untracked frames stay NaN
    between = np.ones(got.run["stroke_deg"].size, bool)
    between[s.frame_sample[placed]] = False
    assert np.isnan(got.run["stroke_deg"][between]).all()  # NaN between the frames
    sync = got.extras["sync"]
    assert sync["trigger_time_s"] == pytest.approx(lf.TRIGGER_S, abs=0.5 / lf.FS_HZ)
    assert sync["frames_placed"] == int(placed.sum()) and sync["frames_dropped"] == 46
    assert abs(sync["offset_s"]) < 0.25 / lf.FPS and got.warnings == []
    assert got.extras["video"]["tracked_share"] == pytest.approx(0.98, abs=0.002)
    np.testing.assert_allclose(got.run["drive_v"], read(session["v5"]).run["drive_v"])


def test_stroke_from_the_actuator_tip_follows_the_transmission_ratio(session, tmp_path) -> None:
    s = session["v5"]
    rig = tmp_path / "tip_rig.yaml"
    rig.write_text(yaml.safe_dump(lf.rig_mapping(stroke_from="actuator_tip")))
    got = read(s, rig=rig).run["stroke_deg"][s.frame_sample[s.frame_sample >= 0]]
    want = s.stroke_deg[s.frame_sample >= 0]
    tracked = np.isfinite(want)
    # zero at the tip's mean position over the tracked frames: the stroke less a constant
    difference = got[tracked] - want[tracked]
    assert np.ptp(difference) < 0.01 and abs(np.mean(difference)) < 0.5


def test_sync_by_frame0_time_gives_the_same_run(session, tmp_path) -> None:
    s = session["v5"]
    rig = tmp_path / "frame0_rig.yaml"
    rig.write_text(yaml.safe_dump(lf.rig_mapping(sync="frame0_time_s")))
    by_time, by_trigger = read(s, rig=rig), read(s)
    np.testing.assert_array_equal(by_time.run["stroke_deg"], by_trigger.run["stroke_deg"])
    assert by_time.extras["sync"]["trigger_time_s"] is None
    assert by_time.extras["sync"]["method"] == "frame0_time_s"


def test_a_wrong_trigger_frame_shows_as_an_offset_and_is_warned(session, tmp_path) -> None:
    rig = tmp_path / "off_rig.yaml"
    rig.write_text(yaml.safe_dump(lf.rig_mapping(trigger_frame=lf.TRIGGER_FRAME + 3)))
    got = read(session["v5"], rig=rig)
    # frames placed 3 frames early: the video's stroke leads the sensor's by 0.3 ms
    assert got.extras["sync"]["offset_s"] == pytest.approx(-3 / lf.FPS, abs=0.25 / lf.FPS)
    assert len(got.warnings) == 1 and "ms off, more than one frame (0.100 ms)" in got.warnings[0]


def main_in_process(module, argv: list[str]) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of a `flaair` subcommand's main run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = module.main(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def imported(session, tmp_path_factory) -> dict[str, Path]:
    """v7.3 through the command a lab types (a process of its own), v5 in this process."""
    from flaair_tools.bagio import import_cli

    out = {}
    for version, s in session.items():
        bag = tmp_path_factory.mktemp("bags") / f"bag_{version}"
        argv = [
            str(s.mat),
            "--rig",
            str(s.rig),
            "--tracks",
            str(s.tracks),
            "--tip-track",
            str(s.tip_track),
            "--out",
            str(bag),
        ]
        if version == "v7.3":
            result = run_offline([FLAAIR, "import", *argv], isolated_env(), 180)
            code, stdout, stderr = result.returncode, result.stdout, result.stderr
        else:
            code, stdout, stderr = main_in_process(import_cli, argv)
        assert code == 0, stderr
        assert (
            "video 10000 fps, 10046 frames (98.0 % tracked), 10000 placed, 46 outside the "
            "log; trigger at 0.012300 s; video vs stroke sensor" in stdout
        )
        out[version] = bag
    return out


@pytest.mark.slow  # imports two MAT versions to bags and calibrates each
def test_both_mat_versions_import_to_bags_that_calibrate_to_the_bench_robot(
    imported, tmp_path
) -> None:
    from flaair_tools.analysis import calibrate

    gains = {}
    for version, bag in imported.items():
        code, _, stderr = main_in_process(calibrate, [str(bag), "--out", str(tmp_path / version)])
        assert code == 0, stderr
        gains[version] = json.loads((tmp_path / version / "calibration.json").read_text())
    for cal in gains.values():
        assert cal["stroke"]["gain_deg_per_v"] == pytest.approx(25.4, rel=0.01)
        assert cal["pitch"]["gain_deg_per_v"] == pytest.approx(108.0, rel=0.01)
    assert gains["v5"]["stroke"]["gain_deg_per_v"] == gains["v7.3"]["stroke"]["gain_deg_per_v"]


def test_the_bag_records_files_rig_and_sync_and_analyze_shows_the_video(imported) -> None:
    from flaair_tools import bagio
    from flaair_tools.analysis.analyze import analyze_bag

    bag = imported["v7.3"]
    marker = json.loads(
        next(
            iter(bagio.read_bag(bag, [bagio.RUN_MARKER_TOPIC]).messages(bagio.RUN_MARKER_TOPIC))
        ).data
    )
    assert marker["lab_files"]["variable"] == "rt_log"
    assert marker["lab_files"]["tracks"].endswith("bench_v73_xyzpts.csv")
    assert yaml.safe_load(marker["rig"])["video"]["fps"] == lf.FPS
    assert marker["sync"]["frames_dropped"] == 46
    result, _ = analyze_bag(bag, 1.25)
    video = result["runs"]["bench_v73"]["video"]
    assert video["fps"] == lf.FPS and video["tracked_share"] == pytest.approx(0.98, abs=0.002)
    assert result["runs"]["bench_v73"]["drive"]["kind"] == "chirp"


@pytest.mark.slow  # imports a session's runs into a bag
def test_a_session_manifest_imports_every_run_into_one_bag(session, tmp_path) -> None:
    manifest = tmp_path / "session.yaml"
    manifest.write_text(
        yaml.safe_dump(
            {
                "rig": str(session["v5"].rig),
                "runs": [
                    {"mat": str(s.mat), "tracks": str(s.tracks), "tip_track": str(s.tip_track)}
                    for s in session.values()
                ],
            }
        )
    )
    from flaair_tools.bagio import import_cli

    code, stdout, stderr = main_in_process(
        import_cli, ["--manifest", str(manifest), "--out", str(tmp_path / "bag")]
    )
    assert code == 0, stderr
    assert stdout.count("video 10000 fps") == 2 and "bench_v73: " in stdout


BAD_RIGS = {
    "missing key": (lambda r: r["video"].pop("fps"), "video: missing key(s) fps"),
    "unknown key": (lambda r: r["geometry"].update(upp=[0, 0, 1]), "geometry: unknown key(s) upp"),
    "label the log lacks": (
        lambda r: r["signals"].update(pitch_sensor="pvdf_wing"),
        "no signal labelled 'pvdf_wing'",
    ),
    "no trigger edge": (
        lambda r: r["video"]["sync"].update(trigger_threshold_v=7.5),
        "no rising edge through 7.5 V in the camera trigger",
    ),
    "frame rate above the DAQ rate": (
        lambda r: r["video"].update(fps=40000.0),
        "frame rate 40000 fps is above the DAQ rate 20000 Hz",
    ),
    "a point the file lacks": (
        lambda r: r["points"].update(wing_leading_edge_2=7),
        "no point 7 (wing_leading_edge_2)",
    ),
    "coinciding points": (
        lambda r: r["points"].update(wing_leading_edge_2=2),
        "the wing points must be different points",
    ),
}


@pytest.mark.parametrize("case", BAD_RIGS)
def test_a_bad_rig_or_log_is_named(session, tmp_path, case) -> None:
    from flaair_tools.bagio.target_log import LabFileError

    change, message = BAD_RIGS[case]
    mapping = lf.rig_mapping()
    change(mapping)
    rig = tmp_path / "bad_rig.yaml"
    rig.write_text(yaml.safe_dump(mapping))
    with pytest.raises(LabFileError, match=message.replace("(", r"\(").replace(")", r"\)")):
        read(session["v5"], rig=rig)


def test_bad_files_exit_2_with_one_line_and_leave_no_bag(session, tmp_path) -> None:
    s = session["v5"]
    never = tmp_path / "never_xyzpts.csv"
    lines = s.tracks.read_text().splitlines()
    header = lines[0].split(",")
    never.write_text(
        "\n".join(
            [lines[0]]
            + [
                ",".join(
                    "" if header[k].startswith("pt1_") else cell
                    for k, cell in enumerate(row.split(","))
                )
                for row in lines[1:]
            ]
        )
        + "\n"
    )
    wrong = tmp_path / "wrong_xyzpts.csv"
    wrong.write_text("frame,x,y\n1,2,3\n")
    cases = {
        "never tracked": (
            ["--tracks", str(never)],
            "point 1 (wing_leading_edge_2) is never tracked",
        ),
        "not DLTdv8": (["--tracks", str(wrong)], "column 1 'frame' is not a DLTdv8 xyzpts column"),
        "no tip track": (["--tracks", str(s.tracks)], "needs the 2D track (--tip-track"),
    }
    rig = tmp_path / "tip_rig.yaml"
    rig.write_text(yaml.safe_dump(lf.rig_mapping(stroke_from="actuator_tip")))
    from flaair_tools.bagio import import_cli

    for name, (extra, message) in cases.items():
        bag = tmp_path / f"bag_{name.replace(' ', '_')}"
        args = [str(s.mat), "--rig", str(rig if name == "no tip track" else s.rig), *extra]
        if name != "no tip track":
            args += ["--tip-track", str(s.tip_track)]
        if name == "never tracked":  # once as a lab types it, in a process of its own
            result = run_offline([FLAAIR, "import", *args, "--out", str(bag)], isolated_env(), 120)
            code, stderr = result.returncode, result.stderr
        else:
            code, _, stderr = main_in_process(import_cli, [*args, "--out", str(bag)])
        assert code == 2, (name, stderr)
        assert message in stderr and "Traceback" not in stderr, stderr
        assert len(stderr.strip().splitlines()) == 1, stderr
        assert not bag.exists()


@pytest.fixture(scope="module")
def track_bytes(session) -> dict[str, bytes]:
    s = session["v5"]
    return {
        "xyz": "\n".join(s.tracks.read_text().splitlines()[:400]).encode(),
        "xy": "\n".join(s.tip_track.read_text().splitlines()[:400]).encode(),
    }


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    kind=st.sampled_from(["xyz", "xy"]),
    cut=st.floats(0.0, 0.999),
    flips=st.lists(st.tuples(st.floats(0.0, 0.999), st.integers(0, 255)), max_size=6),
)
def test_cut_or_damaged_tracks_give_a_lab_file_error_or_points(
    tmp_path_factory, track_bytes, kind, cut, flips
) -> None:
    from flaair_tools.bagio.dlt_tracks import read_xy_point, read_xyz_points
    from flaair_tools.bagio.target_log import LabFileError

    data = bytearray(track_bytes[kind])
    for where, byte in flips:
        data[int(where * len(data))] = byte
    data = data[: max(1, int(len(data) * (1 - cut)))] if cut > 0.001 else data
    path = tmp_path_factory.mktemp("tracks") / "damaged.csv"
    path.write_bytes(bytes(data))
    try:
        if kind == "xyz":
            got = read_xyz_points(path, lf.POINTS, 0.001)["wing_leading_edge_1"]
        else:
            got = read_xy_point(path, 1, 2, "tip")
    except LabFileError as exc:
        assert "damaged.csv" in str(exc)
    else:
        assert got.ndim == 2 and np.isfinite(got).any()


@settings(max_examples=60, deadline=None)
@given(data=st.binary(max_size=2048), prefix=st.sampled_from([b"", b"pt1_X,pt1_Y,pt1_Z\n"]))
def test_random_bytes_as_tracks_give_a_lab_file_error(tmp_path_factory, data, prefix) -> None:
    from flaair_tools.bagio.dlt_tracks import read_xyz_points
    from flaair_tools.bagio.target_log import LabFileError

    path = tmp_path_factory.mktemp("bytes") / "random_xyzpts.csv"
    path.write_bytes(prefix + data)
    try:
        got = read_xyz_points(path, {"le1": 1}, 0.001)
    except LabFileError as exc:
        assert "random_xyzpts.csv" in str(exc)
    else:
        assert np.isfinite(got["le1"]).any()


def test_identify_takes_the_imported_bag_as_it_is(imported, tmp_path) -> None:
    from flaair_tools.discrepancy import identify

    code, _, stderr = main_in_process(identify, [str(imported["v5"]), "--out", str(tmp_path)])
    assert code == 0, stderr
    fitted = json.loads((tmp_path / "identification.json").read_text())["parameters"]
    # the bench robot's plant is the nominal one: the fit on the imported run lands on it
    assert fitted["stroke_natural_frequency_hz"]["value"] == pytest.approx(140.0, rel=0.01)
    assert fitted["actuator_gain_nm_per_v"]["value"] == pytest.approx(1.67e-7, rel=0.01)
