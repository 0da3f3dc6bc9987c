"""The format guides' examples (docs/formats/): the shipped files read as their guides say, the
guides' quick commands run on them as written, and the files are what
scripts/make_format_examples.py writes.
"""

from __future__ import annotations

import json
import math
import shlex
from pathlib import Path

import numpy as np
import pytest

from flaair_common.runcsv import read_run
from rosproc import (
    FLAAIR,
    OFFLINE_COMMANDS,
    REPO_ROOT,
    import_script,
    isolated_env,
    run,
    run_offline,
)

FORMATS = REPO_ROOT / "docs" / "formats"
RUNS = [REPO_ROOT / "examples" / "runs" / f"run0{k}.csv" for k in (1, 2)]
TABLE = REPO_ROOT / "examples" / "sweep_table" / "robot_sweep.csv"


def try_it(doc: Path) -> list[list[str]]:
    """The commands of a guide's "Try it" code block(s), as written."""
    text = doc.read_text().split("Try it", 1)[1]
    commands = []
    for block in text.split("```bash\n")[1:]:
        body = block.split("```", 1)[0].replace("\\\n", " ")
        commands += [shlex.split(line) for line in body.splitlines() if line.strip()]
    return commands


@pytest.mark.timeout(60)
def test_the_example_runs_and_table_read_as_the_guides_say() -> None:
    for path, amplitude_v in zip(RUNS, (100.0, 50.0), strict=True):
        run = read_run(path)
        assert run.sample_rate_hz == pytest.approx(10000.0)
        assert len(run["time_s"]) == 3000
        assert np.max(np.abs(run["drive_v"])) == pytest.approx(amplitude_v, rel=1e-3)
        truth = run["stroke_deg"]
        assert np.all(np.isfinite(truth[::5])) and np.all(np.isnan(truth[1::5]))
        for film in ("stroke_sensor_v", "pitch_sensor_v"):  # at rest, a film reads V_HREF
            assert abs(np.mean(run[film][:5]) - 1.25) < 0.005
    from flaair_tools.tables.table_io import load_tables

    (table,) = load_tables([TABLE])
    assert table.n_points == 36
    assert sorted(set(table.drive_amplitude_v)) == [30.0, 60.0, 90.0]
    pitch = table.responses["pitch_pp_deg"]
    assert 0 < int(np.isnan(pitch).sum()) < 36  # some pitch cells not measured, as said
    assert not any(math.isnan(v) for v in table.responses["stroke_pp_deg"])
    # each guide shows the file's real first lines
    head = RUNS[0].read_text().split("\n")[:4]
    assert (
        "\n".join(f"    {line}" for line in head) in (FORMATS / "MEASURED_RUN_CSV.md").read_text()
    )
    assert "\n".join(TABLE.read_text().split("\n")[:8]) in (FORMATS / "SWEEP_TABLE.md").read_text()


@pytest.mark.timeout(30)
def test_every_guide_command_names_files_that_exist_and_writes_apart() -> None:
    commands = [
        c
        for doc in sorted(FORMATS.glob("*.md"))
        if "Try it" in doc.read_text()
        for c in try_it(doc)
    ]
    assert len(commands) >= 6
    for command in commands:
        assert command[0] == "bin/flaair", command
        inputs = [a for a in command if a.startswith("examples/")]
        assert all((REPO_ROOT / a).exists() for a in inputs), command
    outs = [c[c.index("--out") + 1] for c in commands if "--out" in c]
    assert len(set(outs)) == len(outs), outs


@pytest.mark.slow  # runs five commands (a bag, a simulation, two fits): about half a minute
@pytest.mark.timeout(600)
def test_the_quick_commands_of_the_csv_and_table_guides_run(tmp_path: Path) -> None:
    for doc in ("MEASURED_RUN_CSV.md", "SWEEP_TABLE.md"):
        for command in try_it(FORMATS / doc):
            args = [str(tmp_path / a) if a.startswith("out/") else a for a in command[1:]]
            runner = run_offline if args[0] in OFFLINE_COMMANDS else run
            result = runner([FLAAIR, *args], isolated_env(), 300)
            assert result.returncode == 0, (command, result.stderr[-2000:])
    assert (tmp_path / "out/bags/runs/metadata.yaml").is_file()
    assert read_run(tmp_path / "out/sim/run01.csv").sample_rate_hz == pytest.approx(10000.0)
    assert (tmp_path / "out/fit_runs/model.yaml").is_file()
    assert (tmp_path / "out/fit_table/identification.json").is_file()


@pytest.mark.slow  # simulates the two runs and 36 steady states: about half a minute
@pytest.mark.timeout(300)
def test_the_shipped_examples_are_what_the_script_writes(tmp_path: Path) -> None:
    make_format_examples = import_script("make_format_examples")
    assert make_format_examples.main(["--out", str(tmp_path)]) == 0
    for shipped in [*RUNS, TABLE]:
        fresh = tmp_path / shipped.parent.name / shipped.name
        if fresh.read_bytes() == shipped.read_bytes():
            continue
        # another CPU's last bits: the same numbers to the digits written
        a, b = (np.genfromtxt(p, delimiter=",", skip_header=1) for p in (fresh, shipped))
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6, err_msg=shipped.name)


@pytest.mark.slow  # the discrepancy workflow on two runs: about 10 s
@pytest.mark.timeout(300)
def test_discrepancy_md_example_finds_the_hinge_films_strain_transfer(tmp_path: Path) -> None:
    """docs/DISCREPANCY.md's example: the two example runs end `explained` with the bench
    robot's strain transfer (0.23) named, as the guide shows.
    """
    command = [FLAAIR, "discrepancy", *map(str, RUNS), "--out", str(tmp_path / "disc")]
    result = run_offline(command, isolated_env(), 300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "status explained" in result.stdout
    found = json.loads((tmp_path / "disc" / "discrepancy.json").read_text())
    assert found["status"] == "explained"
    assert [e["name"] for e in found["effects"]] == ["strain_transfer_loss"]
    assert found["effects"][0]["parameters"]["efficiency"] == pytest.approx(0.23, abs=0.005)
    assert not found["discovered"]
    assert "status explained" in (REPO_ROOT / "docs" / "DISCREPANCY.md").read_text()
