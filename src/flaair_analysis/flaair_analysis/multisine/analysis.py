"""The multisine analysis of a set of runs (../shared/multisine.md, sections 2-4), pure.

`analyse` takes one run per realization (measured-run columns), the design when it is known
and a model when one is given, refuses what the contract refuses (`MultisineInputError`, one
line naming the run), and returns the figures of nonlinearity.json with the line spectra the
report draws.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from flaair_analysis.multisine import nld, spectra
from flaair_analysis.multisine.design import MultisineDesign
from flaair_analysis.multisine.localise import localise
from flaair_model.model import Model
from flaair_sim.core.plant import simulate

__all__ = [
    "CHANNEL_UNITS",
    "SATURATION_SAMPLES",
    "SENSORS",
    "VIDEO",
    "Analysis",
    "ChannelSpectra",
    "FoundDesign",
    "MultisineInputError",
    "RunInput",
    "analyse",
    "channel_grid",
    "find_design",
    "model_columns",
    "model_reading",
]

CHANNEL_UNITS = {
    "stroke_sensor_v": "V",
    "pitch_sensor_v": "V",
    "stroke_deg": "deg",
    "pitch_deg": "deg",
}
SENSORS = ("stroke_sensor_v", "pitch_sensor_v")
VIDEO = ("stroke_deg", "pitch_deg")
SATURATION_SAMPLES = 5  # this many consecutive samples at the minimum or maximum: saturated
SAME_DRIVE = 1e-3  # two runs' first-period drive spectra within this x max|U|: one realization


class MultisineInputError(ValueError):
    """A run (or the set of runs) the analysis refuses; the message is one line naming it."""


@dataclass(frozen=True)
class RunInput:
    """One realization's run: its name (the file), sample rate and measured-run columns."""

    name: str
    fs_hz: float
    columns: Mapping[str, np.ndarray]


@dataclass(frozen=True)
class FoundDesign:
    """What the analysis uses: N, the lines, T and P, and where they came from."""

    source: str  # "design" | "drive"
    fs_hz: float
    period_samples: int
    excited_lines: tuple[int, ...]
    transient_periods: int
    periods: int
    realizations: int

    def doc(self) -> dict[str, Any]:
        """The `design` object of nonlinearity.json."""
        sets = nld.line_sets(self.excited_lines)
        f0 = self.fs_hz / self.period_samples
        return {
            "source": self.source,
            "fs_hz": self.fs_hz,
            "period_samples": self.period_samples,
            "base_frequency_hz": f0,
            "band_hz": [float(sets.excited[0] * f0), float(sets.excited[-1] * f0)],
            "excited_lines": [int(k) for k in sets.excited],
            "odd_detection_lines": [int(k) for k in sets.odd],
            "even_lines": [int(k) for k in sets.even],
            "transient_periods": self.transient_periods,
            "periods": self.periods,
            "realizations": self.realizations,
        }


@dataclass(frozen=True)
class ChannelSpectra:
    """What the report draws of one channel: per line k = 0 .. K-1, |Ybar|^2 and sigma2 averaged
    over the runs, and the model's |Yhat|^2 (None without a model).
    """

    power: np.ndarray
    sigma2: np.ndarray
    model_power: np.ndarray | None


@dataclass(frozen=True)
class Analysis:
    """The document (nonlinearity.json without `runs` and `model`) and the report's spectra."""

    design: FoundDesign
    doc: dict[str, Any]
    spectra: dict[str, ChannelSpectra] = field(default_factory=dict)


def _drive(run: RunInput) -> np.ndarray:
    if "drive_v" not in run.columns:
        raise MultisineInputError(f"{run.name}: no drive_v column")
    d = np.asarray(run.columns["drive_v"], dtype=np.float64)
    if not np.all(np.isfinite(d)):
        raise MultisineInputError(f"{run.name}: drive_v has missing or non-finite samples")
    return d


def _lines_of(run: RunInput, d: np.ndarray, n: int) -> tuple[int, ...]:
    lines = spectra.excited_lines_of(d[:n])
    even = lines[lines % 2 == 0]
    if lines.size < 2 or even.size:
        why = f"even line {int(even[0])} excited" if even.size else "fewer than 2 excited lines"
        raise MultisineInputError(f"{run.name}: not an odd multisine ({why})")
    return tuple(int(k) for k in lines)


