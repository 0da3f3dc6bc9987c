"""Fault suite, issue 38: nothing lost, nothing redirected, nothing unbounded.

The bridge's target address, outputs that would overwrite inputs, outliers and non-finite
samples in lab files, duplicated keys, YAML alias bombs, special files, huge integers and
decompression bombs. Each test fails on the code before the fix.
"""

from __future__ import annotations

import numpy as np
import pytest

from flaair_bridge.core import protocol, target
from flaair_bridge.core.protocol import SensorPacket

pytestmark = pytest.mark.timeout(120)

TARGET = ("10.0.0.2", 25001)
STRAY = ("10.6.6.6", 4444)


def _valid_packet() -> bytes:
    return protocol.pack_sensor(SensorPacket(0, 0, 20000.0, 0, *np.zeros((3, 4), np.float32)))


def _bridge_after(datagrams, host: str = "", port: int = 0):
    """The bridge's target after `datagrams` arrived: the decision its node takes for every
    datagram (`target.follow`, bridge_node.on_datagram), with no ROS and no socket.
    """
    current = target.configured(host, port)
    for data, sender in datagrams:
        current, _notes = target.follow(host, port, sender, current, data)
    return current


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
