"""Start FLAAIR processes for tests over real DDS: isolated domain, localhost only, always cleaned up."""
from __future__ import annotations

import fcntl
import itertools
import os
import signal
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

REPO_ROOT = Path(__file__).resolve().parents[1]
FLAAIR = str(REPO_ROOT / "bin" / "flaair")
DOMAINS_PER_SLOT = 10
SLOTS = 20  # domains 1..200
_domain_counter = itertools.count()
_slot: tuple[int, object] | None = None


def _domain_slot() -> int:
    """A block of domain IDs this test process holds exclusively (flock) while it lives.

    Two test runs on one machine (say a developer's and another's) must never share a domain:
    their nodes would see each other's blocks.
    """
    global _slot
    if _slot is None:
        lock_dir = Path("/tmp/flaair-ros-domains")
        lock_dir.mkdir(exist_ok=True)
        for slot in range(SLOTS):
            handle = open(lock_dir / f"slot{slot}", "w")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                handle.close()
                continue
            _slot = (slot, handle)
            break
        else:
            raise RuntimeError(f"all {SLOTS} ROS domain slots are taken by other test runs")
    return _slot[0]


def isolated_env() -> dict[str, str]:
    """Environment for one test: a ROS_DOMAIN_ID no other test run uses, loopback-only discovery."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(1 + _domain_slot() * DOMAINS_PER_SLOT + next(_domain_counter) % DOMAINS_PER_SLOT)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


class Processes:
    """Processes started in their own process groups; stop() signals, waits, then kills."""

    def __init__(self, env: dict[str, str]) -> None:
        self.env = env
        self.started: list[subprocess.Popen] = []

    def start(self, *args: str, stdout=subprocess.PIPE, stderr=subprocess.PIPE) -> subprocess.Popen:
        """Start a process in its own session; stdout/stderr: PIPE (default) or an open file."""
        process = subprocess.Popen(
            list(args), env=self.env, stdout=stdout, stderr=stderr, text=True,
            start_new_session=True, cwd=REPO_ROOT,
        )
        self.started.append(process)
        return process

    def flaair(self, *args: str, **kwargs) -> subprocess.Popen:
        return self.start(FLAAIR, *args, **kwargs)

    def stop(self, process: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = 10.0) -> int:
        if process.poll() is None:
            try:
                os.killpg(process.pid, sig)
            except ProcessLookupError:
                pass
        try:
            return process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            return process.wait()

    def stop_all(self) -> None:
        for process in self.started:
            self.stop(process)


@contextmanager
def ros_processes() -> Iterator[Processes]:
    """Yield a Processes group on a fresh isolated domain; every process is stopped on exit."""
    group = Processes(isolated_env())
    try:
        yield group
    finally:
        group.stop_all()


def run(args: list[str], env: dict[str, str], timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    """Run a command to completion in `env`, capturing output."""
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=timeout_s, cwd=REPO_ROOT)


def wait_for(predicate, timeout_s: float, interval_s: float = 0.05) -> bool:
    """Poll `predicate` until true or timeout; return its last value."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return bool(predicate())