def find_design(runs: Sequence[RunInput], design: MultisineDesign | None) -> FoundDesign:
    """N, the lines, T and P of the runs (from `design`, or from the drive); refuses a run that
    is not periodic, not an odd multisine, another design, a repeated realization, too short.
    """
    if not runs:
        raise MultisineInputError("no runs given")
    fs = float(design.fs_hz) if design is not None else float(runs[0].fs_hz)
    first_n: int | None = design.period_samples if design is not None else None
    first_lines = tuple(design.excited_lines) if design is not None else None
    against = "--design" if design is not None else f"the first run ({runs[0].name})"
    heads: list[np.ndarray] = []
    for run in runs:
        d = _drive(run)
        if abs(run.fs_hz - fs) > 1e-6 * fs:
            raise MultisineInputError(
                f"{run.name}: another design than {against} (sampled at {run.fs_hz:g} Hz, "
                f"not {fs:g} Hz)"
            )
        n = spectra.period_of(d)
        if n is None:
            raise MultisineInputError(
                f"{run.name}: no periodic excitation (the drive never repeats: a chirp or a "
                "stepped sine?)"
            )
        lines = _lines_of(run, d, n)
        if first_n is None:
            first_n, first_lines = n, lines
        elif n != first_n or lines != first_lines:
            what = (
                f"period {n} samples, not {first_n}" if n != first_n else "its excited lines differ"
            )
            raise MultisineInputError(f"{run.name}: another design than {against} ({what})")
        head = np.fft.rfft(d[:n])
        for other, previous in zip(runs, heads, strict=False):
            scale = max(float(np.abs(previous).max()), float(np.abs(head).max()))
            if float(np.abs(head - previous).max()) <= SAME_DRIVE * scale:
                raise MultisineInputError(
                    f"{run.name}: repeats the realization of {other.name} (the same drive)"
                )
        heads.append(head)
    assert first_n is not None and first_lines is not None
    if design is not None:
        t = design.transient_periods
    else:
        t = spectra.transient_periods(
            [np.asarray(r.columns[c]) for r in runs for c in SENSORS if c in r.columns], first_n
        )
    periods = []
    for run in runs:
        p = len(run.columns["drive_v"]) // first_n - t
        if p < 2:
            raise MultisineInputError(
                f"{run.name}: holds fewer than 2 whole periods after the transient "
                f"({max(p, 0)} after {t} transient period(s) of {first_n} samples)"
            )
        periods.append(p)
    return FoundDesign(
        "design" if design is not None else "drive",
        fs,
        first_n,
        first_lines,
        t,
        min(periods),
        len(runs),
    )


def _check_sensors(run: RunInput, first: int, count: int) -> None:
    for name in SENSORS:
        if name not in run.columns:
            raise MultisineInputError(f"{run.name}: no {name} column")
        seg = np.asarray(run.columns[name][first : first + count], dtype=np.float64)
        for edge in (seg.min(), seg.max()):
            at = np.concatenate([[0], (seg == edge).astype(np.int8), [0]])
            starts, ends = np.flatnonzero(np.diff(at) == 1), np.flatnonzero(np.diff(at) == -1)
            longest = int((ends - starts).max()) if starts.size else 0
            if longest >= SATURATION_SAMPLES:
                where = first + int(starts[int(np.argmax(ends - starts))])
                raise MultisineInputError(
                    f"{run.name}: {name} saturated ({longest} consecutive samples at "
                    f"{edge:g} from sample {where})"
                )


def model_columns(
    runs: Sequence[RunInput], model: Model, limit_v: float | None = None
) -> list[dict[str, np.ndarray]]:
    """The model simulated noise-free on each run's own drive from its first sample (clamped to
    +-limit_v as the plant does): sensor voltages and angles in degrees.
    """
    out = []
    for run in runs:
        d = _drive(run)
        if limit_v is not None:
            d = np.clip(d, -limit_v, limit_v)
        sim = simulate(d, run.fs_hz, model)
        out.append(
            {
                "stroke_sensor_v": sim.stroke_sensor_v,
                "pitch_sensor_v": sim.pitch_sensor_v,
                "stroke_deg": np.degrees(sim.stroke_rad),
                "pitch_deg": np.degrees(sim.pitch_rad),
            }
        )
    return out


