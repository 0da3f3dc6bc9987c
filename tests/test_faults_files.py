"""Fault suite, issue 38: every file opened through one checked reader.

YAML alias bombs, /dev/zero and FIFOs, 401-digit integers, a rig key written twice, NaN in a MAT
log, MAT files that expand hugely, an outlier in a track. The unbounded cases run in a child
with its address space limited (`bounded`), so the code before the fix fails them without
taking the machine's memory. Each test fails on the code before the fix.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml

import lab_files as lf
from rosproc import REPO_ROOT, isolated_env

pytestmark = pytest.mark.timeout(180)

AS_LIMIT_BYTES = 3 << 30  # numba and numpy reserve address space; far below the bombs' 3-6 GB
BOUNDED_TIMEOUT_S = 60.0


def bounded(code: str, timeout_s: float = BOUNDED_TIMEOUT_S) -> dict:
    """Run `code` in a child limited to AS_LIMIT_BYTES and `timeout_s`; its last stdout line
    as JSON (the child prints one), with its peak memory in `peak_kib`.

    The peak is the child's own (VmHWM of its address space since exec), not `ru_maxrss`,
    which Linux carries across fork and exec: a child of a big pytest worker would report the
    worker's size.
    """
    prelude = textwrap.dedent(
        f"""
        import json, resource, sys
        resource.setrlimit(resource.RLIMIT_AS, ({AS_LIMIT_BYTES}, {AS_LIMIT_BYTES}))
        def report(**values):
            with open("/proc/self/status") as status:
                hwm = [line for line in status if line.startswith("VmHWM:")]
            values["peak_kib"] = int(hwm[0].split()[1])
            print(json.dumps(values))
        """
    )
    try:
        done = subprocess.run(
            [sys.executable, "-c", prelude + textwrap.dedent(code)],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=isolated_env(),
            cwd=REPO_ROOT,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running after {timeout_s:g} s")
    lines = done.stdout.strip().splitlines()
    assert done.returncode == 0 and lines, done.stderr[-2000:]
    return json.loads(lines[-1])


def test_bounded_reads_the_childs_own_peak_not_the_parents() -> None:
    """The bombs' 1 GiB bound is on the child: a worker past it must not fail them, and an
    allocation in the child must show.
    """
    ballast = np.ones(160 << 20 >> 3)  # 160 MiB touched in this process
    idle = bounded("report()")
    grown = bounded("block = b'x' * (300 << 20)\nreport()")
    assert ballast.sum() > 0
    assert idle["peak_kib"] < 100 << 10, idle  # a bare interpreter: tens of MiB
    assert grown["peak_kib"] > idle["peak_kib"] + (290 << 10), (idle, grown)


def _refusal(call: str) -> str:
    """Child code: run `call`, report the exception's type and message (one line expected)."""
    return (
        f"try:\n    {call}\n"
        "except Exception as exc:\n    report(error=type(exc).__name__, message=str(exc))\n"
        "else:\n    report(error=None, message='')\n"
    )


def alias_bomb(levels: int = 9) -> str:
    """The billion-laughs document: 9**levels leaves from ~2.8 KB."""
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for k in range(1, levels + 1):
        lines.append(f"a{k}: &a{k} [" + ",".join([f"*a{k - 1}"] * 9) + "]")
    return "\n".join(lines) + f"\nplant: *a{levels}\n"


LOADERS = {
    "model": ("from flaair_model.model_io import load_model", "load_model({path!r})", "Model"),
    "rig": ("from flaair_tools.bagio.rig import read_rig", "read_rig({path!r})", "LabFile"),
    "manifest": (
        "from flaair_tools.bagio.lab_import import read_manifest",
        "read_manifest({path!r})",
        "LabFile",
    ),
    "calibration": (
        "from flaair_tools.analysis.analyze import load_calibration",
        "load_calibration(__import__('pathlib').Path({path!r}))",
        "Analysis",
    ),
}


def _load_in_child(kind: str, path: Path) -> dict:
    imports, call, _ = LOADERS[kind]
    return bounded(imports + "\n" + _refusal(call.format(path=str(path))))


@pytest.mark.slow  # each command in a new process on the bomb
@pytest.mark.parametrize("kind", sorted(LOADERS))
def test_a_yaml_alias_bomb_is_refused_at_once(kind, tmp_path) -> None:
    path = tmp_path / f"{kind}.yaml"
    path.write_text(alias_bomb())
    assert path.stat().st_size < 3000
    result = _load_in_child(kind, path)
    assert result["error"] and result["error"].startswith(LOADERS[kind][2]), result
    assert "aliases expand past" in result["message"], result
    assert len(result["message"].replace(str(path), "")) < 150, result
    assert "\n" not in result["message"]
    assert result["peak_kib"] < 1 << 20, result  # under 1 GiB (the bomb took 3-6 GB)


