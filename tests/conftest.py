"""Shared pytest setup: the pure cores import straight from src/ (no build needed); every ROS
domain a test leased is released when the test ends.
"""

from __future__ import annotations

import signal
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
for package_dir in sorted((REPO_ROOT / "src").iterdir()):
    if (package_dir / "setup.py").exists() and str(package_dir) not in sys.path:
        sys.path.insert(0, str(package_dir))

import rosproc


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C at its default action for every process a test starts, as from a terminal.

    A test run started in the background (`make test &` in a script, a CI runner's job) may have
    SIGINT ignored, and every process it starts inherits that: the tests that stop a node, `live`
    or `launch` with Ctrl-C would wait out their limits instead (seen: two graph tests, 50 and
    120 s each). A Python handler here becomes the default action across exec.
    """
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The modules with the most `slow` tests first, each module's tests kept together and in
    order: spread over the workers, the longest tests start early instead of leaving one worker
    running them alone at the end of the phase. The same order in every worker (xdist requires it).
    """

    def module(item: pytest.Item) -> str:
        return item.nodeid.split("::")[0]

    slow = Counter(module(item) for item in items if item.get_closest_marker("slow") is not None)
    items.sort(key=lambda item: -slow[module(item)])


@pytest.fixture(autouse=True)
def _graph_tests_are_marked(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test that starts a ROS graph (or an experiment, `live`, a recorder) must be marked `graph`,
    so that it runs after the others (scripts/run_tests.sh); a domain it leased is released when it
    ends.
    """
    yield  # (a module fixture's graph, started before this fixture, counts for its first test)
    rosproc.release_leases()
    started, rosproc.GRAPHS_STARTED[:] = list(rosproc.GRAPHS_STARTED), []
    if started and request.node.get_closest_marker("graph") is None:
        pytest.fail(
            f"{request.node.nodeid} starts {', '.join(sorted(set(started)))} but is not "
            "marked @pytest.mark.graph (graph tests run after the others)",
            pytrace=False,
        )
