"""What drive a run carries, recognised from the drive signal itself (pure: numpy and scipy).

Kinds (``KINDS``):
  chirp         the drive frequency sweeps monotonically (paper: 20-200 Hz in 1 s)
  stepped_sine  the frequency holds on two or more levels in turn (paper: 60-200 Hz, 10 Hz steps);
                the steps (start, stop, frequency) are found from the drive
  sine          one frequency throughout (e.g. the collision runs)
  transition    the drive is made by the dSA controller from feedback (the run has controller
                state: K_r steps or ramps from synchronous to self-excited)
  free          no drive (the wing rings down or is moved by hand)
  unrecognised  a drive that is none of the above (analysed as a sweep, with a warning)

Method: the drive's analytic signal (Hilbert) gives an instantaneous frequency and envelope;
their medians over short blocks (``block_s``) give a block frequency, NaN where the envelope
is below ``free_run_drive_v`` (no drive). Consecutive blocks within the frequency tolerance of
the plateau's mean so far form a plateau; a plateau held at least ``min_dwell_s`` and
``min_dwell_cycles`` whose frequency does not drift is a dwell. Dwells covering
``dwell_coverage`` of the driven time make a stepped sine (two or more levels) or a sine (one
level); otherwise a monotone block frequency is a chirp. Each dwell's frequency is the slope
of the unwrapped drive phase, refined by a least-squares sine fit to the dwell's drive.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize, signal

from flaair_tools.bagio.markers import RUN_KINDS

KINDS = RUN_KINDS  # the vocabulary run markers carry


class RunKindError(ValueError):
    """A drive record or recognition parameter that cannot be used (the message names it)."""


@dataclass(frozen=True)
class RecognitionParams:
    """Thresholds of drive recognition (config/flaair.yaml, section analyze)."""

    block_s: float  # length of one frequency-estimate block [s]
    free_run_drive_v: float  # drive envelope below this counts as no drive [V]
    tolerance_hz: float  # a dwell's frequency stays within max(tolerance_hz, ...
    tolerance_fraction: float  # ... tolerance_fraction * frequency) of its start [-]
    min_dwell_s: float  # shortest dwell [s]
    min_dwell_cycles: float  # ... and at least this many drive cycles [-]
    dwell_coverage: float  # dwells cover at least this fraction of driven time [-]
    sweep_monotone_fraction: float  # chirp: this fraction of block-to-block changes go one way [-]

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise RunKindError(
                    f"recognition parameter '{name}' must be a finite number > 0, got {value!r}"
                )
        for name in ("dwell_coverage", "sweep_monotone_fraction", "tolerance_fraction"):
            if getattr(self, name) > 1:
                raise RunKindError(
                    f"recognition parameter '{name}' must be <= 1, got {getattr(self, name)!r}"
                )

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> RecognitionParams:
        """From a config section; names a missing key."""
        missing = [name for name in cls.__dataclass_fields__ if name not in values]
        if missing:
            raise RunKindError(f"recognition parameter(s) missing: {', '.join(missing)}")
        return cls(**{name: float(values[name]) for name in cls.__dataclass_fields__})


@dataclass(frozen=True)
class Step:
    """One dwell of constant drive frequency: samples [start, stop) at frequency_hz."""

    start: int
    stop: int
    frequency_hz: float


@dataclass(frozen=True)
class DriveKind:
    """The recognised drive of a run."""

    kind: str
    reason: str  # one human sentence: why this kind
    steps: tuple[Step, ...] = ()  # dwells (stepped_sine: each step; sine: the one dwell)
    sweep_hz: tuple[float, float] | None = None  # lowest and highest drive frequency seen
    drive_amplitude_v: float = 0.0  # median drive envelope over driven time [V]

    @property
    def frequency_hz(self) -> float | None:
        """The frequency of a sine (None for other kinds)."""
        return self.steps[0].frequency_hz if self.kind == "sine" and self.steps else None

    def frequency_track(self, n_samples: int) -> np.ndarray:
        """Drive frequency of every sample: each dwell's frequency, 0 outside the dwells."""
        track = np.zeros(n_samples)
        for step in self.steps:
            track[step.start : min(step.stop, n_samples)] = step.frequency_hz
        return track

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-ready form."""
        return {
            "kind": self.kind,
            "reason": self.reason,
            "drive_amplitude_v": self.drive_amplitude_v,
            "sweep_hz": list(self.sweep_hz) if self.sweep_hz else None,
            "steps": [
                {"start": s.start, "stop": s.stop, "frequency_hz": s.frequency_hz}
                for s in self.steps
            ],
        }


def _block_frequency(
    drive_v: np.ndarray, fs_hz: float, block: int, floor_v: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unwrapped phase per sample, and median frequency
    and envelope per block (NaN when undriven).
    """
    analytic = signal.hilbert(drive_v - np.median(drive_v))
    phase = np.unwrap(np.angle(analytic))
    frequency = np.gradient(phase) * fs_hz / (2 * np.pi)
    n_blocks = drive_v.size // block
    shape = (n_blocks, block)
    rough_f = np.median(frequency[: n_blocks * block].reshape(shape), axis=1)
    block_env = np.median(np.abs(analytic[: n_blocks * block]).reshape(shape), axis=1)
    # The analytic signal of a gated sine ripples at twice its frequency; the mean frequency
    # over one whole cycle (the phase advance across it) cancels the ripple. At the record's
    # ends the window slides inwards rather than shrinking.
    with np.errstate(divide="ignore", invalid="ignore"):
        width = np.where(rough_f > 0, np.round(fs_hz / rough_f), block)
    width = np.clip(np.nan_to_num(width, nan=block), block, drive_v.size - 1).astype(np.int64)
    lo = np.clip(np.arange(n_blocks) * block + block // 2 - width // 2, 0, drive_v.size - 1 - width)
    hi = lo + width
    block_f = (phase[hi] - phase[lo]) * fs_hz / (2 * np.pi * np.maximum(hi - lo, 1))
    # Within a cycle and a half of the record's ends the analytic signal is unreliable.
    centre = np.arange(n_blocks) * block + block // 2
    edge = (centre < 1.5 * width) | (centre > drive_v.size - 1.5 * width)
    block_f[(block_env < floor_v) | (block_f <= 0) | edge] = np.nan
    return phase, block_f, block_env


def _plateaus(block_f: np.ndarray, p: RecognitionParams) -> list[tuple[int, int]]:
    """Runs [a, b) of blocks whose frequency stays within tolerance of the run's mean so far."""
    runs: list[tuple[int, int]] = []
    start, total = None, 0.0
    for i, f in enumerate(block_f):
        mean = total / (i - start) if start is not None else 0.0
        if start is not None and (not np.isfinite(f) or abs(f - mean) > _tolerance(mean, p)):
            runs.append((start, i))
            start = None
        if start is None and np.isfinite(f):
            start, total = i, 0.0
        if start is not None:
            total += f
    if start is not None:
        runs.append((start, block_f.size))
    return runs


def _tolerance(frequency_hz: float, p: RecognitionParams) -> float:
    return max(p.tolerance_hz, p.tolerance_fraction * frequency_hz)


def _dwell_frequency(
    drive_v: np.ndarray, phase: np.ndarray, start: int, stop: int, fs_hz: float, tolerance_hz: float
) -> float:
    """A dwell's frequency: the phase slope over its
    middle 80 %, refined by a least-squares sine fit.
    """
    trim = (stop - start) // 10
    a, b = start + trim, stop - trim
    rough = float(np.polyfit(np.arange(a, b) / fs_hz, phase[a:b], 1)[0] / (2 * np.pi))
    t = np.arange(start, stop) / fs_hz
    x = drive_v[start:stop]

    def residual(f: float) -> float:
        basis = np.column_stack(
            [np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones(t.size)]
        )
        coef = np.linalg.lstsq(basis, x, rcond=None)[0]
        return float(np.sum((x - basis @ coef) ** 2))

    best = optimize.minimize_scalar(
        residual,
        bounds=(rough - tolerance_hz, rough + tolerance_hz),
        method="bounded",
        options={"xatol": 1e-5},
    )
    return float(best.x) if best.success and best.fun <= residual(rough) else rough


def recognise(
    drive_v: np.ndarray,
    fs_hz: float,
    params: RecognitionParams,
    *,
    has_controller_state: bool = False,
) -> DriveKind:
    """Recognise a run's drive (see module docstring).

    Parameters
    ----------
    drive_v
        The run's drive [V], one sample per sample; NaN samples count as no drive.
    fs_hz
        Sample rate [Hz].
    params
        Recognition thresholds.
    has_controller_state
        True when the run's drive was made by the dSA controller (the bag holds its state).
    """
    drive = np.asarray(drive_v, float).ravel()
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise RunKindError(f"sample rate must be a finite number > 0, got {fs_hz!r}")
    drive = np.where(np.isfinite(drive), drive, 0.0)
    if has_controller_state:
        return DriveKind(
            "transition",
            "the drive was made by the dSA controller from stroke "
            "feedback (controller state recorded)",
            drive_amplitude_v=float(np.sqrt(2) * np.std(drive)) if drive.size else 0.0,
        )
    block = max(8, round(params.block_s * fs_hz))
    if (
        drive.size < 4 * block
        or np.max(np.abs(drive - np.median(drive)), initial=0.0) < params.free_run_drive_v
    ):
        return DriveKind("free", f"no drive above {params.free_run_drive_v:g} V")
    phase, block_f, block_env = _block_frequency(drive, fs_hz, block, params.free_run_drive_v)
    driven = np.isfinite(block_f)
    if driven.sum() < 4:
        return DriveKind("free", f"the drive envelope stays below {params.free_run_drive_v:g} V")
    amplitude_v = float(np.median(block_env[driven]))
    sweep = (float(np.nanmin(block_f)), float(np.nanmax(block_f)))
    dwells = _dwells(drive, phase, block_f, block, fs_hz, params)
    covered = sum(s.stop - s.start for s in dwells) / (driven.sum() * block)
    if dwells and covered >= params.dwell_coverage:
        return _sine_or_steps(drive, phase, dwells, covered, fs_hz, sweep, amplitude_v, params)
    changes = np.diff(block_f[driven])
    changes = changes[np.abs(changes) > 1e-9]
    rising = float(np.mean(changes > 0)) if changes.size else 0.5
    if (
        sweep[1] - sweep[0] > 3 * _tolerance(sweep[1], params)
        and max(rising, 1 - rising) >= params.sweep_monotone_fraction
    ):
        return DriveKind(
            "chirp",
            f"the frequency sweeps {'up' if rising >= 0.5 else 'down'} from "
            f"{sweep[0]:.4g} to {sweep[1]:.4g} Hz "
            f"({max(rising, 1 - rising):.0%} of changes one way)",
            (),
            sweep,
            amplitude_v,
        )
    return DriveKind(
        "unrecognised",
        f"neither steady dwells ({covered:.0%} of the driven time) "
        f"nor a monotone sweep ({sweep[0]:.4g}-{sweep[1]:.4g} Hz)",
        (),
        sweep,
        amplitude_v,
    )


def _dwells(
    drive: np.ndarray,
    phase: np.ndarray,
    block_f: np.ndarray,
    block: int,
    fs_hz: float,
    params: RecognitionParams,
) -> list[Step]:
    """The steady stretches of the blocks' frequency long enough to be dwells."""
    dwells: list[Step] = []
    for a, b in _plateaus(block_f, params):
        f0 = float(np.median(block_f[a:b]))
        long_enough = (b - a) * block >= max(
            params.min_dwell_s * fs_hz, params.min_dwell_cycles * fs_hz / f0
        )
        # A slow chirp also stays within tolerance for a while, but it drifts across it.
        drift = abs(np.polyfit(np.arange(a, b), block_f[a:b], 1)[0]) * (b - a) if b - a > 2 else 0.0
        if long_enough and drift < 0.5 * _tolerance(f0, params):
            frequency = _dwell_frequency(
                drive, phase, a * block, b * block, fs_hz, _tolerance(f0, params)
            )
            dwells.append(Step(a * block, b * block, frequency))
    return dwells


def _sine_or_steps(
    drive: np.ndarray,
    phase: np.ndarray,
    dwells: list[Step],
    covered: float,
    fs_hz: float,
    sweep: tuple[float, float],
    amplitude_v: float,
    params: RecognitionParams,
) -> DriveKind:
    """Dwells covering the drive: one sine (one frequency level) or a stepped sine."""
    levels = _levels([s.frequency_hz for s in dwells], params)
    if len(levels) == 1:
        start, stop = dwells[0].start, dwells[-1].stop
        step = Step(
            start,
            stop,
            _dwell_frequency(drive, phase, start, stop, fs_hz, _tolerance(levels[0], params)),
        )
        return DriveKind(
            "sine",
            f"one frequency, {step.frequency_hz:.4g} Hz, over {covered:.0%} of the driven time",
            (step,),
            sweep,
            amplitude_v,
        )
    return DriveKind(
        "stepped_sine",
        f"{len(dwells)} dwells at {len(levels)} frequencies "
        f"({levels[0]:.4g}-{levels[-1]:.4g} Hz) cover "
        f"{covered:.0%} of the driven time",
        tuple(dwells),
        sweep,
        amplitude_v,
    )


def _levels(frequencies_hz: list[float], params: RecognitionParams) -> list[float]:
    """Distinct frequency levels among the dwells (within tolerance), ascending."""
    levels: list[float] = []
    for f in sorted(frequencies_hz):
        if not levels or f - levels[-1] > _tolerance(f, params):
            levels.append(f)
    return levels
