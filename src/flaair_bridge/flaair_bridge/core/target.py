"""Where the bridge sends drive and stop packets: the target's address (pure).

A configured host and port are used as they are; either left empty (0) is learnt from the
sender of a valid sensor packet of the protocol (`protocol.target_address`: a stray or malformed
datagram never redirects the drive), and followed when the target restarts elsewhere.
"""

from __future__ import annotations

from flaair_bridge.core import protocol
from flaair_model.notes import INFO, Note

__all__ = ["Address", "configured", "follow"]

Address = tuple[str, int]


def configured(host: str, port: int) -> Address | None:
    """The configured target; None: learnt when the target speaks."""
    return (host, port) if host and port else None


def follow(
    host: str, port: int, sender: Address, current: Address | None, data: bytes | memoryview
) -> tuple[Address | None, tuple[Note, ...]]:
    """The target after datagram `data` from `sender` (`host`, `port`: the configured ones, each
    empty or 0 to take the sender's), with a note when it changed (the first valid packet, or a
    target that restarted elsewhere).
    """
    configured_address = {"target_host": host, "target_port": port}
    target = protocol.target_address(current, configured_address, data, sender)
    if target == current or target is None:
        return current, ()
    return target, (
        Note(INFO, f"target at {target[0]}:{target[1]}: drive and stop packets go there"),
    )
