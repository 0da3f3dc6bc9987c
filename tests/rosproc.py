"""Start FLAAIR processes for tests over real DDS, through the project's one launcher.

`flaair_common.graph.Graph` gives each `ros_processes()` block its own leased ROS domain
(localhost discovery), children in their own process groups that die with the test process,
and a stop in reverse order. This module only adapts it to the tests' habits (pipes by default).
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io
import json
import os
import signal
import subprocess
import tempfile
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from flaair_common.graph import Graph, graph_env, lease_domain, wait_for  # noqa: F401 - wait_for re-exported

REPO_ROOT = Path(__file__).resolve().parents[1]
FLAAIR = str(REPO_ROOT / "bin" / "flaair")


def import_script(name: str):
    """A module of the repository's scripts/ (not a package), imported by its name."""
    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None, name
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def graph_pids(domain_id: int | None = None, launcher_pid: int | None = None) -> list[int]:
    """Processes of FLAAIR graphs (their launcher marks them FLAAIR_GRAPH=domain:launcher_pid):
    those on `domain_id`, of `launcher_pid`, or both; never this process.
    """
    wanted = (
        None if domain_id is None else str(domain_id).encode(),
        None if launcher_pid is None else str(launcher_pid).encode(),
    )
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            environ = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        for item in environ:
            if item.startswith(b"FLAAIR_GRAPH="):
                mark = tuple(item.removeprefix(b"FLAAIR_GRAPH=").split(b":", 1))
                # a launcher's mark is domain:pid; a mark without a pid matches on its domain
                if all(w is None or w == m for w, m in zip(wanted, mark, strict=False)):
                    found.append(int(entry.name))
                break
    return found


_LEASES: list = []
# what this test started that exchanges data in real time (conftest checks the mark)
GRAPHS_STARTED: list[str] = []
GRAPH_COMMANDS = {"experiment", "live"}  # `flaair` commands that bring a graph up


def isolated_env() -> dict[str, str]:
    """Environment on a ROS domain leased until the end of the current test, localhost discovery.

    conftest's autouse fixture releases every lease taken during a test when it ends.
    """
    lease = lease_domain()
    _LEASES.append(lease)
    return graph_env(lease.domain_id)


def release_leases() -> None:
    """Release every domain `isolated_env` leased (called after each test)."""
    while _LEASES:
        _LEASES.pop().release()


class Processes:
    """The tests' view of a Graph: child output to files, `flaair(...)` for bin/flaair.

    A child's stdout and stderr go to files in `log_dir` (never to a pipe nobody reads, which
    blocks a chatty child once 64 KiB wait in it). The Popen's `.stdout` / `.stderr` read those
    files (what was written so far), and its `.communicate()` waits for the exit and returns both.
    """

    def __init__(self, graph: Graph) -> None:
        self.graph = graph
        self.env = graph.env
        self.started = [process for _, process in graph.children]
        self.log_dir = Path(tempfile.mkdtemp(prefix="flaair-test-graph-"))

    def start(
        self, *args: str, stdout: IO | None = None, stderr: IO | int | None = None
    ) -> subprocess.Popen:
        """Start a process on the graph's domain; stdout/stderr:
        its own log files (default) or an open file.
        """
        self.graph.env = self.env  # a test may adjust the environment before starting
        words = "_".join(a for a in args[1:3] if a.isidentifier())
        name = f"{len(self.started):02d}_{Path(args[0]).name}_{words}"
        out_path, err_path = self.log_dir / f"{name}.out", self.log_dir / f"{name}.err"
        with open(out_path, "w") as out_file, open(err_path, "w") as err_file:
            process = self.graph.start(
                Path(args[0]).name,
                args,
                stdout=stdout or out_file,
                stderr=err_file if stderr is None else stderr,
            )
        # the logs, read back as Popen's pipes are (`.stderr.read()`) for the process's life
        process.stdout = open(out_path) if stdout is None else None  # noqa: SIM115  Popen's pipe
        process.stderr = open(err_path) if stderr is None else None  # noqa: SIM115  Popen's pipe

        def communicate(input: str | None = None, timeout: float | None = None) -> tuple[str, str]:
            process.wait(timeout=timeout)
            return (
                out_path.read_text() if stdout is None else "",
                err_path.read_text() if stderr is None else "",
            )

        process.communicate = communicate
        self.started.append(process)
        return process

    def flaair(self, *args: str, **kwargs) -> subprocess.Popen:
        return self.start(FLAAIR, *args, **kwargs)

    def stop(
        self, process: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = 10.0
    ) -> int:
        return self.graph.stop(process, sig, timeout_s)

    def stop_all(self) -> None:
        self.graph.stop_all(timeout_s=10.0)


