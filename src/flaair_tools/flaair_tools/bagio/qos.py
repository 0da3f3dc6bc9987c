"""QoS profiles as rosbag2 records them: from rclpy profiles, to and from metadata YAML.

Part of `flaair_tools.bagio` (its `__init__` lists the public names).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos

from flaair_tools.bagio.messages import NS_PER_S

__all__ = ["qos_from_rclpy", "qos_from_yaml", "qos_to_yaml"]


def _qos_time(duration: Any) -> QosTime:
    nanoseconds = int(getattr(duration, "nanoseconds", duration))
    sec, nsec = divmod(nanoseconds, NS_PER_S)
    return QosTime(sec, nsec)


def qos_from_rclpy(profile: Any) -> Qos:
    """Rosbags Qos of an rclpy QoSProfile (duck-typed: rclpy is not imported here)."""
    return Qos(
        QosHistory(int(profile.history)),
        int(profile.depth),
        QosReliability(int(profile.reliability)),
        QosDurability(int(profile.durability)),
        _qos_time(profile.deadline),
        _qos_time(profile.lifespan),
        QosLiveliness(int(profile.liveliness)),
        _qos_time(profile.liveliness_lease_duration),
        bool(profile.avoid_ros_namespace_conventions),
    )


def qos_to_yaml(profiles: Sequence[Qos]) -> str:
    """Offered QoS profiles as the YAML text rosbag2 (Jazzy, v9) stores in MCAP channel metadata."""
    if not profiles:
        return ""
    return yaml.safe_dump(
        dump_qos_v9(list(profiles)), default_flow_style=False, sort_keys=False
    ).strip()


def qos_from_yaml(text: str) -> list[Qos]:
    """Offered QoS profiles from the YAML text of a
    channel's metadata (inverse of `qos_to_yaml`).
    """
    return parse_qos(text)
