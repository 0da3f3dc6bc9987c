"""`flaair live` faults a person meets at the bench: a Foxglove port already taken, a target that
never answers (a mistyped port). One clear line, a non-zero exit, nothing left half done.
"""

from __future__ import annotations

import contextlib
import socket
import subprocess
import time
from pathlib import Path

import pytest

from rosproc import FLAAIR, REPO_ROOT, isolated_env

pytestmark = pytest.mark.graph  # brings a live graph up (against no target)


def _udp_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    return sock


def test_a_foxglove_port_in_use_is_named_in_one_line() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run(
            [FLAAIR, "live", "--sim", "--duration", "2", "--foxglove", f"127.0.0.1:{port}"],
            env=isolated_env(),
            capture_output=True,
            text=True,
            timeout=120,
            cwd=REPO_ROOT,
        )
    assert result.returncode == 2, result.stderr[-3000:]
    assert (
        result.stderr.strip()
        == f"flaair live: --foxglove 127.0.0.1:{port}: port in use (Address already in use)"
    )


def test_a_silent_target_is_waited_for_named_then_given_up_with_a_stop_packet_and_a_closed_bag(
    tmp_path: Path,
) -> None:
    from flaair_bridge.core import protocol
    from flaair_tools import bagio

    target = _udp_socket()  # where drive goes: nothing answers from here
    target.settimeout(0.2)
    with _udp_socket() as probe:  # a free port to listen on, where no target sends
        listen_port = probe.getsockname()[1]
    target_port, bag = target.getsockname()[1], tmp_path / "bag"
    started = time.monotonic()
    live = subprocess.Popen(
        [
            FLAAIR,
            "live",
            "--target",
            f"127.0.0.1:{target_port}",
            "--listen",
            f"127.0.0.1:{listen_port}",
            "--duration",
            "5",
            "--out",
            str(bag),
            "--first-packet-timeout",
            "2",
        ],
        env=isolated_env(),
        cwd=REPO_ROOT,
        stdout=subprocess.DEVNULL,
        stderr=open(tmp_path / "live.err", "w"),  # noqa: SIM115  the child's log
    )
    received: list[bytes] = []
    try:
        while live.poll() is None and time.monotonic() - started < 120:
            with contextlib.suppress(TimeoutError):
                received.append(target.recvfrom(65536)[0])
        # live has exited: what it sent last (the stop packet) may still wait unread in the buffer
        target.setblocking(False)
        while True:
            try:
                received.append(target.recvfrom(65536)[0])
            except BlockingIOError:
                break
    finally:
        if live.poll() is None:
            live.kill()
        target.close()
    stderr = (tmp_path / "live.err").read_text()
    assert live.wait(timeout=10) == 3, stderr[-3000:]
    assert "Traceback" not in stderr
    assert (
        f"waiting for the target's first sensor packet on 127.0.0.1:{listen_port} (drive goes "
        f"to 127.0.0.1:{target_port}); giving up after 2 s"
    ) in stderr
    assert (
        f"error: no sensor packet from the target on 127.0.0.1:{listen_port} in 2 s (drive was "
        f"addressed to 127.0.0.1:{target_port})"
    ) in stderr
    stops = [p for p in map(protocol.unpack_drive, received) if p.stop]
    # the stop packet reached the target
    assert stops and all(not p.drive_v.any() for p in stops)
    assert f"bag {bag} closed" in stderr
    bagio.message_counts(bag)  # a complete bag: it reads
    info = subprocess.run(
        [FLAAIR, "bag", "info", str(bag)], capture_output=True, text=True, timeout=60
    )
    assert info.returncode == 0, info.stdout + info.stderr
