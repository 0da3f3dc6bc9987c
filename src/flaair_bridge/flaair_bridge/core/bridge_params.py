"""The bridge core's parameters: frozen, validated,
no defaults (config/flaair.yaml, bridge_node).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from flaair_bridge.core import protocol

__all__ = ["BridgeParameterError", "BridgeParams"]


class BridgeParameterError(ValueError):
    """A bridge parameter out of range; the message names it."""


@dataclass(frozen=True)
class BridgeParams:
    """Bridge settings (no defaults: config/flaair.yaml, section bridge_node)."""

    sample_rate_hz: float
    block_size: int
    lead_samples: int
    drive_limit_v: float
    max_ahead_samples: int
    max_fill_samples: int
    resync_packets: int
    drive_timeout_s: float
    sensor_timeout_s: float
    target_host: str  # the target's address ("": learnt); sensor packets from another: foreign
    target_port: int  # its drive port (0: learnt); a packet from target_host:target_port is its

    def __post_init__(self) -> None:
        checks = {
            "sample_rate_hz": self.sample_rate_hz > 0 and math.isfinite(self.sample_rate_hz),
            "block_size": 1 <= self.block_size <= protocol.MAX_SAMPLES,
            "lead_samples": self.lead_samples >= 0,
            "drive_limit_v": self.drive_limit_v >= 0 and math.isfinite(self.drive_limit_v),
            "max_ahead_samples": self.max_ahead_samples >= 0,
            "max_fill_samples": self.max_fill_samples >= 0,
            "resync_packets": self.resync_packets >= 1,
            "drive_timeout_s": self.drive_timeout_s > 0,
            "sensor_timeout_s": self.sensor_timeout_s > 0,
        }
        for name, ok in checks.items():
            if not ok:
                raise BridgeParameterError(
                    f"parameter '{name}' = {getattr(self, name)!r} is out of range"
                )
