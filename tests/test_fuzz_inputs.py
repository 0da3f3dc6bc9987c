"""Fuzz, issue 38: every input kind a command reads, damaged at random, ends in exit 0 or 2 with
one line, no traceback, and no partial output.

One hypothesis test per kind (model, rig, manifest, MAT, track, CSV, launch, validation). Each
starts from a valid file and replaces a value (YAML), flips or cuts bytes (MAT, tracks, CSV) or
swaps attributes and elements (launch), mixed with the hostile inputs of issue 38 (alias bombs,
401-digit integers, keys written twice, deep nesting). The commands run in this process
(`run_offline`), on inputs of a few kilobytes; example counts and deadlines keep the whole
module near a minute.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lab_files as lf
from rosproc import FLAAIR, REPO_ROOT, run_offline

pytestmark = pytest.mark.timeout(120)

FUZZ = settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
FS_HZ = 20000.0
HUGE = int("9" * 401)
# offline commands join no ROS domain: no lease per example (isolated_env holds one per test)
ENV = dict(os.environ)


def _bomb(levels: int = 9) -> str:
    lines = ['a0: &a0 ["x","x","x","x","x","x","x","x","x"]']
    lines += [f"a{k}: &a{k} [" + ",".join([f"*a{k - 1}"] * 9) + "]" for k in range(1, levels + 1)]
    return "\n".join(lines) + "\n"


HOSTILE_TEXTS = [
    _bomb(),
    "[" * 5000 + "]" * 5000,
    "a: 1\na: 2\n",
    f"plant: {HUGE}\n",
    "&a [*a]\n",
    "\x00\xff\xfe",
    "",
]

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**40), 10**40),
    st.sampled_from([HUGE, -HUGE, 0, -1]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
)
values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=6,
)


def _mutated(data: st.DataObject, document: object) -> object:
    """`document` with one value somewhere inside replaced, deleted or added."""
    if not isinstance(document, (dict, list)) or not document or data.draw(st.integers(0, 3)) == 0:
        return data.draw(values)
    if isinstance(document, dict):
        key = data.draw(st.sampled_from(sorted(document, key=str)))
        out = dict(document)
        action = data.draw(st.sampled_from(["replace", "delete", "add"]))
        if action == "delete":
            del out[key]
        elif action == "add":
            out[data.draw(st.text(max_size=8))] = data.draw(values)
        else:
            out[key] = _mutated(data, document[key])
        return out
    index = data.draw(st.integers(0, len(document) - 1))
    out_list = list(document)
    out_list[index] = _mutated(data, document[index])
    return out_list


def _yaml_text(data: st.DataObject, document: object) -> str:
    if data.draw(st.integers(0, 4)) == 0:
        return data.draw(st.sampled_from(HOSTILE_TEXTS))
    try:
        return yaml.safe_dump(_mutated(data, document), allow_unicode=True)
    except (yaml.YAMLError, ValueError):
        return "not: [valid"


def _damaged(data: st.DataObject, raw: bytes) -> bytes:
    """`raw` with a few bytes overwritten and maybe cut short."""
    out = bytearray(raw)
    for _ in range(data.draw(st.integers(0, 6))):
        out[data.draw(st.integers(0, len(out) - 1))] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        out = out[: data.draw(st.integers(1, len(out)))]
    return bytes(out)


def _check(result, *outputs: Path, codes=(0, 2)) -> None:
    """Exit 0 or 2, no traceback; a refusal is one line and leaves none of `outputs`."""
    stderr = result.stderr
    assert result.returncode in codes, stderr[-3000:]
    assert "Traceback" not in stderr, stderr[-3000:]
    if result.returncode != 0:
        errors = [line for line in stderr.strip().splitlines() if "warning" not in line]
        assert len(errors) == 1, stderr[-3000:]
        assert len(errors[0]) < 600, errors[0]
        for path in outputs:
            assert not path.exists(), path


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def csv_run(workdir) -> Path:
    from flaair_common.runcsv import write_run

    run = lf.chirp_run(duration_s=0.05)
    n = run["drive_v"].size
    path = workdir / "run.csv"
    write_run(
        path,
        {
            "time_s": np.arange(n) / FS_HZ,
            **{k: run[k] for k in ("drive_v", "stroke_sensor_v", "pitch_sensor_v")},
            "stroke_deg": np.degrees(run["stroke_rad"]),
            "pitch_deg": np.degrees(run["pitch_rad"]),
        },
    )
    return path


@pytest.fixture(scope="module")
def session(workdir) -> lf.LabSession:
    return lf.write_lab_run(workdir, "lab", lf.chirp_run(duration_s=0.2), "v5")


def _fresh(workdir: Path, name: str) -> Path:
    path = workdir / name
    if path.is_dir():
        import shutil

        shutil.rmtree(path)
    elif path.exists():
        path.unlink()
    return path


@FUZZ
@given(data=st.data())
def test_fuzz_model(data, workdir, csv_run) -> None:
    document = yaml.safe_load((Path(REPO_ROOT) / "config/model.yaml").read_text())
    model = workdir / "model.yaml"
    model.write_text(_yaml_text(data, document), encoding="utf-8", errors="surrogateescape")
    out = _fresh(workdir, "sim.csv")
    args = [FLAAIR, "simulate", str(csv_run), "--model", str(model), "--out", str(out)]
    _check(run_offline(args, ENV), out)


@FUZZ
@given(data=st.data())
def test_fuzz_rig(data, workdir, session) -> None:
    rig = workdir / "rig.yaml"
    rig.write_text(_yaml_text(data, lf.rig_mapping()), encoding="utf-8", errors="surrogateescape")
    bag = _fresh(workdir, "bag_rig")
    args = [str(session.mat), "--rig", str(rig), "--tracks", str(session.tracks)]
    args += ["--tip-track", str(session.tip_track)]
    _check(run_offline([FLAAIR, "import", *args, "--out", str(bag)], ENV), bag)


@FUZZ
@given(data=st.data())
def test_fuzz_manifest(data, workdir, session) -> None:
    document = {
        "rig": session.rig.name,
        "runs": [{"mat": session.mat.name, "tracks": session.tracks.name}],
    }
    manifest = workdir / "manifest.yaml"
    manifest.write_text(_yaml_text(data, document), encoding="utf-8", errors="surrogateescape")
    bag = _fresh(workdir, "bag_manifest")
    args = [FLAAIR, "import", "--manifest", str(manifest), "--out", str(bag)]
    _check(run_offline(args, ENV), bag)


@FUZZ
@given(data=st.data())
def test_fuzz_mat(data, workdir, session) -> None:
    mat = workdir / "damaged.mat"
    mat.write_bytes(_damaged(data, session.mat.read_bytes()))
    bag = _fresh(workdir, "bag_mat")
    args = [str(mat), "--rig", str(session.rig), "--tracks", str(session.tracks)]
    _check(run_offline([FLAAIR, "import", *args, "--out", str(bag)], ENV), bag)


@FUZZ
@given(data=st.data())
def test_fuzz_track(data, workdir, session) -> None:
    tracks = workdir / "damaged_xyzpts.csv"
    raw = session.tracks.read_bytes()
    damaged = _damaged(data, raw)
    lines = damaged.split(b"\n")
    if len(lines) > 1 and data.draw(st.booleans()):  # a wild value, as a digitizing slip
        k = data.draw(st.integers(1, max(1, len(lines) - 1)))
        lines[k] = b",".join([b"1e308", *lines[k].split(b",")[1:]])
        damaged = b"\n".join(lines)
    tracks.write_bytes(damaged)
    bag = _fresh(workdir, "bag_track")
    args = [str(session.mat), "--rig", str(session.rig), "--tracks", str(tracks)]
    _check(run_offline([FLAAIR, "import", *args, "--out", str(bag)], ENV), bag)


@FUZZ
@given(data=st.data())
def test_fuzz_csv(data, workdir, csv_run) -> None:
    csv = workdir / "damaged.csv"
    raw = csv_run.read_bytes()
    if data.draw(st.booleans()):
        lines = raw.split(b"\n")
        k = data.draw(st.integers(1, len(lines) - 2))
        cells = lines[k].split(b",")
        cells[data.draw(st.integers(0, len(cells) - 1))] = data.draw(
            st.sampled_from([b"nan", b"inf", b"1e308", b"-0", b"", b"9" * 401, b"0x10"])
        )
        raw = b"\n".join([*lines[:k], b",".join(cells), *lines[k + 1 :]])
    csv.write_bytes(_damaged(data, raw) if data.draw(st.booleans()) else raw)
    bag = _fresh(workdir, "bag_csv")
    _check(run_offline([FLAAIR, "import", str(csv), "--out", str(bag)], ENV), bag)


LAUNCH = """<launch>
  <arg name="ns" default="a"/>
  <let name="rate" value="20000"/>
  <group>
    <push-ros-namespace namespace="$(var ns)"/>
    <node pkg="flaair_sim" exec="plant_node" name="plant">
      <param name="sample_rate_hz" value="$(var rate)"/>
      <remap from="x" to="y"/>
    </node>
  </group>
  <include file="{include}"/>
