"""Where the bridge sends drive and stop packets: the target's address (pure).

A configured host and port are used as they are; either left empty (0) is learnt from the
sender of the target's packets, and followed when the target restarts elsewhere.
"""

from __future__ import annotations

from flaair_model.notes import INFO, Note

__all__ = ["Address", "configured", "follow"]

Address = tuple[str, int]


def configured(host: str, port: int) -> Address | None:
    """The configured target; None: learnt when the target speaks."""
    return (host, port) if host and port else None


def follow(
    host: str, port: int, sender: Address, current: Address | None
) -> tuple[Address | None, tuple[Note, ...]]:
    """The target after a datagram from `sender` (`host`, `port`: the configured ones, each
    empty or 0 to take the sender's), with a note when it changed (the first packet, or a
    target that restarted elsewhere).
    """
    target = (host or sender[0], port or sender[1])
    if target == current:
        return current, ()
    return target, (
        Note(INFO, f"target at {target[0]}:{target[1]}: drive and stop packets go there"),
    )