@pytest.mark.parametrize(
    ("kind", "special"),
    # a directory as a rig, manifest or calibration was already refused in one line
    [(k, s) for k in sorted(LOADERS) for s in ("/dev/zero", "fifo")] + [("model", "directory")],
)
@pytest.mark.slow  # each command in a new process on a FIFO and a device
def test_a_special_file_is_refused_without_reading_it(kind, special, tmp_path) -> None:
    if special == "fifo":
        path = tmp_path / "fifo.yaml"
        os.mkfifo(path)  # nobody writes it: opening it for reading would block for ever
    else:
        path = Path(special) if special == "/dev/zero" else tmp_path
    result = _load_in_child(kind, path)
    assert result["error"] and result["error"].startswith(LOADERS[kind][2]), result
    assert "regular file" in result["message"] or "directory" in result["message"], result


READERS = {
    "mat": (
        "from flaair_tools.bagio.target_log import read_target_log",
        "read_target_log({p!r}, [])",
    ),
    "track": (
        "from flaair_tools.bagio.dlt_tracks import read_xy_point",
        "read_xy_point({p!r}, 1, 1, 't')",
    ),
    "csv": ("from flaair_common.runcsv import read_run", "read_run({p!r})"),
}


@pytest.mark.parametrize(
    ("kind", "special"),
    # a CSV may come from a pipe, `<(unzip -p runs.zip run.csv)` (test_runcsv)
    [(k, s) for k in sorted(READERS) for s in ("/dev/zero", "fifo") if (k, s) != ("csv", "fifo")],
)
def test_a_special_file_as_a_mat_log_track_or_csv_is_refused(kind, special, tmp_path) -> None:
    path = tmp_path / "fifo"
    if special == "fifo":
        os.mkfifo(path)
    else:
        path = Path(special)
    imports, call = READERS[kind]
    result = bounded(imports + "\n" + _refusal(call.format(p=str(path))))
    assert result["error"] in ("LabFileError", "RunFileError"), result
    assert "regular file" in result["message"], result


HUGE = "1" + "0" * 400


@pytest.mark.slow  # each command in a new process on the file
@pytest.mark.parametrize("kind", sorted(LOADERS))
def test_a_401_digit_integer_is_refused_by_name(kind, tmp_path) -> None:
    if kind == "model":
        text = (Path(REPO_ROOT) / "config/model.yaml").read_text()
        document = yaml.safe_load(text)
        section = document["plant"]
        key = next(iter(section))
        section[key] = int(HUGE)
        name = f"plant.{key}"
    elif kind == "rig":
        document, name = lf.rig_mapping(), "drive_gain_v_per_v"
        document[name] = int(HUGE)
    elif kind == "manifest":
        document, name = {"runs": [{"mat": "a.mat", "tracks": "t.csv", "n": int(HUGE)}]}, "runs"
    else:
        document, name = {"stroke": {"gain_deg_per_v": int(HUGE)}}, "stroke.gain_deg_per_v"
    path = tmp_path / f"{kind}.yaml"
    path.write_text(yaml.safe_dump(document))
    result = _load_in_child(kind, path)
    assert result["error"] and result["error"].startswith(LOADERS[kind][2]), result
    assert "401 digits" in result["message"] and name in result["message"], result
    assert len(result["message"]) < 300, result


def test_a_rig_key_written_twice_is_refused(tmp_path) -> None:
    from flaair_tools.bagio.rig import read_rig
    from flaair_tools.bagio.target_log import LabFileError

    text = yaml.safe_dump(lf.rig_mapping(), sort_keys=False)
    assert "drive_gain_v_per_v: 100" in text
    path = tmp_path / "rig.yaml"
    path.write_text(text + "drive_gain_v_per_v: 1\n")
    with pytest.raises(LabFileError, match="key drive_gain_v_per_v written twice"):
        read_rig(path)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> dict[str, lf.LabSession]:
    root = tmp_path_factory.mktemp("lab")
    chirp = lf.chirp_run(duration_s=0.3)
    return {
        version: lf.write_lab_run(root, f"run_{version.replace('.', '')}", chirp, version)
        for version in ("v5", "v7.3")
    }


