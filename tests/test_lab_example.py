"""docs/LAB_FILES.md's walk-through on the session the project ships (examples/lab_session): its
commands, parsed out of the document, run as written (outputs under a temporary `out/`), and the
shipped files are what scripts/make_lab_example.py writes.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import pytest

from rosproc import FLAAIR, REPO_ROOT, import_script, isolated_env, run_offline

DOC = REPO_ROOT / "docs" / "LAB_FILES.md"
EXAMPLE = REPO_ROOT / "examples" / "lab_session"
MARK = "<!-- walk-through:"


def walk_through() -> list[list[str]]:
    """The commands of the document's walk-through block (the ```sh block after MARK)."""
    text = DOC.read_text()
    assert text.count(MARK) == 1, "one walk-through block in docs/LAB_FILES.md"
    block = text.split(MARK, 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    return [shlex.split(line) for line in block.replace("\\\n", " ").splitlines() if line.strip()]


@pytest.mark.timeout(30)
def test_the_walk_through_names_files_that_exist_and_writes_apart() -> None:
    commands = walk_through()
    assert [c[:2] for c in commands] == [
        ["bin/flaair", name]
        for name in ("import", "import", "calibrate", "analyze", "identify", "discrepancy")
    ]
    inputs = [a for c in commands for a in c if a.startswith("examples/")]
    assert inputs and all((REPO_ROOT / a).is_file() for a in inputs), inputs
    outs = [c[c.index("--out") + 1] for c in commands]
    assert len(set(outs)) == len(outs)  # the two imports write to different bags


@pytest.mark.slow  # every command of docs/LAB_FILES.md's walk-through, as written
@pytest.mark.timeout(900)
def test_the_walk_through_runs_on_the_example_session(tmp_path: Path) -> None:
    stdout = []
    for command in walk_through():
        args = [str(tmp_path / a) if a.startswith("out/") else a for a in command[1:]]
        result = run_offline([FLAAIR, *args], isolated_env(), 600)
        assert result.returncode == 0, (command, result.stderr[-3000:])
        assert "warning" not in result.stderr.lower() or command[1] != "import", result.stderr
        stdout.append(result.stdout)
    # the import's summary as the document shows it
    assert (
        "run01: 10000 samples at 5000 Hz (first_sample_index 0) from "
        "examples/lab_session/run01.mat; video 2000 fps, 800 frames (99.0 % tracked), 800 "
        "placed, 0 outside the log; trigger at 0.800000 s; video vs stroke sensor +0.016 ms "
        "(correlation +0.999)"
    ) in stdout[0]
    assert stdout[1].count("video 2000 fps, 800 frames") == 2
    calibration = json.loads((tmp_path / "out/calibration/calibration.json").read_text())
    assert calibration["stroke"]["gain_deg_per_v"] == pytest.approx(25.4, abs=0.05)
    assert calibration["pitch"]["gain_deg_per_v"] == pytest.approx(108.0, abs=0.1)
    found = json.loads((tmp_path / "out/discrepancy/discrepancy.json").read_text())
    # the session's pitch chain keeps a gap beside it: fitted, listed as approximate, not named
    assert "strain_transfer_loss" not in [e["name"] for e in found["effects"]]
    evidence = [e["evidence"] for e in found["approximate"]]
    transfer = [
        value
        for e in evidence
        for name, value in zip(e["candidate"].split("+"), e["values"], strict=True)
        if name == "strain_transfer_loss[pitch]"
    ]
    assert transfer and transfer[0] == pytest.approx(0.23, abs=0.01)
    page = (tmp_path / "out/discrepancy/report.html").read_text()
    assert "Fitted, not named" in page and "strain_transfer_loss" in page
    assert (tmp_path / "out/report/report.html").is_file()


def same_numbers(fresh: Path, shipped: Path) -> None:
    """The same numbers to 1e-9 (a simulation on another CPU may differ in its last bits)."""
    import numpy as np

    from flaair_tools.bagio.target_log import read_target_log

    assert fresh.suffix in (".csv", ".mat"), f"{shipped.name} differs"
    if fresh.suffix == ".csv":
        assert fresh.read_text().split("\n", 1)[0] == shipped.read_text().split("\n", 1)[0]
        load = [np.genfromtxt(p, delimiter=",", skip_header=1) for p in (fresh, shipped)]
    else:
        labels = ["amp_in", "pvdf_act", "pvdf_hinge", "cam_trig"]
        logs = [read_target_log(p, labels) for p in (fresh, shipped)]
        load = [np.column_stack([log.time_s, *log.signals.values()]) for log in logs]
    np.testing.assert_allclose(load[0], load[1], rtol=1e-9, atol=1e-12, err_msg=shipped.name)


@pytest.mark.timeout(120)
def test_the_shipped_example_is_what_the_script_writes(tmp_path: Path) -> None:
    make_lab_example = import_script("make_lab_example")
    assert make_lab_example.main(["--out", str(tmp_path)]) == 0
    shipped = sorted(p.name for p in EXAMPLE.iterdir())
    assert shipped == sorted(p.name for p in tmp_path.iterdir())
    for name in shipped:
        if (tmp_path / name).read_bytes() != (EXAMPLE / name).read_bytes():
            same_numbers(tmp_path / name, EXAMPLE / name)  # another CPU's last bits
    assert sum((EXAMPLE / name).stat().st_size for name in shipped) < 500_000
