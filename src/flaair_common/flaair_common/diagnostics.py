"""A node's health as data: what /diagnostics carries (diagnostic_msgs/DiagnosticStatus), built by
pure functions from a node's state so the decision is tested without ROS.

Levels are diagnostic_msgs' (OK 0, WARN 1, ERROR 2, STALE 3); `values` are its key/value pairs.
`FlaairNode.publish_health` turns a `Health` into a DiagnosticArray once a second (the rate of
ROS's diagnostic_updater), under the node's fully qualified name as hardware id.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["ERROR", "OK", "STALE", "WARN", "Health", "health", "loss_percent"]

OK, WARN, ERROR, STALE = 0, 1, 2, 3
DIAGNOSTICS_PERIOD_S = 1.0  # diagnostic_updater's default rate: 1 Hz


@dataclass(frozen=True)
class Health:
    """One DiagnosticStatus: `name` (what is checked), `level`, a one-line `message`, `values`."""

    name: str
    level: int
    message: str
    values: tuple[tuple[str, str], ...]


def health(
    name: str, problems: list[tuple[int, str]], ok_message: str, values: Mapping[str, object]
) -> Health:
    """The worst of `problems` (level, text) with every text joined, or OK with `ok_message`.

    Values are formatted as text (floats with 4 significant digits), in the given order.
    """
    level = max((lv for lv, _ in problems), default=OK)
    message = "; ".join(text for lv, text in problems if lv > OK) or ok_message
    return Health(
        name,
        level,
        message,
        tuple(
            (key, f"{value:.4g}" if isinstance(value, float) else str(value))
            for key, value in values.items()
        ),
    )


def loss_percent(lost: int, total: int) -> float:
    """`lost` of `total` as a percentage (0 when nothing was expected)."""
    return 100.0 * lost / total if total else 0.0