@pytest.mark.parametrize("version", ["v5", "v7.3"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_mat_log_with_nan_or_inf_is_refused(version, bad, tmp_path) -> None:
    from flaair_tools.bagio.target_log import LabFileError, read_target_log

    n = 400
    stroke = np.zeros(n)
    stroke[123] = bad
    log = lf.structure_with_time(np.arange(n) / 20000.0, {"pvdf_act": stroke})
    path = lf.write_mat(tmp_path / "log.mat", log, version)
    with pytest.raises(LabFileError, match=r"signal 'pvdf_act' value 123 is not finite"):
        read_target_log(path, ["pvdf_act"])


@pytest.mark.parametrize("field", ["char", "struct"])
def test_char_or_struct_mat_fields_are_one_line_errors(field, tmp_path) -> None:
    from flaair_tools.bagio.target_log import LabFileError, read_target_log

    log = lf.structure_with_time(np.arange(10) / 20000.0, {"pvdf_act": np.zeros(10)})
    if field == "char":
        log["signals"][0, 0] = ("abcdefghij", "pvdf_act", "bench/pvdf_act")
    else:
        log["time"] = {"a": np.zeros(3)}
    path = lf.write_mat(tmp_path / "log.mat", log, "v5")
    with pytest.raises(LabFileError, match=r"'rt_log' is not in Structure-with-time form"):
        read_target_log(path, ["pvdf_act"])


def _v5_struct_bomb(path: Path, expanded_bytes: int) -> None:
    """A MAT v5 file whose one compressed struct (`rt_log` with a `time` of zeros) expands to
    about `expanded_bytes`, written without ever holding them.
    """

    def element(kind: int, data: bytes) -> bytes:
        return np.array([kind, len(data)], "<u4").tobytes() + data + b"\0" * (-len(data) % 8)

    n = expanded_bytes // 8
    name = b"time".ljust(32, b"\0") + b"signals".ljust(32, b"\0")
    double = (
        element(6, np.array([6, 0], "<u4").tobytes())
        + element(5, np.array([n, 1], "<i4").tobytes())
        + element(1, b"")
    )
    double_header = np.array([9, 8 * n], "<u4").tobytes()
    empty = (
        element(6, np.array([6, 0], "<u4").tobytes())
        + element(5, np.array([0, 0], "<i4").tobytes())
        + element(1, b"")
    )
    struct_head = (
        element(6, np.array([2, 0], "<u4").tobytes())
        + element(5, np.array([1, 1], "<i4").tobytes())
        + element(1, b"rt_log")
        + np.array([(4 << 16) | 5, 32], "<u4").tobytes()
        + element(1, name)
    )
    time_field_bytes = len(double) + 8 + 8 * n
    signals_field = element(14, empty)
    matrix_bytes = len(struct_head) + 8 + time_field_bytes + len(signals_field)
    pack = zlib.compressobj(9)
    parts = [
        pack.compress(np.array([14, matrix_bytes], "<u4").tobytes() + struct_head),
        pack.compress(np.array([14, time_field_bytes], "<u4").tobytes() + double + double_header),
    ]
    zeros, left = bytes(1 << 22), 8 * n
    while left:
        chunk = zeros[: min(left, len(zeros))]
        parts.append(pack.compress(chunk))
        left -= len(chunk)
    parts += [pack.compress(signals_field), pack.flush()]
    compressed = b"".join(parts)
    header = b"MATLAB 5.0 MAT-file, bomb".ljust(116, b" ") + bytes(8) + b"\x00\x01IM"
    path.write_bytes(header + np.array([15, len(compressed)], "<u4").tobytes() + compressed)


# slow: builds a compressed MAT file declaring gigabytes, then runs the importer on it in a new
# process
@pytest.mark.slow
def test_a_compressed_mat_bomb_is_refused_before_it_expands(tmp_path) -> None:
    path = tmp_path / "bomb.mat"
    _v5_struct_bomb(path, 2 << 30)
    assert path.stat().st_size < 4 << 20
    result = bounded(
        _refusal(
            "__import__('flaair_tools.bagio.target_log').bagio.target_log"
            f".read_target_log({str(path)!r}, ['x'])"
        )
    )
    assert result["error"] == "LabFileError" and "expands past" in result["message"], result
    assert result["peak_kib"] < 1 << 20, result


@pytest.mark.slow  # each command in a new process on the file
def test_a_v73_dataset_declaring_gigabytes_is_refused(session, tmp_path) -> None:
    import h5py

    path = tmp_path / "bomb.mat"
    path.write_bytes(session["v7.3"].mat.read_bytes())
    with h5py.File(path, "r+") as f:
        del f["rt_log"]["time"]
        f["rt_log"].create_dataset(
            "time", shape=(1, 300_000_000), dtype="f8", chunks=(1, 1 << 20), compression="gzip"
        )
    result = bounded(
        _refusal(
            "__import__('flaair_tools.bagio.target_log').bagio.target_log"
            f".read_target_log({str(path)!r}, ['pvdf_act'])"
        )
    )
    assert result["error"] == "LabFileError" and "expands past" in result["message"], result


def test_an_outlier_in_a_tip_track_is_dropped_and_counted(session, tmp_path) -> None:
    from flaair_tools.bagio.lab_import import LabRunFiles, read_lab_run

    s = session["v5"]
    rig = tmp_path / "tip_rig.yaml"
    rig.write_text(yaml.safe_dump(lf.rig_mapping(stroke_from="actuator_tip")))
    lines = s.tip_track.read_text().splitlines()
    row = next(k for k in range(200, len(lines)) if "NaN,NaN,NaN" not in lines[k][8:])
    cells = lines[row].split(",")
    cells[2] = "1e308"
    lines[row] = ",".join(cells)
    tip = tmp_path / "tip_xypts.csv"
    tip.write_text("\n".join(lines) + "\n")
    clean = read_lab_run(LabRunFiles(s.mat, rig, s.tracks, s.tip_track), 0.002)
    spoilt = read_lab_run(LabRunFiles(s.mat, rig, s.tracks, tip), 0.002)
    assert spoilt.extras["video"]["outliers_dropped"] == 1
    assert any("1 outlying frame(s) dropped" in w for w in spoilt.warnings)
    stroke = spoilt.run["stroke_deg"]
    assert np.nanmax(np.abs(stroke)) < 90.0
    both = np.isfinite(stroke) & np.isfinite(clean.run["stroke_deg"])
    # the tip's rest position is its mean over one frame fewer
    np.testing.assert_allclose(stroke[both], clean.run["stroke_deg"][both], atol=0.01)


def test_a_launch_file_that_includes_itself_is_one_error(tmp_path) -> None:
    from flaair_tools.orchestration.launch_file import LaunchFileError, load

    own = tmp_path / "own.launch.xml"
    own.write_text('<launch><include file="own.launch.xml"/></launch>')
    with pytest.raises(LaunchFileError, match="which includes it back"):
        load(own)
    first, second = tmp_path / "a.launch.xml", tmp_path / "b.launch.xml"
    first.write_text('<launch><include file="b.launch.xml"/></launch>')
    second.write_text('<launch><include file="$(dirname)/a.launch.xml"/></launch>')
    with pytest.raises(LaunchFileError, match="which includes it back"):
        load(first)


@pytest.mark.parametrize("special", ["directory", "fifo", "/dev/zero"])
def test_a_directory_or_device_as_a_launch_file_is_one_error(special, tmp_path) -> None:
    path = tmp_path
    if special == "fifo":
        path = tmp_path / "fifo.launch.xml"
        os.mkfifo(path)
    elif special == "/dev/zero":
        path = Path(special)
    imports = "from flaair_tools.orchestration.launch_file import load"
    result = bounded(imports + "\n" + _refusal(f"load({str(path)!r})"), timeout_s=30.0)
    assert result["error"] == "LaunchFileError", result
    assert "directory" in result["message"] or "regular file" in result["message"], result


@pytest.mark.parametrize("source", ["csv", "mat"])
def test_an_implausible_signal_is_refused_on_every_import_path(source, tmp_path) -> None:
    from flaair_common.runcsv import write_run
    from rosproc import FLAAIR, run_offline

    run = lf.chirp_run(duration_s=0.3)
    run["pitch_sensor_v"] = run["pitch_sensor_v"].copy()
    run["pitch_sensor_v"][100] = 5000.0  # a log in millivolts read as volts, one sample
    if source == "csv":
        path = tmp_path / "run.csv"
        n = run["drive_v"].size
        write_run(
            path,
            {
                "time_s": np.arange(n) / lf.FS_HZ,
                **{k: run[k] for k in ("drive_v", "stroke_sensor_v", "pitch_sensor_v")},
                "stroke_deg": np.degrees(run["stroke_rad"]),
                "pitch_deg": np.degrees(run["pitch_rad"]),
            },
        )
        args = [str(path)]
    else:
        s = lf.write_lab_run(tmp_path, "run", run, "v5")
        args = [str(s.mat), "--rig", str(s.rig), "--tracks", str(s.tracks)]
    bag = tmp_path / "bag"
    result = run_offline([FLAAIR, "import", *args, "--out", str(bag)], isolated_env(), 120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr[-2000:]
    assert len(lines) == 1 and "pitch_sensor_v[100] = 5000 is beyond" in lines[0], lines
    assert not bag.exists()
