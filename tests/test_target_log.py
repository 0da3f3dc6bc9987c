"""A real-time target's MAT log (flaair_tools.bagio.target_log), written by independent writers:
scipy.io.savemat for MAT v5 (plain and compressed) and hdf5storage for MATLAB v7.3 (HDF5).
Every damaged or wrong file is one LabFileError naming the file, never another exception.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from flaair_tools.bagio.target_log import LabFileError, read_target_log

FS = 20000.0
LABELS = ("amp_in", "pvdf_act", "pvdf_hinge", "cam_trig")


def structure_with_time(
    n: int = 400, labels: tuple[str, ...] = LABELS, time_s: np.ndarray | None = None
) -> dict:
    """A Simulink Structure-with-time log: time N x 1, signals a 1 x k struct array."""
    t = np.arange(n) / FS if time_s is None else time_s
    signals = np.zeros(
        (1, len(labels)), dtype=[("values", object), ("label", object), ("blockName", object)]
    )
    for k, label in enumerate(labels):
        signals[0, k] = (
            np.sin(2 * np.pi * (k + 1) * 50.0 * t).reshape(-1, 1) * (k + 1),
            label,
            f"rig/{label}",
        )
    return {"time": t.reshape(-1, 1), "signals": signals, "blockName": "rig"}


def write_v5(path: Path, log: dict, compress: bool = False, name: str = "run_log") -> Path:
    import scipy.io

    scipy.io.savemat(str(path), {"note": np.array([1.0]), name: log}, do_compression=compress)
    return path


def write_v73(path: Path, log: dict, name: str = "run_log") -> Path:
    import hdf5storage

    hdf5storage.savemat(str(path), {name: log}, format="7.3", matlab_compatible=True)
    return path


WRITERS = {
    "v5": write_v5,
    "v5-compressed": lambda p, log: write_v5(p, log, compress=True),
    "v7.3": write_v73,
}


@pytest.mark.parametrize("version", WRITERS)
def test_each_version_reads_back_the_signals_asked_for(tmp_path: Path, version: str) -> None:
    log = structure_with_time()
    path = WRITERS[version](tmp_path / "run.mat", log)
    got = read_target_log(path, ["pvdf_act", "amp_in"])
    assert got.variable == "run_log" and got.labels == LABELS
    assert set(got.signals) == {"pvdf_act", "amp_in"}
    np.testing.assert_array_equal(got.signals["pvdf_act"], log["signals"][0, 1]["values"].ravel())
    np.testing.assert_array_equal(got.time_s, log["time"].ravel())
    assert got.sample_rate_hz == pytest.approx(FS)


@pytest.mark.parametrize("version", WRITERS)
def test_a_log_of_one_signal_reads_too(tmp_path: Path, version: str) -> None:
    log = structure_with_time(labels=("amp_in",))
    got = read_target_log(WRITERS[version](tmp_path / "one.mat", log), ["amp_in"])
    np.testing.assert_array_equal(got.signals["amp_in"], log["signals"][0, 0]["values"].ravel())


@pytest.mark.parametrize("version", WRITERS)
def test_a_label_the_rig_names_but_the_log_lacks_is_named(tmp_path: Path, version: str) -> None:
    path = WRITERS[version](tmp_path / "run.mat", structure_with_time())
    with pytest.raises(
        LabFileError,
        match=r"run.mat: variable 'run_log': no signal labelled 'pvdf_wing' "
        r"\(the log holds: 'amp_in', 'pvdf_act'",
    ):
        read_target_log(path, ["amp_in", "pvdf_wing"])


@pytest.mark.parametrize("version", WRITERS)
def test_non_uniform_time_is_refused(tmp_path: Path, version: str) -> None:
    t = np.arange(400) / FS
    t[200:] += 0.5 / FS  # a dropped half sample: not one clock
    path = WRITERS[version](tmp_path / "run.mat", structure_with_time(time_s=t))
    with pytest.raises(LabFileError, match="time is not uniform"):
        read_target_log(path, ["amp_in"])


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_a_file_without_a_structure_with_time_variable_is_refused(
    tmp_path: Path, version: str
) -> None:
    import hdf5storage
    import scipy.io

    path = tmp_path / "other.mat"
    data = {"gains": {"kp": np.array([[1.0]])}, "trace": np.zeros((10, 1))}
    if version == "v5":
        scipy.io.savemat(str(path), data)
    else:
        hdf5storage.savemat(str(path), data, format="7.3", matlab_compatible=True)
    with pytest.raises(
        LabFileError, match=re.escape("other.mat: no variable in Structure-with-time form")
    ):
        read_target_log(path, ["amp_in"])


def test_a_file_that_is_not_a_mat_file_is_named(tmp_path: Path) -> None:
    path = tmp_path / "run.mat"
    path.write_text("time,drive_v\n0,1\n")
    with pytest.raises(LabFileError, match=r"run.mat: not a MATLAB MAT file \(version 5 or 7.3\)"):
        read_target_log(path, ["amp_in"])
    with pytest.raises(LabFileError, match=re.escape("missing.mat: cannot read")):
        read_target_log(tmp_path / "missing.mat", ["amp_in"])


@pytest.fixture(scope="module")
def good_files(tmp_path_factory) -> dict[str, bytes]:
    root = tmp_path_factory.mktemp("mat")
    return {
        version: writer(root / f"{version}.mat", structure_with_time(2000)).read_bytes()
        for version, writer in WRITERS.items()
    }


@settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    version=st.sampled_from(sorted(WRITERS)),
    cut=st.floats(0.0, 0.999),
    flips=st.lists(st.tuples(st.floats(0.0, 0.999), st.integers(0, 255)), max_size=8),
)
@pytest.mark.slow  # every cut and damage of a MAT log through the reader
def test_cut_or_damaged_files_give_a_lab_file_error_or_the_right_values(
    tmp_path: Path, good_files, version, cut, flips
) -> None:
    data = bytearray(good_files[version])
    for where, byte in flips:
        data[int(where * len(data))] = byte
    data = data[: max(1, int(len(data) * (1 - cut)))] if cut > 0.001 else data
    path = tmp_path / "damaged.mat"
    path.write_bytes(bytes(data))
    try:
        got = read_target_log(path, ["amp_in"])
    except LabFileError as exc:
        assert "damaged.mat" in str(exc)
    # damage the reader could not see: data it read
    else:
        assert got.signals["amp_in"].size == got.time_s.size


@settings(max_examples=30, deadline=None)
@given(
    data=st.binary(max_size=4096),
    prefix=st.sampled_from([b"", b"MATLAB 5.0 MAT-file", b"\x89HDF\r\n\x1a\n"]),
)
@pytest.mark.slow  # property test: many random byte strings through the MAT reader
def test_random_bytes_give_a_lab_file_error(tmp_path_factory, data: bytes, prefix: bytes) -> None:
    path = tmp_path_factory.mktemp("bytes") / "random.mat"
    path.write_bytes(prefix + data)
    with pytest.raises(LabFileError, match=re.escape("random.mat")):
        read_target_log(path, ["amp_in"])
