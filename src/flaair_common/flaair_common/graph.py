"""One way to bring up a FLAAIR graph: a private ROS domain, localhost discovery, and child
processes that die with their parent.

Every graph FLAAIR starts (experiments, `flaair live`, the demo, tests, benchmarks) goes
through `Graph`:

  * a ROS domain leased exclusively (an flock on a per-domain lock file, held while the graph
    lives), so two runs on one machine never see each other;
  * ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless asked otherwise (no subnet discovery);
  * each child in its own process group (so a stop reaches its whole tree) with a
    parent-death signal (PR_SET_PDEATHSIG: SIGTERM), so a `kill -9` of the parent leaves no
    orphan feeding the next graph;
  * stop in reverse start order: SIGINT, then SIGKILL after a timeout; logs per child;
  * a node child starts with SIGINT and SIGTERM blocked until its runtime handles them
    (`with_deferred_signals`): a stop during its first second ends it cleanly.

No rclpy here: readiness is checked by the caller (a predicate for `wait_for`).
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO

from ament_index_python.packages import PackageNotFoundError, get_package_prefix

from flaair_model.config import config_dir

DOMAIN_LOCK_DIR = Path(tempfile.gettempdir()) / "flaair-ros-domains"
# 1-101: the domain IDs the ROS 2 docs call safe on Linux (above 101 a domain's ports can reach
# the ephemeral port range); 0 is left alone as every other ROS program's default.
DOMAIN_IDS = range(1, 102)
# how long `Graph.stop` waits for a signalled child before it kills the child's process group
STOP_TIMEOUT_S = 15.0
_PR_SET_PDEATHSIG = 1


class GraphError(RuntimeError):
    """A graph could not be brought up or a child died; the message names which and why."""


class Terminated(BaseException):
    """SIGTERM arrived (see `terminate_raises`): unwind, stop the graph, exit 143.

    A BaseException, like KeyboardInterrupt: no `except Exception` on the way may swallow it.
    """


class DomainLease:
    """A ROS domain ID held exclusively by this process until `release` (or exit)."""

    def __init__(self, domain_id: int, handle: IO[str]) -> None:
        self.domain_id = domain_id
        self._handle: IO[str] | None = handle

    def release(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None


def lease_domain() -> DomainLease:
    """Lease a ROS domain no other FLAAIR graph on this machine holds."""
    DOMAIN_LOCK_DIR.mkdir(parents=True, exist_ok=True)
    candidates = list(DOMAIN_IDS)
    random.Random(os.getpid() ^ time.monotonic_ns()).shuffle(candidates)
    for domain_id in candidates:
        # kept open while the lease lasts (the flock lives as long as the file is open)
        handle = open(DOMAIN_LOCK_DIR / f"domain{domain_id}.lock", "w")  # noqa: SIM115
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return DomainLease(domain_id, handle)
    raise GraphError(
        f"every ROS domain in {DOMAIN_IDS.start}..{DOMAIN_IDS.stop - 1} is leased by "
        f"another FLAAIR graph on this machine (locks in {DOMAIN_LOCK_DIR})"
    )


def graph_env(
    domain_id: int, *, localhost: bool = True, base: dict[str, str] | None = None
) -> dict[str, str]:
    """Environment for a graph's processes: its domain, localhost discovery, unbuffered output."""
    env = dict(os.environ if base is None else base)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    if localhost:
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    else:
        env.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
    env.pop("ROS_LOCALHOST_ONLY", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


# libc's prctl, looked up now: between fork and exec the child only calls it (no dlopen, no import)
_PRCTL = ctypes.CDLL(None, use_errno=True).prctl


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """SIGTERM to this child when its parent dies (PR_SET_PDEATHSIG survives the exec)."""
    _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)


def with_parent_death_signal(argv: Sequence[str]) -> tuple[list[str], Callable[[], None] | None]:
    """(argv, preexec_fn) that make the child receive SIGTERM when this process dies.

    The prctl runs in the child itself: `setpriv --pdeathsig TERM` (tried first) left the child
    alive after its Python parent's kill -9 in 11 of 30 trials on this machine, the prctl in 0.
    """
    return list(argv), _die_with_parent


