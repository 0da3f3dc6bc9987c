"""A lab's run put together: the target's log, the video's angles and the sync between them.

Pure numpy (docs/LAB_FILES.md, sections 1, 4 and 5): the drive from the logged amplifier input
(gain and bias), the video frames placed on the DAQ clock by the camera trigger's first rising
edge or by an explicit frame-0 time, each frame's angles at the DAQ sample nearest its time, and
the cross-correlation check of that sync against the stroke sensor's own estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flaair_tools.bagio import video_angles
from flaair_tools.bagio.rig import Rig
from flaair_tools.bagio.target_log import LabFileError

__all__ = [
    "FramePlacement",
    "SyncCheck",
    "drive_v",
    "place_frames",
    "sync_check",
    "sync_check_rate_problem",
    "trigger_time_s",
    "truth_columns",
    "video_angles_deg",
]


@dataclass(frozen=True)
class FramePlacement:
    """Where the video's frames fell on the DAQ clock."""

    frame_time_s: np.ndarray  # (frames,) DAQ time of each frame
    sample_index: np.ndarray  # (frames,) nearest DAQ sample, -1 outside the log
    trigger_time_s: float | None  # None: frame0_time_s sync
    placed: int  # frames inside the log
    dropped: int  # frames outside it


@dataclass(frozen=True)
class SyncCheck:
    """Video stroke against the stroke sensor's estimate: the lag that lines them up best."""

    offset_s: float  # video later than the estimate by this much (> 0)
    correlation: float  # normalised, at that lag (sign: the sensor's polarity)
    frame_period_s: float

    @property
    def suspicious(self) -> bool:
        """An offset over one frame: the sync (trigger frame, threshold, frame-0 time) is off."""
        return abs(self.offset_s) > self.frame_period_s


def trigger_time_s(
    time_s: np.ndarray, trigger_v: np.ndarray, threshold_v: float, where: str
) -> float:
    """Time of the first sample at which the trigger rises through `threshold_v`."""
    below = trigger_v[:-1] < threshold_v
    rises = np.flatnonzero(below & (trigger_v[1:] >= threshold_v))
    if rises.size == 0:
        raise LabFileError(
            f"{where}: no rising edge through {threshold_v:g} V in the camera "
            f"trigger (it spans {np.nanmin(trigger_v):.3g} to "
            f"{np.nanmax(trigger_v):.3g} V)"
        )
    return float(time_s[rises[0] + 1])


def place_frames(
    n_frames: int, rig: Rig, time_s: np.ndarray, trigger_v: np.ndarray | None, where: str
) -> FramePlacement:
    """Each frame's DAQ time and nearest sample (section 5); frames outside the log dropped.

    Frames are numbered as DLTdv numbers them, the first row being frame 1: frame k is at
    t_trig + (k - trigger_frame) / fps, or at frame0_time_s + (k - 1) / fps.
    """
    fs_hz = (time_s.size - 1) / (time_s[-1] - time_s[0])
    if rig.fps > fs_hz * (1 + 1e-9):
        raise LabFileError(
            f"{where}: the video's frame rate {rig.fps:g} fps is above the DAQ "
            f"rate {fs_hz:g} Hz: frames would share samples"
        )
    frames = np.arange(1, n_frames + 1)  # DLTdv's numbers: the first row is frame 1
    if rig.trigger_frame is not None:
        assert trigger_v is not None and rig.trigger_threshold_v is not None
        t_trig = trigger_time_s(time_s, trigger_v, rig.trigger_threshold_v, where)
        frame_time_s = t_trig + (frames - rig.trigger_frame) / rig.fps
    else:
        assert rig.frame0_time_s is not None
        t_trig = None
        frame_time_s = rig.frame0_time_s + (frames - 1) / rig.fps
    index = np.rint((frame_time_s - time_s[0]) * fs_hz).astype(np.int64)
    inside = (index >= 0) & (index < time_s.size)
    return FramePlacement(
        frame_time_s, np.where(inside, index, -1), t_trig, int(inside.sum()), int((~inside).sum())
    )


