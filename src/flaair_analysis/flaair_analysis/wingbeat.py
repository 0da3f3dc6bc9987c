"""Per-wingbeat summary of the wing state: stroke amplitude, frequency, pitch amplitude.

A wingbeat runs from one upward zero crossing of the stroke angle to the next. A Schmitt
trigger decides the crossings: the stroke must first fall below ``-hysteresis_deg`` to arm it,
then its upward crossing of zero (linearly interpolated between the two samples around it, so
the position is fractional) ends one wingbeat and starts the next. For each complete wingbeat:

- ``amplitude_deg``: half the stroke's peak-to-peak over the wingbeat;
- ``frequency_hz``: sample rate / wingbeat length in (fractional) samples;
- ``pitch_amplitude_deg``: half the pitch's peak-to-peak over the wingbeat;
- ``collision_score`` and ``k_r``: the latest collision-monitor and controller values given
  with the block that ended the wingbeat (NaN when none have been seen).

A wingbeat holding an invalid sample, or longer than ``1 / min_frequency_hz``, or shorter than
``1 / max_frequency_hz``, is dropped (an idle or broken wing has no wingbeat to summarise).

``step(state, inputs, params) -> (state, outputs)`` runs block by block; ``summarize`` is the
same step over a whole record, so the live view and an offline bag give identical summaries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np


class WingbeatParameterError(ValueError):
    """A wingbeat parameter or input is invalid; the message names it."""


@dataclass(frozen=True)
class WingbeatParams:
    """Wingbeat detection (SI; units in names). No defaults: values come from config/flaair.yaml."""

    sample_rate_hz: float
    hysteresis_deg: float
    min_frequency_hz: float
    max_frequency_hz: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sample_rate_hz) and self.sample_rate_hz > 0):
            raise WingbeatParameterError(
                f"sample_rate_hz must be finite and > 0, got {self.sample_rate_hz}"
            )
        if not (math.isfinite(self.hysteresis_deg) and self.hysteresis_deg >= 0):
            raise WingbeatParameterError(
                f"hysteresis_deg must be finite and >= 0, got {self.hysteresis_deg}"
            )
        if not (0 < self.min_frequency_hz < self.max_frequency_hz <= self.sample_rate_hz / 2):
            raise WingbeatParameterError(
                f"need 0 < min_frequency_hz < max_frequency_hz <= sample_rate_hz / 2, got "
                f"{self.min_frequency_hz}, {self.max_frequency_hz}, {self.sample_rate_hz}"
            )


class WingbeatState(NamedTuple):
    """Trigger and running extrema of the wingbeat in progress."""

    next_index: int  # sample index the next block must start at
    armed: bool  # stroke has been below -hysteresis since the last crossing
    last_crossing: float  # fractional sample index of the last crossing (NaN: none yet)
    previous_deg: float  # last stroke sample (NaN: none)
    stroke_max_deg: float
    stroke_min_deg: float
    pitch_max_deg: float
    pitch_min_deg: float
    beat_valid: bool  # every sample since the last crossing was valid


class WingbeatInputs(NamedTuple):
    """One wing-state block and the latest slow values."""

    first_sample_index: int
    stroke_deg: np.ndarray
    pitch_deg: np.ndarray
    valid: np.ndarray  # stroke_valid & pitch_valid
    # latest CollisionStatus spectrum_rmse_deg / threshold_deg (NaN: none)
    collision_score: float
    k_r: float  # latest ControllerState k_r (NaN: none)


class Wingbeats(NamedTuple):
    """Wingbeats completed within one block (arrays of equal length, possibly empty)."""

    start_sample: np.ndarray  # fractional sample index of the wingbeat's start
    end_sample: np.ndarray  # ... and of its end
    amplitude_deg: np.ndarray
    frequency_hz: np.ndarray
    pitch_amplitude_deg: np.ndarray
    collision_score: np.ndarray
    k_r: np.ndarray


def initial_state(params: WingbeatParams) -> WingbeatState:
    """State before any sample: nothing armed, no crossing seen."""
    return WingbeatState(
        0, False, math.nan, math.nan, -math.inf, math.inf, -math.inf, math.inf, False
    )


def collision_score(spectrum_rmse_deg: float, threshold_deg: float) -> float:
    """The collision monitor's metric over its threshold: >= 1 reads as colliding."""
    return spectrum_rmse_deg / threshold_deg if threshold_deg > 0 else math.nan