# coreutils >= 8.31 blocks signals for the command it execs (--block-signal)
_ENV = shutil.which("env")
_ENV_BLOCKS: list[bool] = []


def is_node_executable(path: str | os.PathLike) -> bool:
    """True for a node's console script, <prefix>/lib/<package>/<name>_node or .../container: those
    end through flaair_common.runtime, which unblocks SIGINT and SIGTERM once it handles them.
    """
    path = Path(path)
    return path.parent.parent.name == "lib" and (
        path.name.endswith("_node") or path.name == "container"
    )


def with_deferred_signals(argv: Sequence[str]) -> list[str]:
    """Argv that starts a node with SIGINT and SIGTERM at their default action but blocked.

    From exec until flaair_common.runtime has its handlers in place (Python starting, the node
    module's first imports) a Ctrl-C or SIGTERM then stays pending instead of interrupting an
    import with a traceback; runtime unblocks them and the node ends cleanly (exit 0). Default,
    not ignored: a parent that ignores SIGINT (a background shell) still stops its node with it.
    Any other argv is returned unchanged.
    """
    argv = list(argv)
    program = (
        argv[1]
        if len(argv) > 1 and Path(argv[0]).name.startswith("python")
        else argv[0]
        if argv
        else ""
    )
    if not argv or not is_node_executable(program) or not _env_blocks_signals():
        return argv
    return [
        _ENV,
        "--default-signal=INT",
        "--default-signal=TERM",
        "--block-signal=INT",
        "--block-signal=TERM",
        "--",
        *argv,
    ]