@contextmanager
def ros_processes() -> Iterator[Processes]:
    """Yield a Processes group on a fresh leased domain; every process is stopped on exit."""
    GRAPHS_STARTED.append("ros_processes()")
    with Graph() as graph:
        yield Processes(graph)


def run(
    args: list[str], env: dict[str, str], timeout_s: float = 60.0
) -> subprocess.CompletedProcess:
    """Run a command to completion in `env`, capturing output."""
    if (
        args[:1] == [FLAAIR]
        and len(args) > 1
        and args[1] in GRAPH_COMMANDS
        and "--help" not in args
    ):
        GRAPHS_STARTED.append(f"flaair {args[1]}")
    return subprocess.run(
        args, env=env, capture_output=True, text=True, timeout=timeout_s, cwd=REPO_ROOT
    )


# `flaair` commands that only read and write files: run_offline runs them in the test's process
OFFLINE_COMMANDS = {
    "multisine",
    "simulate",
    "calibrate",
    "import",
    "import-table",
    "analyze",
    "discrepancy",
    "identify",
    "bag",
    "health",
}


def run_offline(
    args: list[str], env: dict[str, str], timeout_s: float = 60.0
) -> subprocess.CompletedProcess:
    """Run an offline `bin/flaair` command as `run` would, but in this process.

    The same entry point (`flaair_tools.cli.main`) gets the same arguments, environment and
    working directory; stdout and stderr are captured, and the exit status is what the
    interpreter would return: SystemExit's code, or 1 with the traceback on stderr for an
    uncaught exception. This spares a new interpreter importing numpy, scipy and numba (about
    2 s a command). `timeout_s` is kept for `run`'s signature: pytest-timeout bounds the test.
    The signal handlers a command installs are put back. One test per command still starts it
    through bin/flaair in a new process, as a person runs it (they say so).
    """
    if args[:1] != [FLAAIR] or len(args) < 2 or args[1] not in OFFLINE_COMMANDS:
        raise ValueError(f"run_offline runs offline flaair commands only, not {args[:2]}")
    cli = importlib.import_module("flaair_tools.cli")
    out, err = io.StringIO(), io.StringIO()
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    saved_env = dict(os.environ)
    os.environ.clear()
    os.environ.update(env)
    try:
        with (
            contextlib.chdir(REPO_ROOT),
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
        ):
            try:
                returncode = int(cli.main(args[1:]) or 0)
            except SystemExit as exc:
                if exc.code is None or isinstance(exc.code, int):
                    returncode = int(exc.code or 0)
                else:
                    print(exc.code, file=err)
                    returncode = 1
            except Exception:
                traceback.print_exc(file=err)
                returncode = 1
    finally:
        os.environ.clear()
        os.environ.update(saved_env)
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    return subprocess.CompletedProcess(args, returncode, out.getvalue(), err.getvalue())


def target_driven(counters: Path) -> bool:
    """The emulated target has applied fresh drive (its counters, written once a second of its
    signal): its watchdog is armed, so a drive that stops from here on trips it.
    """
    try:
        return json.loads(counters.read_text())["fresh_samples"] > 0
    except (OSError, ValueError, KeyError):  # not written yet
        return False


def target_watchdog_tripped(log: Path) -> bool:
    """The emulated target's drive watchdog is tripped
    now: the last state line of its log says so.
    """
    states = [
        line for line in log.read_text().splitlines() if "emulated_target: drive watchdog " in line
    ]
    return bool(states) and " tripped at sample " in states[-1]
