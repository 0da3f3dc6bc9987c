"""Fault suite, issue 38: nothing lost, nothing redirected, nothing unbounded.

The bridge's target address, outputs that would overwrite inputs, outliers and non-finite
samples in lab files, duplicated keys, YAML alias bombs, special files, huge integers and
decompression bombs. Each test fails on the code before the fix.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from flaair_bridge.core import protocol
from flaair_bridge.core.protocol import SensorPacket

pytestmark = pytest.mark.timeout(120)

TARGET = ("10.0.0.2", 25001)
STRAY = ("10.6.6.6", 4444)


def _valid_packet() -> bytes:
    return protocol.pack_sensor(SensorPacket(0, 0, 20000.0, 0, *np.zeros((3, 4), np.float32)))


def _bridge_after(datagrams, host: str = "", port: int = 0):
    """The bridge node's target after its `on_datagram` saw `datagrams` (no ROS, no socket)."""
    from flaair_bridge.bridge_node import BridgeNode

    logger = SimpleNamespace(info=lambda *_: None)
    node = SimpleNamespace(
        p={"target_host": host, "target_port": port},
        target=(host, port) if host and port else None,
        state=SimpleNamespace(counters=SimpleNamespace(drive_packets=0)),
        process=lambda _inputs: None,
        get_logger=lambda: logger,
    )
    for data, sender in datagrams:
        BridgeNode.on_datagram(node, data, sender, 0.0)
    return node.target


def test_a_stray_datagram_never_redirects_the_drive() -> None:
    assert _bridge_after([(_valid_packet(), TARGET), (b"junk", STRAY)]) == TARGET
    assert _bridge_after([(b"\x00" * 40, STRAY)]) is None
    # a malformed packet with the right magic does not count either
    assert _bridge_after([(_valid_packet(), TARGET), (_valid_packet()[:-1], STRAY)]) == TARGET
    # a valid packet from a target that restarted elsewhere is followed
    assert _bridge_after([(_valid_packet(), TARGET), (_valid_packet(), STRAY)]) == STRAY


def test_a_configured_target_is_never_learnt() -> None:
    assert _bridge_after([(_valid_packet(), STRAY)], *TARGET) == TARGET
    assert _bridge_after([(_valid_packet(), STRAY)], TARGET[0], 0) == (TARGET[0], STRAY[1])