def _env_blocks_signals() -> bool:
    """Whether this machine's `env` has --block-signal (checked once)."""
    if not _ENV_BLOCKS:
        _ENV_BLOCKS.append(
            _ENV is not None
            and subprocess.run(
                [_ENV, "--block-signal=INT", "true"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            ).returncode
            == 0
        )
    return _ENV_BLOCKS[0]


def repo_root() -> Path:
    """The checkout (FLAAIR_ROOT, set by bin/flaair, else the one holding config/)."""
    env = os.environ.get("FLAAIR_ROOT")
    if env:
        return Path(env)
    return config_dir().parent


def flaair_argv(*args: str) -> list[str]:
    """Argv of `bin/flaair ARGS...`."""
    return [str(repo_root() / "bin" / "flaair"), *args]


def node_argv(package: str, executable: str, ros_args: Sequence[str] = ()) -> list[str]:
    """Argv of one node from the install space (like `ros2 run`), in this interpreter."""
    try:
        path = Path(get_package_prefix(package)) / "lib" / package / executable
    except PackageNotFoundError as exc:
        raise GraphError(f"package {package} is not built; run scripts/setup_env.sh") from exc
    if not path.exists():
        raise GraphError(f"no executable {executable} in {package} ({path})")
    return [sys.executable, str(path), *(["--ros-args", *ros_args] if ros_args else [])]


class Graph:
    """Child processes of one graph on one private domain (a context manager: stops them all)."""

    def __init__(
        self, *, domain_id: int | None = None, localhost: bool = True, log_dir: Path | None = None
    ) -> None:
        self.lease = lease_domain() if domain_id is None else None
        self.domain_id = self.lease.domain_id if self.lease is not None else int(domain_id)
        self.localhost = localhost
        self.env = graph_env(self.domain_id, localhost=localhost)
        # Marks every process of this graph (and theirs): what a search for strays looks for.
        self.env["FLAAIR_GRAPH"] = f"{self.domain_id}:{os.getpid()}"
        self.log_dir = log_dir
        self.children: list[tuple[str, subprocess.Popen]] = []

    def describe(self) -> str:
        scope = "localhost" if self.localhost else "subnet"
        return f"ROS domain {self.domain_id}, {scope} discovery"

    def start(
        self,
        name: str,
        argv: Sequence[str],
        *,
        stdout=None,
        stderr=None,
        stdin=subprocess.DEVNULL,
        text: bool = True,
    ) -> subprocess.Popen:
        """Start a child; output goes to LOG_DIR/NAME.log unless stdout/stderr say otherwise."""
        log = None
        if self.log_dir is not None and (stdout is None or stderr is None):
            self.log_dir.mkdir(parents=True, exist_ok=True)
            # only when logging: closed below, once Popen has handed the child its own descriptor
            log = open(self.log_dir / f"{name}.log", "w")  # noqa: SIM115
        argv, preexec = with_parent_death_signal(with_deferred_signals(argv))
        process = subprocess.Popen(
            argv,
            env=self.env,
            cwd=repo_root(),
            text=text,
            stdin=stdin,
            stdout=stdout if stdout is not None else (log or subprocess.DEVNULL),
            stderr=stderr
            if stderr is not None
            else (
                log
                if log and stdout is not None
                else subprocess.STDOUT
                if log
                else subprocess.DEVNULL
            ),
            start_new_session=True,
            preexec_fn=preexec,
        )
        if log is not None:
            log.close()  # the child holds its own descriptor
        self.children.append((name, process))
        return process

    def log_tail(self, name: str, lines: int = 15) -> str:
        """The last lines of a child's log (empty without a log directory)."""
        path = self.log_dir / f"{name}.log" if self.log_dir is not None else None
        if path is None or not path.exists():
            return ""
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])

    def check_alive(self, ok_codes: Sequence[int] = (0, -signal.SIGINT)) -> None:
        """Raise GraphError naming a child that died, with its log's last lines."""
        for name, process in self.children:
            if process.poll() is not None and process.returncode not in ok_codes:
                tail = self.log_tail(name)
                raise GraphError(
                    f"{name} exited with code {process.returncode}" + (f":\n{tail}" if tail else "")
                )

    def stop(
        self, process: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = STOP_TIMEOUT_S
    ) -> int:
        """Signal a child's process group, wait, then kill it; returns its exit code."""
        if process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, sig)
        try:
            return process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            return process.wait()

    def stop_together(
        self, processes: Sequence[subprocess.Popen], timeout_s: float = STOP_TIMEOUT_S
    ) -> None:
        """Signal every one of `processes` at once (SIGINT), then wait for each (then kill it):
        for children whose stopping order does not matter, each spending its own wait for acks.
        """
        for process in processes:
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for process in processes:
            self.stop(process, timeout_s=max(0.0, deadline - time.monotonic()))

    def stop_all(self, timeout_s: float = STOP_TIMEOUT_S) -> None:
        """Stop every child, last started first."""
        for _, process in reversed(self.children):
            self.stop(process, timeout_s=timeout_s)

    def close(self) -> None:
        self.stop_all()
        if self.lease is not None:
            self.lease.release()

    def __enter__(self) -> Graph:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_for(predicate: Callable[[], bool], timeout_s: float, interval_s: float = 0.05) -> bool:
    """Poll ``predicate`` until true or ``timeout_s``; returns its last value."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return bool(predicate())


_terminate_requested = False


def is_termination(exc: BaseException) -> bool:
    """`exc` is SIGTERM's `Terminated`, or what rclpy made of it: rclpy turns an exception raised
    inside one of its calls into a RuntimeError ("Unable to convert call argument"), told apart
    from a real one by SIGTERM having arrived.
    """
    return isinstance(exc, Terminated) or (isinstance(exc, RuntimeError) and _terminate_requested)


def terminate_raises() -> None:
    """From now on SIGTERM raises `Terminated` in the main thread (a CLI unwinds and exits 143).

    SIGINT and SIGTERM are unblocked too: a CLI that handles them must see them even when it was
    started with them blocked (a launcher's signal mask is inherited across exec).
    """

    def handler(signum: int, frame: object) -> None:
        global _terminate_requested
        _terminate_requested = True
        raise Terminated()

    signal.signal(signal.SIGTERM, handler)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
