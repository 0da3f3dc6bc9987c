"""What real MAT saves hold beside a Simulink log (docs/LAB_FILES.md, section 1): a MATLAB object
caught by a plain `save` (MCOS bytes as MATLAB writes them, tests/lab_writers.py), two Scopes'
logs in one file (`log_variable`), a Scope with several inputs (N x k values, "label[j]"),
labels two signals share, and logs at 50 Hz, 1 kHz and 20 kHz.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lab_writers as lw
from flaair_tools.bagio.target_log import LabFileError, read_target_log

pytestmark = pytest.mark.timeout(120)


def scope_log(fs_hz: float, signals: list[tuple[str, np.ndarray, str]], n: int = 400) -> dict:
    """A Scope's Structure-with-time log: time N x 1, signals 1 x k with values (N x 1 or
    N x k), dimensions, label, title and plotStyle; blockName on the log only.
    """
    t = np.arange(n) / fs_hz
    array = np.zeros(
        (1, len(signals)),
        dtype=[
            ("values", object),
            ("dimensions", object),
            ("label", object),
            ("title", object),
            ("plotStyle", object),
        ],
    )
    for k, (label, values, title) in enumerate(signals):
        values = values.reshape(n, -1)
        array[0, k] = (
            values,
            np.array([[float(values.shape[1])]]),
            label,
            title,
            np.zeros((1, values.shape[1])),
        )
    return {"time": t.reshape(-1, 1), "signals": array, "blockName": "bench/Scope"}


def wave(n: int = 400, k: float = 1.0) -> np.ndarray:
    return np.sin(np.arange(n) * 0.01 * k) * k


FOUR = [(label, wave(k=k + 1), "") for k, label in enumerate(("amp_in", "pvdf_act", "cam_trig"))]


def write(path: Path, version: str, variables: dict, objects: dict | None = None) -> Path:
    if version == "v7.3":
        return lw.write_v73_with_object(path, variables, objects or {})
    return lw.write_v5_with_object(path, variables, objects or {}, compress=version == "v5")


VERSIONS = ["v5", "v5-uncompressed", "v7.3"]


@pytest.mark.filterwarnings("ignore:Duplicate variable name")  # scipy's, reading every object
@pytest.mark.parametrize("version", VERSIONS)
def test_a_matlab_object_beside_the_log_does_not_matter(tmp_path: Path, version: str) -> None:
    import scipy.io

    log = scope_log(20000.0, FOUR)
    objects = {"tg": "slrealtime.Target", "out": "Simulink.SimulationOutput"}
    path = write(tmp_path / "bench.mat", version, {"rt_log": log, "gain": 2.0}, objects)
    if version != "v7.3":  # what scipy's listing makes of MATLAB's object (the old refusal)
        with pytest.raises(TypeError, match="'NoneType' object is not iterable"):
            scipy.io.whosmat(str(path))
        assert type(scipy.io.loadmat(str(path))["None"]).__name__ == "MatlabOpaque"
    got = read_target_log(path, ["pvdf_act", "amp_in"])
    assert got.variable == "rt_log" and got.labels == ("amp_in", "pvdf_act", "cam_trig")
    np.testing.assert_array_equal(got.signals["pvdf_act"], wave(k=2.0))
    assert got.sample_rate_hz == pytest.approx(20000.0)


@pytest.mark.slow  # imports lab logs through the command
@pytest.mark.parametrize("version", VERSIONS)
def test_two_scopes_need_log_variable_and_it_picks_one(tmp_path: Path, version: str) -> None:
    first = scope_log(20000.0, FOUR)
    second = scope_log(1000.0, [("amp_in", wave(k=5.0), ""), ("pvdf_act", wave(k=6.0), "")])
    path = write(
        tmp_path / "two.mat", version, {"ScopeData1": first, "ScopeData2": second, "k": 1.0}
    )
    with pytest.raises(
        LabFileError,
        match=r"two.mat: 2 variables in Structure-with-time form \('ScopeData1', 'ScopeData2'\): "
        r"name the log in the rig file \(log_variable\)",
    ):
        read_target_log(path, ["amp_in"])
    got = read_target_log(path, ["pvdf_act"], variable="ScopeData2")
    assert got.variable == "ScopeData2" and got.sample_rate_hz == pytest.approx(1000.0)
    np.testing.assert_array_equal(got.signals["pvdf_act"], wave(k=6.0))
    with pytest.raises(LabFileError, match=r"two.mat: no variable 'Scope3' \(log_variable\); "):
        read_target_log(path, ["amp_in"], variable="Scope3")
    with pytest.raises(LabFileError, match=r"variable 'k' \(log_variable\) is not in Structure"):
        read_target_log(path, ["amp_in"], variable="k")


@pytest.mark.slow  # imports lab logs through the command
@pytest.mark.parametrize("version", VERSIONS)
def test_a_scope_with_several_inputs_gives_columns_by_label_j(tmp_path: Path, version) -> None:
    pvdf = np.column_stack([wave(k=1.0), wave(k=2.0), wave(k=3.0)])  # N x 3
    log = scope_log(20000.0, [("amp_in", wave(k=4.0), ""), ("pvdf", pvdf, "")])
    path = write(tmp_path / "nk.mat", version, {"rt_log": log})
    got = read_target_log(path, ["pvdf[2]", "pvdf[3]", "amp_in[1]"])
    np.testing.assert_array_equal(got.signals["pvdf[2]"], wave(k=2.0))
    np.testing.assert_array_equal(got.signals["pvdf[3]"], wave(k=3.0))
    np.testing.assert_array_equal(got.signals["amp_in[1]"], wave(k=4.0))
    with pytest.raises(
        LabFileError,
        match=r"nk.mat: variable 'rt_log': signal 'pvdf' has 3 columns \(a Scope with several "
        r"inputs\): name one as 'pvdf\[j\]', j from 1 to 3",
    ):
        read_target_log(path, ["pvdf"])
    with pytest.raises(LabFileError, match=r"'pvdf\[4\]': signal 'pvdf' has 3 column\(s\)"):
        read_target_log(path, ["pvdf[4]"])


@pytest.mark.parametrize("version", VERSIONS)
def test_a_label_two_signals_share_is_refused_naming_both(tmp_path: Path, version) -> None:
    signals = [
        ("amp_in", wave(k=1.0), "Drive"),
        ("pvdf", wave(k=2.0), "Actuator film"),
        ("cam_trig", wave(k=3.0), ""),
        ("pvdf", wave(k=4.0), "Hinge film"),
    ]
    path = write(tmp_path / "dup.mat", version, {"rt_log": scope_log(20000.0, signals)})
    with pytest.raises(
        LabFileError,
        match=r"dup.mat: variable 'rt_log': 2 signals are labelled 'pvdf': signals 2, 4 "
        r"\(title 'Actuator film', title 'Hinge film'\)",
    ) as refused:
        read_target_log(path, ["amp_in", "pvdf"])
    assert "\n" not in str(refused.value)
    # the other labels still import, the last one no longer wins silently
    got = read_target_log(path, ["amp_in", "cam_trig"])
    np.testing.assert_array_equal(got.signals["cam_trig"], wave(k=3.0))


def test_a_label_list_in_a_refusal_shows_at_most_ten(tmp_path: Path) -> None:
    signals = [(f"s{k:02d}", wave(k=1.0), "") for k in range(14)]
    path = write(tmp_path / "many.mat", "v5", {"rt_log": scope_log(20000.0, signals)})
    with pytest.raises(LabFileError) as refused:
        read_target_log(path, ["pvdf_act"])
    assert "'s00', 's01'" in str(refused.value) and "'s09', ... (14 in all)" in str(refused.value)
    assert "'s10'" not in str(refused.value)


@pytest.mark.parametrize("fs_hz", [50.0, 1000.0, 20000.0])
@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_any_logging_rate_reads(tmp_path: Path, fs_hz: float, version: str) -> None:
    path = write(tmp_path / "rate.mat", version, {"rt_log": scope_log(fs_hz, FOUR)})
    got = read_target_log(path, ["amp_in"])
    assert got.sample_rate_hz == pytest.approx(fs_hz, rel=1e-9)
    assert got.time_s[-1] == pytest.approx(399 / fs_hz)


def test_only_the_signals_asked_for_are_kept_while_reading(tmp_path: Path) -> None:
    from flaair_tools.bagio import mat_v5

    signals = [(f"unused_{k}", wave(k=1.0), "") for k in range(6)] + FOUR
    path = write(tmp_path / "wide.mat", "v5", {"rt_log": scope_log(20000.0, signals)})
    seen: list[str] = []

    def drop(fields: dict) -> dict:
        if "label" in fields:
            seen.append(fields["label"])
            if fields["label"] != "pvdf_act":
                fields["values"] = None
        return fields

    with open(path, "rb") as handle:
        variable = next(v for v in mat_v5.list_variables(handle) if v.name == "rt_log")
        log = mat_v5.read_variable(handle, variable, drop)
    # each element went through the hook as it was read: only one signal's values remain
    assert len(seen) == 9 and seen[-3] == "amp_in"
    kept = [s["label"] for s in log[0]["signals"] if s["values"] is not None]
    assert kept == ["pvdf_act"]


@pytest.fixture(scope="module")
def object_file_bytes(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("mat") / "saved.mat"
    variables = {"rt_log": scope_log(20000.0, FOUR), "gain": 2.0}
    return write(path, "v5", variables, {"tg": "slrealtime.Target"}).read_bytes()


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    cut=st.floats(0.0, 0.999),
    flips=st.lists(st.tuples(st.floats(0.0, 0.999), st.integers(0, 255)), max_size=8),
)
def test_a_damaged_save_with_an_object_gives_a_lab_file_error_or_the_log(
    tmp_path_factory, object_file_bytes, cut, flips
) -> None:
    data = bytearray(object_file_bytes)
    for where, byte in flips:
        data[int(where * len(data))] = byte
    data = data[: max(1, int(len(data) * (1 - cut)))] if cut > 0.001 else data
    path = tmp_path_factory.mktemp("damaged") / "damaged.mat"
    path.write_bytes(bytes(data))
    try:
        got = read_target_log(path, ["amp_in"])
    except LabFileError as exc:
        assert "damaged.mat" in str(exc) and "\n" not in str(exc)
    else:
        assert got.signals["amp_in"].size == got.time_s.size
