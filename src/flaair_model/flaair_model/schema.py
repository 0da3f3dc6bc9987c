"""The one declaration of a node's parameters: name (unit in the name), type, range, meaning.

Pure (no rclpy): I/O modules list their nodes' parameters here once; `flaair_common.params`
turns each into the ROS descriptor rclpy enforces, `flaair_common.runtime` into the --help
table. Values come from config/ only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["ParamSpec", "ParameterError", "declared_values"]


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