@numba.njit(cache=True)
def _scan(
    first: int,
    stroke: np.ndarray,
    pitch: np.ndarray,
    valid: np.ndarray,
    armed: bool,
    last_crossing: float,
    previous: float,
    s_max: float,
    s_min: float,
    p_max: float,
    p_min: float,
    beat_valid: bool,
    hysteresis: float,
    min_len: float,
    max_len: float,
) -> tuple[np.ndarray, bool, float, float, float, float, float, float, bool]:  # pragma: no cover
    n = stroke.shape[0]
    out = np.empty((n, 5))
    count = 0
    for k in range(n):
        x, p, ok = stroke[k], pitch[k], valid[k]
        if not ok or not math.isfinite(x) or not math.isfinite(p):
            beat_valid = False
            armed = False
            previous = math.nan
            continue
        if armed and previous < 0.0 <= x:
            crossing = first + k - 1 + (0.0 - previous) / (x - previous)
            if not math.isnan(last_crossing) and beat_valid:
                length = crossing - last_crossing
                if min_len <= length <= max_len:
                    out[count, 0] = last_crossing
                    out[count, 1] = crossing
                    out[count, 2] = 0.5 * (s_max - s_min)
                    out[count, 3] = length
                    out[count, 4] = 0.5 * (p_max - p_min)
                    count += 1
            last_crossing = crossing
            armed = False
            beat_valid = True
            s_max, s_min, p_max, p_min = -math.inf, math.inf, -math.inf, math.inf
        if x < -hysteresis:
            armed = True
        if not math.isnan(last_crossing) and first + k - last_crossing > max_len:
            last_crossing = math.nan  # idle: too long for a wingbeat, start over
        s_max, s_min = max(s_max, x), min(s_min, x)
        p_max, p_min = max(p_max, p), min(p_min, p)
        previous = x
    return out[:count], armed, last_crossing, previous, s_max, s_min, p_max, p_min, beat_valid


def step(
    state: WingbeatState, inputs: WingbeatInputs, params: WingbeatParams
) -> tuple[WingbeatState, Wingbeats]:
    """Advance the summary by one wing-state block.

    A block that does not continue the stream (a gap or a restart) drops the wingbeat in
    progress and starts over at its first sample.
    """
    stroke = np.ascontiguousarray(inputs.stroke_deg, dtype=np.float64)
    pitch = np.ascontiguousarray(inputs.pitch_deg, dtype=np.float64)
    valid = np.ascontiguousarray(inputs.valid, dtype=np.bool_)
    if not (stroke.shape == pitch.shape == valid.shape) or stroke.ndim != 1:
        raise WingbeatParameterError(
            "stroke_deg, pitch_deg and valid must be 1-D of one length, "
            f"got {stroke.shape}, {pitch.shape}, {valid.shape}"
        )
    if inputs.first_sample_index != state.next_index:
        state = initial_state(params)
    fs = params.sample_rate_hz
    rows, armed, last, previous, s_max, s_min, p_max, p_min, beat_valid = _scan(
        int(inputs.first_sample_index),
        stroke,
        pitch,
        valid,
        state.armed,
        state.last_crossing,
        state.previous_deg,
        state.stroke_max_deg,
        state.stroke_min_deg,
        state.pitch_max_deg,
        state.pitch_min_deg,
        state.beat_valid,
        params.hysteresis_deg,
        fs / params.max_frequency_hz,
        fs / params.min_frequency_hz,
    )
    new_state = WingbeatState(
        int(inputs.first_sample_index) + stroke.size,
        bool(armed),
        float(last),
        float(previous),
        float(s_max),
        float(s_min),
        float(p_max),
        float(p_min),
        bool(beat_valid),
    )
    count = rows.shape[0]
    return new_state, Wingbeats(
        rows[:, 0],
        rows[:, 1],
        rows[:, 2],
        fs / rows[:, 3],
        rows[:, 4],
        np.full(count, inputs.collision_score),
        np.full(count, inputs.k_r),
    )


def summarize(
    stroke_deg: np.ndarray,
    pitch_deg: np.ndarray,
    valid: np.ndarray,
    params: WingbeatParams,
    first_sample_index: int = 0,
) -> Wingbeats:
    """The wingbeats of a whole record: `step` once over it from the initial state."""
    state = initial_state(params)._replace(next_index=first_sample_index)
    return step(
        state,
        WingbeatInputs(first_sample_index, stroke_deg, pitch_deg, valid, math.nan, math.nan),
        params,
    )[1]


def concatenate(parts: list[Wingbeats]) -> Wingbeats:
    """Wingbeats of several blocks as one."""
    if not parts:
        return Wingbeats(*(np.empty(0) for _ in Wingbeats._fields))
    return Wingbeats(*(np.concatenate(column) for column in zip(*parts, strict=True)))
