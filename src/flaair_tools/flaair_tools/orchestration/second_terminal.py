"""What a second terminal types to reach a running graph's private ROS domain.

`flaair_common.graph.Graph` runs every graph on a leased domain with localhost discovery (and
unsets the deprecated ROS_LOCALHOST_ONLY); `ros2 topic echo` or `bin/flaair topic echo` in
another shell sees the graph only with the same settings. `live`, `experiment` and `launch`
print `hint(graph.env)` when they start.
"""

from __future__ import annotations

from collections.abc import Mapping

__all__ = ["export_line", "hint"]

RANGE = "ROS_AUTOMATIC_DISCOVERY_RANGE"
LOCALHOST_ONLY = "ROS_LOCALHOST_ONLY"


def export_line(env: Mapping[str, str]) -> str:
    """The shell line giving another terminal the graph's ROS settings from its environment."""
    words = [f"ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}"]
    if RANGE in env:
        words.append(f"{RANGE}={env[RANGE]}")
    unset = [name for name in (RANGE, LOCALHOST_ONLY) if name not in env]
    return f"export {' '.join(words)}; unset {' '.join(unset)}"


def hint(env: Mapping[str, str]) -> str:
    """Two lines for a command's start: what to type, then that line itself (to paste)."""
    return (
        f"  to reach this graph from another terminal (ros2 or bin/flaair):\n  {export_line(env)}"
    )
