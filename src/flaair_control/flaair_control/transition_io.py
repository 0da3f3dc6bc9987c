"""The transition analysis settings from config/flaair.yaml
(`analyze: hilbert_*`), for every tool.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from flaair_control.core.transition import HilbertParams, TransitionError
from flaair_model.schema import ParameterError
from flaair_sensors.analysis_io import CONFIG_FILE, SECTION, analysis_values, band_from_config

_KEYS = ("hilbert_band_order", "hilbert_savgol_window_s", "hilbert_savgol_order", "hilbert_edge_s")


def hilbert_params_from_config(values: Mapping[str, Any] | None = None) -> HilbertParams:
    """Band-pass + Hilbert + Savitzky-Golay settings of `analyze` and the transition figure."""
    values = analysis_values() if values is None else values
    missing = [k for k in _KEYS if k not in values]
    if missing:
        raise ParameterError(f"config/{CONFIG_FILE} {SECTION}: missing {', '.join(missing)}")
    band_hz = band_from_config(values, "hilbert_band_hz")
    try:
        return HilbertParams(
            band_hz=band_hz,
            band_order=int(values["hilbert_band_order"]),
            savgol_window_s=float(values["hilbert_savgol_window_s"]),
            savgol_order=int(values["hilbert_savgol_order"]),
            edge_s=float(values["hilbert_edge_s"]),
        )
    except (TransitionError, TypeError, ValueError) as exc:
        raise ParameterError(f"config/{CONFIG_FILE} {SECTION}: {exc}") from exc
