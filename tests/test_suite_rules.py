"""The rules the test suite keeps: every graph test marked, no test skipped for a missing module of
the project's own, and `topic pub --wait-subscribers` that fails rather than publishing to no one.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

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
