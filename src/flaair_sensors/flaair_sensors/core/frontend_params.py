"""The front end's parameters: the frozen, validated
`FrontendParams`, and how a model or a calibration gives them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

__all__ = [
    "TUNING_FIELDS",
    "FrontendError",
    "FrontendParams",
    "params_from_calibration",
    "params_from_model",
    "with_overrides",
]


class FrontendError(ValueError):
    """Bad front-end parameter or input; the message names it."""


@dataclass(frozen=True)
class FrontendParams:
    """Inverse sensor model and front-end filter parameters (SI).

    Attributes
    ----------
    stroke_volts_per_rad, pitch_volts_per_rad
        Signed sensor gains: V - V_HREF - offset = volts_per_rad * angle (nominal model: < 0).
    reference_voltage_v
        Nominal charge-amplifier zero (V_HREF).
    sample_rate_hz
        Sample rate of the sensor voltages.
    stroke_offset_v, pitch_offset_v
        Calibrated zero-angle voltage minus ``reference_voltage_v``.
    drift_corner_hz
        Corner of the drift-tracking low-pass (0 disables drift removal).
    stroke_lag_s, pitch_lag_s
        Sensor lag behind the true angle (from calibration); positive = sensor late.
    compensate_lag
        Apply the phase-lead compensator for the lags (else the estimate stays delayed).
    lead_rolloff_hz
        Roll-off of the lead compensator (higher: more accurate in band, more noise).
    rail_low_v, rail_high_v, rail_margin_v
        Charge-amplifier rails; samples with V <= low + margin or V >= high - margin are invalid.
    holdoff_s
        Time marked invalid after an unusable sample (filter transient).
    velocity_cutoff_hz
        Cutoff of the stroke-velocity low-pass differentiator.
    """

    stroke_volts_per_rad: float
    pitch_volts_per_rad: float
    reference_voltage_v: float
    sample_rate_hz: float
    # tuning: no defaults (config/flaair.yaml frontend_node; flaair_sensors.frontend_io)
    drift_corner_hz: float
    compensate_lag: bool
    lead_rolloff_hz: float
    rail_low_v: float
    rail_high_v: float
    rail_margin_v: float
    holdoff_s: float
    velocity_cutoff_hz: float
    # calibration results: zero for the nominal (uncalibrated) sensor
    stroke_offset_v: float = 0.0
    pitch_offset_v: float = 0.0
    stroke_lag_s: float = 0.0
    pitch_lag_s: float = 0.0

    def __post_init__(self) -> None:
        fs = self.sample_rate_hz
        if not (math.isfinite(fs) and fs > 0):
            raise FrontendError(f"sample_rate_hz must be positive and finite, got {fs!r}")
        for name in ("stroke_volts_per_rad", "pitch_volts_per_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v != 0.0):
                raise FrontendError(f"{name} must be finite and non-zero, got {v!r}")
        for name in (
            "reference_voltage_v",
            "stroke_offset_v",
            "pitch_offset_v",
            "stroke_lag_s",
            "pitch_lag_s",
        ):
            if not math.isfinite(getattr(self, name)):
                raise FrontendError(f"{name} must be finite, got {getattr(self, name)!r}")
        if not (0.0 <= self.drift_corner_hz < fs / 2):
            raise FrontendError(
                f"drift_corner_hz must be in [0, fs/2), got {self.drift_corner_hz!r}"
            )
        if not (0.0 < self.velocity_cutoff_hz < fs / 2):
            raise FrontendError(
                f"velocity_cutoff_hz must be in (0, fs/2), got {self.velocity_cutoff_hz!r}"
            )
        if not (0.0 < self.lead_rolloff_hz < fs / 2):
            raise FrontendError(
                f"lead_rolloff_hz must be in (0, fs/2), got {self.lead_rolloff_hz!r}"
            )
        if not self.rail_low_v < self.rail_high_v:
            raise FrontendError(
                f"rail_low_v ({self.rail_low_v}) must be below rail_high_v ({self.rail_high_v})"
            )
        if not (self.rail_margin_v >= 0.0 and self.holdoff_s >= 0.0):
            raise FrontendError("rail_margin_v and holdoff_s must be >= 0")

    @property
    def holdoff_samples(self) -> int:
        """Hold-off after an unusable sample, in samples."""
        return math.ceil(self.holdoff_s * self.sample_rate_hz - 1e-9)


def params_from_model(model: Any, fs_hz: float, **overrides: Any) -> FrontendParams:
    """Front-end parameters from the model's nominal sensor gains.

    Parameters
    ----------
    model
        A ``flaair_model`` model: uses its signed ``stroke_volts_per_rad`` and
        ``pitch_volts_per_rad`` (nominal, effects not included) and
        ``sensors.reference_voltage_v``.
    fs_hz
        Sample rate.
    **overrides
        The tuning fields (required: ``TUNING_FIELDS``, e.g. from
        ``frontend_io.frontend_tuning_from_config``) and any other ``FrontendParams`` field.
    """
    fields = dict(
        stroke_volts_per_rad=_model_gain(model, "stroke_volts_per_rad"),
        pitch_volts_per_rad=_model_gain(model, "pitch_volts_per_rad"),
        reference_voltage_v=float(model.sensors.reference_voltage_v),
        sample_rate_hz=float(fs_hz),
    )
    fields.update(overrides)
    return _params(fields)


TUNING_FIELDS = (
    "drift_corner_hz",
    "compensate_lag",
    "lead_rolloff_hz",
    "rail_low_v",
    "rail_high_v",
    "rail_margin_v",
    "holdoff_s",
    "velocity_cutoff_hz",
)


def _params(fields: dict[str, Any]) -> FrontendParams:
    missing = [name for name in TUNING_FIELDS if name not in fields]
    if missing:
        raise FrontendError(
            f"front-end tuning missing: {', '.join(missing)} (config/flaair.yaml frontend_node)"
        )
    return FrontendParams(**fields)


def _model_gain(model: Any, name: str) -> float:
    """Signed gain from ``model.<name>`` (a number), else ``model.sensors.<name>``."""
    value = getattr(model, name, None)
    if value is None or callable(value):
        value = getattr(model.sensors, name)
        if callable(value):
            value = value()
    return float(value)


def params_from_calibration(
    calibration: Mapping[str, Any], fs_hz: float, **overrides: Any
) -> FrontendParams:
    """Front-end parameters from a ``calibration.calibrate`` result (or its JSON).

    angle_deg = polarity * gain_deg_per_v * (V - reference_voltage_v - offset_v), delayed by lag_s.

    Parameters
    ----------
    calibration
        ``{"reference_voltage_v": ..., "stroke": {...}, "pitch": {...}}``; each channel needs
        ``gain_deg_per_v``, ``polarity``, ``offset_v``, ``lag_s``.
    fs_hz
        Sample rate.
    **overrides
        The tuning fields (required: ``TUNING_FIELDS``) and any other ``FrontendParams`` field.
    """
    fields: dict[str, Any] = {"sample_rate_hz": float(fs_hz)}
    try:
        fields["reference_voltage_v"] = float(calibration["reference_voltage_v"])
    except KeyError:
        raise FrontendError("calibration has no 'reference_voltage_v'") from None
    except (TypeError, ValueError):
        raise FrontendError(
            f"calibration['reference_voltage_v'] must be a number, "
            f"got {calibration['reference_voltage_v']!r}"
        ) from None
    for channel in ("stroke", "pitch"):
        if channel not in calibration:
            raise FrontendError(f"calibration has no '{channel}' section")
        c = calibration[channel]
        for key in ("gain_deg_per_v", "polarity", "offset_v", "lag_s"):
            if key not in c:
                raise FrontendError(f"calibration['{channel}'] has no '{key}'")
        for key in ("gain_deg_per_v", "polarity", "offset_v", "lag_s"):
            try:
                float(c[key])
            except (TypeError, ValueError):
                raise FrontendError(
                    f"calibration['{channel}']['{key}'] must be a number, got {c[key]!r}"
                ) from None
        gain = float(c["gain_deg_per_v"])
        polarity = float(c["polarity"])
        if not (math.isfinite(gain) and gain > 0):
            raise FrontendError(
                f"calibration['{channel}']['gain_deg_per_v'] must be > 0, got {gain!r}"
            )
        if polarity not in (1.0, -1.0):
            raise FrontendError(
                f"calibration['{channel}']['polarity'] must be +1 or -1, got {polarity!r}"
            )
        fields[f"{channel}_volts_per_rad"] = polarity / math.radians(gain)
        fields[f"{channel}_offset_v"] = float(c["offset_v"])
        fields[f"{channel}_lag_s"] = float(c["lag_s"])
    fields.update(overrides)
    return _params(fields)


def with_overrides(params: FrontendParams, **overrides: Any) -> FrontendParams:
    """Copy of ``params`` with fields replaced (validated)."""
    return replace(params, **overrides)
