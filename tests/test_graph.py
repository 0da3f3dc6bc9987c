"""The graph launcher (flaair_common.graph): private
domains, no orphans, clean ends of `experiment`.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import pytest

from flaair_common.graph import Graph, lease_domain, wait_for
from rosproc import graph_pids

REPO_ROOT = Path(__file__).resolve().parents[1]
FLAAIR = str(REPO_ROOT / "bin" / "flaair")
PACKAGE_DIRS = [str(p) for p in (REPO_ROOT / "src").iterdir() if (p / "setup.py").exists()]


def _describe(pids: list[int], log_dir: Path | None = None) -> str:
    """What a lingering process is doing: its command, state, signal masks, kernel wait channel
    and the last lines of its log (a graph child's log is LOG_DIR/<role>.log).
    """
    lines = []
    logs = sorted(log_dir.glob("*.log")) if log_dir is not None and log_dir.is_dir() else []
    for pid in pids:
        proc = Path(f"/proc/{pid}")
        try:
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            status = {
                k: v.strip()
                for k, _, v in (
                    line.partition(":") for line in (proc / "status").read_text().splitlines()
                )
            }
            wchan = (proc / "wchan").read_text()
        except OSError as exc:
            lines.append(f"{pid}: gone ({exc.strerror})")
            continue
        lines.append(f"{pid}: {cmdline[:300]}")
        lines.append(
            f"  state {status.get('State')} threads {status.get('Threads')} wchan {wchan} "
            + " ".join(
                f"{k} {status.get(k)}" for k in ("SigPnd", "ShdPnd", "SigBlk", "SigIgn", "SigCgt")
            )
        )
        for log in logs:
            if log.stem in cmdline:
                tail = log.read_text(errors="replace").splitlines()[-12:]
                lines += [f"  {log.name}: {line}" for line in tail]
    return "\n".join(lines)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    status = Path(f"/proc/{pid}/stat")
    return status.exists() and status.read_text().rsplit(")", 1)[1].split()[0] != "Z"


def test_a_leased_domain_is_never_leased_twice_while_held():
    first = lease_domain()
    try:
        others = [lease_domain() for _ in range(20)]
        assert first.domain_id not in [o.domain_id for o in others]
        assert len({o.domain_id for o in others}) == 20
        for other in others:
            other.release()
    finally:
        first.release()


def test_graph_env_is_private_and_localhost():
    with Graph() as graph:
        assert graph.env["ROS_DOMAIN_ID"] == str(graph.domain_id)
        assert graph.env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
        assert "localhost" in graph.describe() and str(graph.domain_id) in graph.describe()


@pytest.mark.graph
def test_children_die_when_the_parent_is_killed(tmp_path):
    """Kill -9 of the process that started a graph:
    its children get SIGTERM (parent-death signal).
    """
    script = textwrap.dedent(f"""
        import sys, time
        sys.path[:0] = {PACKAGE_DIRS!r}
        from flaair_common.graph import Graph
        graph = Graph()
        child = graph.start("sleeper", [sys.executable, "-c", "import time; time.sleep(120)"])
        print(child.pid, flush=True)
        time.sleep(120)
    """)
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        child_pid = int(parent.stdout.readline())
        # the child runs its own program (its parent-death signal was set before the exec)
        assert wait_for(
            lambda: b"time.sleep" in Path(f"/proc/{child_pid}/cmdline").read_bytes(), 30.0
        )
        assert _alive(child_pid)
        parent.kill()
        parent.wait()
        assert wait_for(lambda: not _alive(child_pid), 10.0), "the child outlived its killed parent"
    finally:
        if parent.poll() is None:
            parent.kill()


_BAR_COUNT = re.compile(r"\| *([\d.]+)([kM]?)/")  # tqdm's "| 10.0/60.0k": samples done so far


def _samples_moved(text: str) -> bool:
    """The run's progress bar has counted a sample (tqdm may print no percentage in between)."""
    return any(float(n) > 0 for n, _ in _BAR_COUNT.findall(text))


def _start_experiment(tmp_path: Path) -> tuple[subprocess.Popen, int, Path]:
    """A running experiment (the stepped sines: 3 s of signal) once its first samples count.

    The 1 s chirp once ran whole between two progress-bar updates, so the gate missed it.
    """
    bag = tmp_path / "bag"
    process = subprocess.Popen(
        [FLAAIR, "experiment", "stepped_sine", "--out", str(bag)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO_ROOT,
    )
    seen = []
    for _ in range(20):
        seen.append(process.stderr.readline())
        match = re.search(r"on ROS domain (\d+), localhost discovery", seen[-1])
        if match:
            break
    assert match, f"experiment did not say which domain: {seen!r}"
    domain = int(match.group(1))
    assert wait_for(lambda: len(graph_pids(domain)) >= 4, 120.0)
    text, deadline = "", time.monotonic() + 120.0
    while not _samples_moved(text) and time.monotonic() < deadline and process.poll() is None:
        text += process.stderr.read(1)
    # say why: the experiment's own last words, if it ended
    if not _samples_moved(text) or process.poll() is not None:
        rest = process.stderr.read() if process.poll() is not None else ""
        raise AssertionError(
            f"the run did not get going (exit {process.poll()}): {(text + rest)[-1500:]!r}"
        )
    return process, domain, bag


def test_a_progress_bar_that_counted_samples_is_seen_without_a_percentage() -> None:
    # the text the failed soak run saw: 10 samples counted, 0 %, then the run's end
    assert _samples_moved("chirp:   0%|          | 10.0/20.0k [00:03<33:39, 9.90sample/s]")
    assert not _samples_moved("chirp:   0%|          | 0.00/20.0k [00:01<?, ?sample/s]")
    assert _samples_moved("stepped:  41%|####      | 24.6k/60.0k [00:02<00:03]")


@pytest.mark.graph
@pytest.mark.slow  # starts an experiment's whole graph and waits for its clean end
def test_sigterm_ends_an_experiment_cleanly(tmp_path):
    from flaair_tools import bagio

    process, domain, bag = _start_experiment(tmp_path)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 143, stderr
    assert "Traceback" not in stderr and "terminated" in stderr
    # every child was stopped; one still exiting (a zombie being reaped) gets a moment
    assert wait_for(lambda: graph_pids(domain) == [], 15.0), _describe(
        graph_pids(domain), bag.parent / f"{bag.name}.logs"
    )
    counts = bagio.message_counts(bag)  # the bag was closed: an independent read works
    assert counts.get("/flaair/sensor_v", 0) > 0


@pytest.mark.graph
@pytest.mark.slow  # starts an experiment's whole graph and waits for every node to end
def test_kill_9_of_an_experiment_leaves_no_node_running(tmp_path):
    from flaair_common.runtime import EXIT_ALARM_MARGIN_S, EXIT_DEADLINE_S

    process, domain, bag = _start_experiment(tmp_path)
    process.kill()
    process.wait()
    # Each node ends on its parent-death SIGTERM, in about ACK_WAIT_S (its readers in the killed
    # process never ack); one whose stop hangs ends at its exit deadline.
    logs = bag.parent / f"{bag.name}.logs"
    assert wait_for(
        lambda: graph_pids(domain) == [], EXIT_DEADLINE_S + EXIT_ALARM_MARGIN_S + 10.0
    ), f"orphans on domain {domain}:\n" + _describe(graph_pids(domain), logs)
    texts = {log.name: log.read_text(errors="replace") for log in logs.glob("*.log")}
    hung = {name: text[-4000:] for name, text in texts.items() if "Timeout (0:" in text}
    if hung:  # ended by the deadline: say where the stop hung (once seen in CI, not here)
        warnings.warn(f"a node's stop hung until its exit deadline: {hung}", stacklevel=1)
