"""The analysis bands, read once from config/flaair.yaml (`analyze:`), for every tool.

`calibrate`, `analyze` and the discrepancy workflow take the band of the band-limited
amplitude RMSE (the stroke-to-pitch resonance band, 110-190 Hz in the paper) and the band of
the lag-corrected time RMSE from here; the cores (`calibration.calibrate`,
`characterization.characterize*`) take them as required arguments.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from flaair_model.config import ConfigError, node_parameters
from flaair_model.schema import ParameterError

CONFIG_FILE = "flaair.yaml"
SECTION = "analyze"


@dataclass(frozen=True)
class AnalysisBands:
    """Frequency bands of the band-limited figures [Hz], each (low, high)."""

    amplitude_band_hz: tuple[float, float]
    time_band_hz: tuple[float, float]

    def label(self, name: str) -> str:
        """'110-190 Hz' for the band `name` (amplitude_band_hz or time_band_hz)."""
        low, high = getattr(self, name)
        return f"{low:g}-{high:g} Hz"


def band_from_config(values: Mapping[str, Any], name: str) -> tuple[float, float]:
    """The [low, high] band `name` of the analyze section, checked (the error names the key)."""
    where = f"config/{CONFIG_FILE} {SECTION}.{name}"
    if name not in values:
        raise ParameterError(f"{where}: missing")
    band = values[name]
    if not (
        isinstance(band, (list, tuple))
        and len(band) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in band)
    ):
        raise ParameterError(f"{where}: must be [low, high] in Hz, got {band!r}")
    low, high = float(band[0]), float(band[1])
    if not (math.isfinite(low) and math.isfinite(high) and 0 <= low < high):
        raise ParameterError(f"{where}: must satisfy 0 <= low < high, got {band!r}")
    return low, high


def analysis_values() -> dict[str, Any]:
    """The `analyze` section of config/flaair.yaml."""
    try:
        return node_parameters(CONFIG_FILE, SECTION)
    except ConfigError as exc:
        raise ParameterError(str(exc)) from exc


def analysis_bands_from_config(values: Mapping[str, Any] | None = None) -> AnalysisBands:
    """The bands from the `analyze` section's values (default: config/flaair.yaml)."""
    values = analysis_values() if values is None else values
    return AnalysisBands(
        band_from_config(values, "amplitude_band_hz"), band_from_config(values, "time_band_hz")
    )