def channel_grid(
    runs: Sequence[RunInput], name: str, found: FoundDesign, first: int, count: int
) -> spectra.VideoGrid | str:
    """The frame grid video channel `name` has in every run's analysed periods, or why none."""
    grids = []
    for run in runs:
        if name not in run.columns:
            return f"no {name} column in {run.name}"
        grid = spectra.video_grid(run.columns[name], first, count, found.period_samples)
        if isinstance(grid, str):
            return f"{run.name}: {grid}"
        grids.append(grid)
    if len({g.step for g in grids}) > 1:
        return "the video frame rate differs between runs"
    step = grids[0].step
    top_hz = max(found.excited_lines) * found.fs_hz / found.period_samples
    rate = found.fs_hz / step
    if rate < 4.0 * top_hz:
        return f"video at {rate:g} Hz is below 4 x the highest excited line ({top_hz:g} Hz)"
    if len({g.offset for g in grids}) > 1:
        return "the video frames sit at different samples in different runs"
    return grids[0]


def analyse(
    runs: Sequence[RunInput],
    design: MultisineDesign | None = None,
    model_runs: Sequence[Mapping[str, np.ndarray]] | None = None,
    margin_db: float = nld.MARGIN_DB,
) -> Analysis:
    """Every channel's BLA, levels and class (and with `model_runs`, the model's simulated
    columns per run, the model's figures and the disagreements); refuses bad runs.
    """
    found = find_design(runs, design)
    n, t, p = found.period_samples, found.transient_periods, found.periods
    first, count = t * n, p * n
    for run in runs:
        _check_sensors(run, first, count)
    sets = nld.line_sets(found.excited_lines)
    f0 = found.fs_hz / n
    drive = np.stack([_drive(r)[: first + count] for r in runs])
    ubar = spectra.line_spectra(drive, first, p, n).mean(axis=1)
    seg = drive[:, first : first + count]
    drive_rms = np.sqrt(np.mean(seg * seg, axis=1))
    trends: dict[str, list[dict[str, float]]] = {}
    channels: dict[str, Any] = {}
    skipped: dict[str, str] = {}
    shown: dict[str, ChannelSpectra] = {}
    for name, unit in CHANNEL_UNITS.items():
        grid: spectra.VideoGrid | None = None
        if name in VIDEO:
            got = channel_grid(runs, name, found, first, count)
            if isinstance(got, str):
                skipped[name] = got
                continue
            grid = got
        y = np.stack([np.asarray(r.columns[name][: first + count], dtype=np.float64) for r in runs])
        figs = nld.ChannelFigures.of(spectra.line_spectra(y, first, p, n, grid))
        levels = nld.levels_db(figs, sets)
        noise = float(levels["noise"])  # type: ignore[arg-type]  # always a number
        entry: dict[str, Any] = {
            "unit": unit,
            "bla": nld.bla(figs, ubar, sets.excited, f0),
            "levels_db": levels,
            "class": nld.classify(levels, noise, margin_db),
        }
        trend = nld.level_trend(figs, sets, drive_rms)
        if trend is not None:
            trends[name] = trend
        model_power = None
        if model_runs is not None:
            sim = np.stack([np.asarray(c[name][: first + count]) for c in model_runs])
            yhat = spectra.line_spectra(sim, first, p, n, grid).mean(axis=1)
            entry["model"] = nld.model_figures(figs, yhat, sets, noise, margin_db)
            entry["disagrees"] = nld.disagreements(
                entry["model"]["unexplained_db"], noise, margin_db
            )
            model_power = np.mean(np.abs(yhat) ** 2, axis=0)
        channels[name] = entry
        shown[name] = ChannelSpectra(figs.power(), np.mean(figs.sigma2, axis=0), model_power)
    doc = {
        "design": found.doc(),
        "margin_db": margin_db,
        "channels": channels,
        "skipped": skipped,
        "localisation": localise(channels, skipped, model_runs is not None, trends),
    }
    return Analysis(found, doc, shown)


def model_reading(
    runs: Sequence[RunInput], model: Model, limit_v: float | None = None
) -> dict[str, Any]:
    """What the runs' spectra say of `model`: per channel the distortion it does not predict
    (`disagrees`, and its level above the noise) and where that points (`localisation`).
    """
    doc = analyse(runs, None, model_columns(runs, model, limit_v)).doc
    return {
        "channels": {
            name: {
                "disagrees": entry["disagrees"],
                "unexplained_db": entry["model"]["unexplained_db"],
                "noise_db": entry["levels_db"]["noise"],
            }
            for name, entry in doc["channels"].items()
        },
        "skipped": doc["skipped"],
        "localisation": doc["localisation"],
    }
