"""The rules the test suite keeps: every graph test marked, no test skipped for a missing module of
the project's own, and `topic pub --wait-subscribers` that fails rather than publishing to no one.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from rosproc import FLAAIR, isolated_env, run

TESTS = Path(__file__).resolve().parent


def test_no_test_module_skips_on_an_import() -> None:
    """A broken build must fail the suite, not turn whole modules into skips."""
    offenders = [
        f"{path.name}:{n}"
        for path in sorted(TESTS.glob("*.py"))
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if re.search(r"\bimportorskip\(", line) and path.name != Path(__file__).name
    ]
    assert offenders == []


@pytest.mark.slow  # runs pytest in a new process
def test_an_unmarked_test_that_starts_a_graph_fails(tmp_path: Path) -> None:
    """Conftest's check: a test starting a ROS graph without @pytest.mark.graph fails by name."""
    (tmp_path / "conftest.py").write_text(
        "import importlib.util, sys\nsys.path.insert(0, {!r})\n"
        "spec = importlib.util.spec_from_file_location('suite_conftest', {!r})\n"
        "suite = importlib.util.module_from_spec(spec)\nspec.loader.exec_module(suite)\n"
        "_graph_tests_are_marked = suite._graph_tests_are_marked\n".format(
            str(TESTS), str(TESTS / "conftest.py")
        )
    )
    (tmp_path / "test_unmarked.py").write_text(
        f"import sys\nsys.path.insert(0, {str(TESTS)!r})\nfrom rosproc import ros_processes\n\n"
        "def test_starts_a_graph():\n    with ros_processes():\n        pass\n"
    )
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    result = subprocess.run(
        ["python", "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert result.returncode == 1, result.stdout[-2000:]
    assert "starts ros_processes() but is not marked @pytest.mark.graph" in result.stdout


@pytest.mark.slow  # waits out the publisher's 1 s for subscribers in a new process
def test_topic_pub_fails_without_publishing_when_its_subscribers_never_come() -> None:
    result = run(
        [
            FLAAIR,
            "topic",
            "pub",
            "/flaair/nobody",
            "std_msgs/msg/String",
            '{"data": "x"}',
            "--wait-subscribers",
            "1",
            "--wait-timeout",
            "1",
        ],
        isolated_env(),
        60,
    )
    assert result.returncode == 1, result.stderr
    assert (
        "'/flaair/nobody' has 0 subscriber(s) after 1 s; wanted 1: nothing published"
        in result.stderr
    )
    assert "Traceback" not in result.stderr


def _slow_marks_without_a_reason(path: Path) -> list[str]:
    """The lines of `path` that mark a test `slow` with no reason: a comment on the line, or
    a comment directly above it (over the test's other decorators).
    """
    lines = path.read_text().splitlines()
    found = []
    for n, line in enumerate(lines):
        if "pytest.mark.slow" not in line or line.lstrip().startswith("#"):
            continue
        if "#" in line.split("pytest.mark.slow", 1)[1]:
            continue
        above = n - 1
        while above >= 0 and lines[above].lstrip().startswith("@"):
            above -= 1
        if above >= 0 and lines[above].lstrip().startswith("#"):
            continue
        found.append(f"{path.name}:{n + 1}")
    return found


def test_every_slow_test_says_why_it_cannot_be_smaller(tmp_path: Path) -> None:
    """`make test-quick` leaves out the `slow` tests (docs/TESTING.md); each says why it costs
    what it does, so a test is not moved out of the edit-test loop without one.
    """
    offenders = [
        where
        for path in sorted(TESTS.glob("test_*.py"))
        if path.name != Path(__file__).name  # its own texts name the mark
        for where in _slow_marks_without_a_reason(path)
    ]
    assert offenders == []
    unexplained = tmp_path / "test_x.py"
    unexplained.write_text("@pytest.mark.slow\ndef test_a():\n    pass\n")
    explained = tmp_path / "test_y.py"
    explained.write_text(
        "# slow: a fit\n@pytest.mark.slow\n@pytest.mark.timeout(9)\ndef test_b():\n"
    )
    assert _slow_marks_without_a_reason(unexplained) == ["test_x.py:1"]
    assert _slow_marks_without_a_reason(explained) == []