def video_angles_deg(
    rig: Rig, wing: dict[str, np.ndarray], tip_px: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """(stroke, pitch) per frame in degrees from the tracked points (section 4)."""
    le1, te1, le2 = (
        wing[name]
        for name in ("wing_leading_edge_1", "wing_trailing_edge_1", "wing_leading_edge_2")
    )
    frames = min(le1.shape[0], te1.shape[0], le2.shape[0])
    le1, te1, le2 = le1[:frames], te1[:frames], le2[:frames]
    pitch = video_angles.pitch_rad(le1, te1, le2, np.array(rig.up))
    if rig.stroke_from == "wing_span":
        stroke = video_angles.stroke_from_span_rad(
            le1, le2, np.array(rig.up), np.array(rig.rest_span)
        )
    else:
        assert tip_px is not None and rig.m_per_px is not None
        assert rig.tip_axis_px is not None and rig.transmission_ratio_rad_per_m is not None
        tip = np.full((frames, 2), np.nan)
        tip[: min(frames, tip_px.shape[0])] = tip_px[:frames]
        stroke = video_angles.stroke_from_tip_rad(
            tip, np.array(rig.tip_axis_px), rig.m_per_px, rig.transmission_ratio_rad_per_m
        )
    return np.degrees(stroke), np.degrees(pitch)


def drive_v(logged: np.ndarray, rig: Rig) -> np.ndarray:
    """The actuator voltage: the logged signal times the amplifier gain, less the bias."""
    return logged * rig.drive_gain_v_per_v - rig.drive_bias_v


def truth_columns(
    n_samples: int, placement: FramePlacement, stroke_deg: np.ndarray, pitch_deg: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """DAQ-rate stroke and pitch: each placed frame's angles at its sample, NaN elsewhere."""
    stroke, pitch = np.full(n_samples, np.nan), np.full(n_samples, np.nan)
    placed = placement.sample_index[: stroke_deg.size] >= 0
    index = placement.sample_index[: stroke_deg.size][placed]
    stroke[index], pitch[index] = stroke_deg[placed], pitch_deg[placed]
    return stroke, pitch


def sync_check_rate_problem(fs_hz: float, max_lag_s: float) -> str | None:
    """Why a log at `fs_hz` cannot make the sync check over lags up to `max_lag_s` (None: it
    can): one sample longer than the whole lag range leaves no lag to find.
    """
    if 1.0 / fs_hz > max_lag_s:
        return (
            f"one sample at {fs_hz:g} Hz ({1e3 / fs_hz:.3g} ms) is longer than the check's lag "
            f"range ({1e3 * max_lag_s:.3g} ms)"
        )
    return None


def sync_check(
    stroke_deg: np.ndarray, estimate_deg: np.ndarray, fs_hz: float, fps: float, max_lag_s: float
) -> SyncCheck | None:
    """Cross-correlate the video's stroke (DAQ rate, NaN off frames) with the sensor's estimate.

    Lags up to `max_lag_s` either way, refined to a fraction of a sample by a parabola through
    the peak; None when too few frames are tracked to say. The caller checks first that the
    log's rate can make the check (`sync_check_rate_problem`).
    """
    frames = np.flatnonzero(np.isfinite(stroke_deg) & np.isfinite(estimate_deg))
    max_lag = max(1, math.ceil(max_lag_s * fs_hz))
    frames = frames[(frames >= max_lag) & (frames < stroke_deg.size - max_lag)]
    if frames.size < 16:
        return None
    video = stroke_deg[frames] - stroke_deg[frames].mean()
    lags = np.arange(-max_lag, max_lag + 1)
    corr = np.empty(lags.size)
    for k, lag in enumerate(lags):
        sensor = estimate_deg[frames - lag]
        sensor = sensor - sensor.mean()
        corr[k] = video @ sensor / (np.linalg.norm(video) * np.linalg.norm(sensor) or 1.0)
    best = int(np.argmax(np.abs(corr)))
    shift = 0.0
    if 0 < best < lags.size - 1:
        a, b, c = np.abs(corr[best - 1 : best + 2])
        denominator = a - 2 * b + c
        shift = 0.5 * (a - c) / denominator if denominator != 0 else 0.0
    return SyncCheck(float((lags[best] + shift) / fs_hz), float(corr[best]), 1.0 / fps)
