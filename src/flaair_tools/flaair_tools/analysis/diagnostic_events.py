"""A run's diagnostic events from its bag: every change of a node's health level on /diagnostics.

Each node publishes its health once a second (`flaair_common.diagnostics`: OK 0, WARN 1, ERROR 2,
STALE 3). An event is a status whose level differs from the one before it under the same name
(the first status counts as a change when it is not OK): a tripped watchdog (ERROR), packet
loss (WARN), and their return to OK. `level_changes` decides, without files; `from_bag` reads
the bag's /diagnostics (a bag without it has no events).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

from flaair_tools import bagio

__all__ = ["DIAGNOSTICS", "LEVEL_NAMES", "Status", "from_bag", "level_changes", "statuses_from_bag"]

DIAGNOSTICS = "/diagnostics"
LEVEL_NAMES = ("OK", "WARN", "ERROR", "STALE")


class Status(NamedTuple):
    """One DiagnosticStatus as logged: its log time [ns] (the bag's signal timeline), name,
    node, level, message, and the array's own stamp [ns] (the publishing node's clock).
    """

    time_ns: int
    name: str
    hardware_id: str
    level: int
    message: str
    stamp_ns: int = 0


def level_name(level: int) -> str:
    """'OK', 'WARN', 'ERROR', 'STALE' (else the number)."""
    return LEVEL_NAMES[level] if 0 <= level < len(LEVEL_NAMES) else str(level)


def level_changes(statuses: Iterable[Status], start_ns: int) -> list[dict[str, Any]]:
    """The level changes of `statuses` (in log-time order), with their times.

    Parameters
    ----------
    statuses
        Every status of the run, in log-time order.
    start_ns
        The bag's start [ns]: `time_s` counts from it.

    Returns
    -------
    list of dict
        One per change: `time_s` (from the bag's start), `time_ns` (log time: the signal's
        timeline), `stamp_ns` (the node's clock), `node` (hardware id), `name`, `level` and
        `previous` (level names), `message`.
    """
    last: dict[str, int] = {}
    events = []
    for status in statuses:
        previous = last.get(status.name, 0)
        last[status.name] = status.level
        if status.level == previous:
            continue
        events.append(
            {
                "time_s": (status.time_ns - start_ns) * 1e-9,
                "time_ns": status.time_ns,
                "stamp_ns": status.stamp_ns,
                "node": status.hardware_id,
                "name": status.name,
                "level": level_name(status.level),
                "previous": level_name(previous),
                "message": status.message,
            }
        )
    return events


def _statuses(messages: Iterable[tuple[str, int, Any]]) -> Iterable[Status]:
    for _, time_ns, array in messages:
        stamp_ns = array.header.stamp.sec * 1_000_000_000 + array.header.stamp.nanosec
        for status in array.status:
            level = status.level
            level = level[0] if isinstance(level, (bytes, bytearray)) else int(level)
            yield Status(time_ns, status.name, status.hardware_id, level, status.message, stamp_ns)


def statuses_from_bag(bag: str | Path) -> list[Status]:
    """Every status of `bag`'s /diagnostics in log-time order (none without the topic): what
    a node said each second, also where its level did not change (a second fault while the
    first holds the node at ERROR).
    """
    if DIAGNOSTICS not in bagio.bag_info(bag).topics:
        return []
    return list(_statuses(bagio.iter_messages(bag, [DIAGNOSTICS])))


def from_bag(bag: str | Path) -> list[dict[str, Any]]:
    """The diagnostic events of `bag` (`level_changes`); none if it has no /diagnostics."""
    info = bagio.bag_info(bag)
    if DIAGNOSTICS not in info.topics:
        return []
    return level_changes(_statuses(bagio.iter_messages(bag, [DIAGNOSTICS])), info.start_ns)
