"""Typed accessors of config/flaair.yaml for the tools that read a section not their own.

A node reads its own section through its `ParamSpec` schema (typed, ranged); offline code that
needs a node's values (replay, the stroke study, a node's own I/O helpers) reads them through
`node_section` with that same schema, so they are checked as the running node checks them. A tool
that needs another section's values (the shared stream settings, the bridge's lead, `live`'s own
settings) reads them here, each section through one function returning a frozen dataclass: a
missing key or a value of the wrong type is a `ConfigError` naming the file, section and key.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import Any, TypeVar

from flaair_model.config import ConfigError, config_dir, node_parameters, shared_parameters
from flaair_model.schema import ParameterError, ParamSpec

__all__ = [
    "BridgeSettings",
    "ControllerSettings",
    "LiveSettings",
    "MonitorSettings",
    "StreamSettings",
    "TableSettings",
    "bridge",
    "controller",
    "live",
    "monitor",
    "node_section",
    "read_section",
    "stream",
    "tables",
]

CONFIG_FILE = "flaair.yaml"
T = TypeVar("T")


@dataclass(frozen=True)
class StreamSettings:
    """The `/**` section: what every block stream shares."""

    sample_rate_hz: float
    block_size: int
    drive_limit_v: float


@dataclass(frozen=True)
class LiveSettings:
    """`bin/flaair live`: the composed loop's DDS
    batching, block size against a target, patience.
    """

    dds_batch_blocks: int
    target_block_size: int
    first_packet_timeout_s: float


@dataclass(frozen=True)
class BridgeSettings:
    """What a graph's launcher needs of the UDP bridge's section."""

    lead_samples: int
    realtime_priority: int


@dataclass(frozen=True)
class MonitorSettings:
    """What an experiment needs of the collision monitor's section."""

    min_wingbeat_hz: float


@dataclass(frozen=True)
class ControllerSettings:
    """The dSA controller's stream settings (its section over `/**`)."""

    sample_rate_hz: float
    block_size: int


@dataclass(frozen=True)
class TableSettings:
    """Frequency-response tables (`tables` section): steady state, noise, hold-out rules."""

    sample_rate_hz: float
    settle_s: float
    measure_wingbeats: int
    min_frequency_hz: float
    max_frequency_hz: float
    reading_noise_deg: float
    reading_noise_rel: float
    phase_noise_deg: float
    fit_range: float
    max_nfev: int
    heldout_max_nfev: int
    shortlist: int
    max_effects_per_side: int
    near_resonance: float
    gap_ratio: float
    min_heldout_drop: float
    min_z: float


def _convert(value: Any, kind: type, where: str) -> Any:
    if kind is bool:
        if isinstance(value, bool):
            return value
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif kind is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif kind is str and isinstance(value, str):
        return value
    raise ConfigError(f"{where}: must be {kind.__name__}, got {value!r}")


def read_section(section: str, cls: type[T], file_name: str = CONFIG_FILE) -> T:
    """`cls` (a frozen dataclass) filled from `section`
    of config/`file_name`, each field checked.
    """
    values = (
        shared_parameters(file_name) if section == "/**" else node_parameters(file_name, section)
    )
    hints = typing.get_type_hints(cls)
    out = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        where = f"{config_dir() / file_name}: {section}.{f.name}"
        if f.name not in values:
            raise ConfigError(f"{where}: missing")
        out[f.name] = _convert(values[f.name], hints[f.name], where)
    return cls(**out)


def stream() -> StreamSettings:
    """Sample rate, block size and drive limit of every block stream (`/**`)."""
    return read_section("/**", StreamSettings)


def live() -> LiveSettings:
    return read_section("live", LiveSettings)


def bridge() -> BridgeSettings:
    return read_section("bridge_node", BridgeSettings)


def monitor() -> MonitorSettings:
    return read_section("collision_monitor_node", MonitorSettings)


def controller() -> ControllerSettings:
    return read_section("dsa_controller_node", ControllerSettings)


def tables() -> TableSettings:
    """`identify` and `discrepancy` on tables, `import-table`."""
    return read_section("tables", TableSettings)


def node_section(
    specs: list[ParamSpec], section: str, file_name: str = CONFIG_FILE
) -> dict[str, Any]:
    """A node's values from `section` of config/`file_name`, checked against its `specs` as the node
    checks them (type, range, choices), plus the shared `/**` values it inherits.

    Raises
    ------
    ParameterError
        Naming the file, section and parameter when one is missing or refused.
    """
    try:
        values = dict(node_parameters(file_name, section))
    except ConfigError as exc:
        raise ParameterError(str(exc)) from exc
    for spec in specs:
        where = f"{config_dir() / file_name}: {section}.{spec.name}"
        if spec.name not in values:
            raise ParameterError(f"{where}: missing")
        value = values[spec.name]
        try:
            if spec.type is list:
                if not isinstance(value, list):
                    raise ConfigError(f"{where}: must be a list of numbers, got {value!r}")
                value = [_convert(v, float, where) for v in value]
            else:
                value = _convert(value, spec.type, where)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from exc
        if spec.type in (int, float) and (
            (spec.min_value is not None and value < spec.min_value)
            or (spec.max_value is not None and value > spec.max_value)
        ):
            raise ParameterError(
                f"{where}: {value!r} is outside [{spec.min_value}, {spec.max_value}]"
            )
        if spec.choices and value not in spec.choices:
            raise ParameterError(f"{where}: {value!r} is not one of {', '.join(spec.choices)}")
        values[spec.name] = value
    return values