</launch>
"""
LAUNCH_WORDS = [
    "node", "group", "include", "arg", "let", "param", "remap", "push-ros-namespace",
    "$(var nope)", "$(env HOME)", "$(dirname)", "$(find-pkg-share nope)", "if", "unless",
    "true", "", "&amp;", "<!DOCTYPE x [<!ENTITY e \"e\">]>", "self.launch.xml", "/dev/zero",
]  # fmt: skip


@FUZZ
@given(data=st.data())
def test_fuzz_launch(data, workdir) -> None:
    from flaair_tools.orchestration import launch_cli

    included = workdir / "included.launch.xml"
    included.write_text("<launch/>")
    text = LAUNCH.format(
        include=data.draw(
            st.sampled_from(["included.launch.xml", "self.launch.xml", "/dev/zero", str(workdir)])
        )
    )
    for _ in range(data.draw(st.integers(0, 4))):
        word = data.draw(st.sampled_from(LAUNCH_WORDS))
        at = data.draw(st.integers(0, len(text)))
        text = text[:at] + word + text[at:]
    path = workdir / "self.launch.xml"
    path.write_text(text)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = launch_cli.main(["flaair_tools", str(path), "--print"])
        except SystemExit as exc:
            code = exc.code
    stderr = err.getvalue()
    assert code in (0, 2), stderr
    assert "Traceback" not in stderr
    if code:
        assert len(stderr.strip().splitlines()) == 1, stderr


@FUZZ
@given(data=st.data())
def test_fuzz_validation(data, workdir, csv_run, monkeypatch_module) -> None:
    from flaair_tools.discrepancy.report import write_validation

    good = {
        "confusion": {
            "columns": ["none", "sensor_delay"],
            "rows": ["none"],
            "counts": [[1, 0]],
            "correct": 1,
            "total": 1,
        },
        "cases": [
            {
                "case": "c",
                "true": "none",
                "found": "none",
                "status": "no_discrepancy",
                "correct": True,
                "parameter_errors": {"delay_s": 0.1},
                "gap_reduction": None,
                "problems": [],
                "elapsed_s": 1.5,
            }
        ],
        "total_s": 1.5,
    }
    import json

    document = _mutated(data, good) if data.draw(st.integers(0, 5)) else good
    try:
        text = json.dumps(document)
    except ValueError:
        text = "{"
    if data.draw(st.integers(0, 5)) == 0:
        text = data.draw(st.sampled_from(["[" * 100_000, "{" * 20 + "}" * 20, "NaN", "\xff"]))
    validation = workdir / "validation.json"
    validation.write_text(text, encoding="utf-8", errors="surrogateescape")
    out = _fresh(workdir, "disc")
    args = [FLAAIR, "discrepancy", str(csv_run), "--validation", str(validation)]
    result = run_offline([*args, "--out", str(out)], ENV)
    # accepted, the file reaches the analysis (stubbed: a Ctrl-C there), and renders
    _check(result, out, codes=(2, 130))
    if result.returncode == 130:
        accepted = json.loads(text)
        write_validation(
            _fresh(workdir, "render"), accepted.get("cases", []), accepted["confusion"], 0.0
        )


@pytest.fixture(scope="module")
def monkeypatch_module():
    """The discrepancy workflow stubbed by a Ctrl-C: the fuzz checks what comes before it."""
    from flaair_tools.discrepancy import cli

    patch = pytest.MonkeyPatch()

    def interrupted(*_args, **_kwargs):
        raise KeyboardInterrupt

    patch.setattr(cli, "analyse_evidence", interrupted)
    yield patch
    patch.undo()


def test_the_hostile_texts_are_what_issue_38_names() -> None:
    assert len(_bomb()) < 3000 and math.log10(HUGE) > 400
