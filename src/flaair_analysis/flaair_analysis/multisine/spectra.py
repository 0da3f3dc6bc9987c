"""Line spectra of periodic runs (../shared/multisine.md, sections 2 and 3), pure.

The design found from the drive alone (its period N and excited lines), the transient periods,
the video grid of a channel, and `Y_mp(k) = (sqrt(2) / N_c) sum_j y(n_j) exp(-2 pi i k n_j / N)`
for every run m and analysed period p at once (numpy's FFT over stacked periods).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "LINE_FLOOR",
    "PERIOD_TOLERANCE",
    "TRANSIENT_RATIO",
    "VideoGrid",
    "excited_lines_of",
    "is_multisine",
    "line_spectra",
    "period_of",
    "transient_periods",
    "video_grid",
]

PERIOD_TOLERANCE = 1e-3  # |d[n+N] - d[n]| <= this x RMS(d) at every sample: N is a period
LINE_FLOOR = 1e-2  # |U(k)| >= this x max|U|: line k is excited
TRANSIENT_RATIO = 2.0  # RMS(y_p - y_last) > this x RMS(y_last-1 - y_last): period p is transient


def period_of(drive_v: np.ndarray) -> int | None:
    """The smallest shift N <= len/2 with |d[n+N] - d[n]| <= 1e-3 RMS(d) at every sample, or None.

    Shifts are screened on the first 32 samples before the whole file is compared.
    """
    d = np.asarray(drive_v, dtype=np.float64)
    n = d.size
    rms = float(np.sqrt(np.mean(d * d)))
    if n < 4 or rms == 0.0:
        return None
    tol = PERIOD_TOLERANCE * rms
    shifts = np.arange(1, n // 2 + 1)
    head = min(32, n - n // 2)
    keep = np.ones(shifts.size, dtype=bool)
    for j in range(head):  # screen: the shifted sample j must match sample j
        keep &= np.abs(d[shifts + j] - d[j]) <= tol
    for shift in shifts[keep].tolist():
        if np.all(np.abs(d[shift:] - d[:-shift]) <= tol):
            return int(shift)
    return None


def excited_lines_of(drive_period_v: np.ndarray) -> np.ndarray:
    """Lines k >= 1 of one period's spectrum with |U(k)| >= 1e-2 max|U| (k >= 1)."""
    spectrum = np.abs(np.fft.rfft(np.asarray(drive_period_v, dtype=np.float64)))[1:]
    if spectrum.size == 0 or spectrum.max() == 0.0:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(spectrum >= LINE_FLOOR * spectrum.max()).astype(np.int64) + 1


def transient_periods(channels: Sequence[np.ndarray], period_samples: int) -> int:
    """T from the sensor channels of every run: the first period and every further leading period
    p with RMS(y_p - y_last) > 2 RMS(y_last-1 - y_last) on some channel (the largest T found).
    """
    t_all = 1
    for y in channels:
        whole = len(y) // period_samples
        if whole < 3:
            continue
        periods = np.asarray(y[: whole * period_samples], dtype=np.float64).reshape(whole, -1)
        last = periods[-1]
        ref = float(np.sqrt(np.mean((periods[-2] - last) ** 2)))
        diffs = np.sqrt(np.mean((periods[:-2] - last) ** 2, axis=1))
        t = 1
        while t < whole - 2 and diffs[t] > TRANSIENT_RATIO * ref:
            t += 1
        t_all = max(t_all, t)
    return t_all


@dataclass(frozen=True)
class VideoGrid:
    """Frames of a video channel: every `step`-th sample from `offset` (within a period)."""

    offset: int
    step: int


def video_grid(values: np.ndarray, first: int, count: int, period_samples: int) -> VideoGrid | str:
    """The regular frame grid of samples first .. first + count - 1, or why there is none."""
    seg = np.asarray(values[first : first + count], dtype=np.float64)
    frames = np.flatnonzero(np.isfinite(seg))
    if frames.size < 2:
        return "no video frames in the analysed periods"
    steps = np.diff(frames)
    step = int(steps.min())
    if np.any(steps != step):
        gap = int(np.argmax(steps != step))
        return (
            f"video frames missing or off the grid of every {step} samples "
            f"(near sample {first + int(frames[gap])})"
        )
    if period_samples % step:
        return f"video every {step} samples does not divide the period of {period_samples}"
    offset = int(frames[0]) % step
    if frames[0] != offset or frames[-1] != count - step + offset:
        return "video frames missing at the start or the end of the analysed periods"
    return VideoGrid(offset, step)


def line_spectra(
    y: np.ndarray, first: int, periods: int, period_samples: int, grid: VideoGrid | None = None
) -> np.ndarray:
    """Y_mp(k) for k = 0 .. N_c/2 of the periods starting at `first`: shape (periods, N_c/2 + 1).

    `y` may be (n,) or (runs, n) (then (runs, periods, N_c/2 + 1)); with a `grid` only its frames
    are used (N_c = N / step) and each line carries the phase of the frames' offset.
    """
    arr = np.asarray(y, dtype=np.float64)
    seg = arr[..., first : first + periods * period_samples]
    seg = seg.reshape(*arr.shape[:-1], periods, period_samples)
    step, offset = (1, 0) if grid is None else (grid.step, grid.offset)
    frames = seg[..., offset::step]
    n_c = frames.shape[-1]
    spec = np.fft.rfft(frames, axis=-1) * (np.sqrt(2.0) / n_c)
    if offset:
        k = np.arange(spec.shape[-1])
        spec = spec * np.exp(-2j * np.pi * k * offset / period_samples)
    return np.asarray(spec)


def is_multisine(drive_v: np.ndarray) -> bool:
    """Whether a drive is an odd multisine: periodic (`period_of`), two or more excited lines,
    every one odd.
    """
    d = np.asarray(drive_v, dtype=np.float64)
    if d.size < 4 or not np.all(np.isfinite(d)):
        return False
    n = period_of(d)
    if n is None:
        return False
    lines = excited_lines_of(d[:n])
    return bool(lines.size >= 2 and not np.any(lines % 2 == 0))
