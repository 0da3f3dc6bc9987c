"""The one declaration of a node's parameters: name (unit in the name), type, range, meaning.

Pure (no rclpy): I/O modules list their nodes' parameters here once; `flaair_common.params`
turns each into the ROS descriptor rclpy enforces, `flaair_common.runtime` into the --help
table. Values come from config/ only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["STREAM_PARAMS", "ParamSpec", "ParameterError", "declared_values"]


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter: name (unit in the name), type, description and allowed values."""

    name: str
    type: type
    description: str
    min_value: float | None = None
    max_value: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False


# The block stream's shape, shared by every node on it (config/flaair.yaml `/**`).
STREAM_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "sample_rate_hz",
        float,
        "Sample rate of every block stream [Hz]",
        1000.0,
        1.0e6,
        read_only=True,
    ),
    ParamSpec("block_size", int, "Samples per block", 1, 100000, read_only=True),
)


class ParameterError(ValueError):
    """A parameter value was refused; the message names the parameter."""


def declared_values(
    values: Mapping[str, Any], specs: Sequence[ParamSpec], skip: tuple[str, ...] = ()
) -> dict[str, Any]:
    """The values of the parameters `specs` declares (but `skip`); ParameterError names any
    missing.
    """
    missing = [s.name for s in specs if s.name not in values and s.name not in skip]
    if missing:
        raise ParameterError(f"missing parameter(s): {', '.join(missing)}")
    return {s.name: values[s.name] for s in specs if s.name not in skip}
