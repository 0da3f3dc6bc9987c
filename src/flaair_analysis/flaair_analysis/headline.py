"""The paper's headline figures beside the ones measured here (pure): the published values,
each figure's label and unit, and the table `flaair analyze` reports (`headline`).
"""

from __future__ import annotations

import math
from typing import Any, Protocol

__all__ = [
    "LABELS",
    "PAPER",
    "BandLabels",
    "HeadlineChoiceError",
    "finite_or_none",
    "headline",
    "transition_source",
]


class HeadlineChoiceError(ValueError):
    """The run named for the headline is not among the bags' (the message names those there)."""


class BandLabels(Protocol):
    """What the headline needs of the analysis bands: a label per band ('110-190 Hz')."""

    def label(self, name: str) -> str:
        """The band `name` as text."""
        ...


def finite_or_none(value: Any) -> float | None:
    """`value` as a float, or None where it is missing or not finite (strict JSON's null)."""
    return float(value) if value is not None and math.isfinite(value) else None


# The paper's published figures, for the side-by-side table (deg, deg/V).
PAPER = {
    "stroke_gain_deg_per_v": 25.5,
    "pitch_gain_deg_per_v": 108.0,
    "stroke_amplitude_rmse_deg": 0.44,
    "pitch_amplitude_rmse_deg": 4.04,
    "pitch_amplitude_rmse_band_deg": 2.44,
    "pitch_time_rmse_deg": 8.20,
    "pitch_time_rmse_lag_corrected_deg": 4.44,
    "pitch_time_rmse_lag_corrected_band_deg": 3.93,
    "stroke_phase_rmse_deg": 9.69,
    "pitch_phase_rmse_deg": 14.41,
    "collision_spectrum_rmse_deg": 3.23,
    "no_collision_spectrum_rmse_deg": 0.53,
    "collision_time_rmse_deg": 15.81,
    "no_collision_time_rmse_deg": 3.34,
}
# Human label and unit of every headline figure ({band} fields: the configured analysis bands).
LABELS = {
    "stroke_gain_deg_per_v": ("Stroke sensor gain", "deg/V"),
    "pitch_gain_deg_per_v": ("Pitch (hinge) sensor gain", "deg/V"),
    "stroke_amplitude_rmse_deg": ("Stroke amplitude error, RMSE over the Bode", "deg"),
    "pitch_amplitude_rmse_deg": ("Pitch amplitude error, RMSE over the Bode", "deg"),
    "pitch_amplitude_rmse_band_deg": ("Pitch amplitude error, RMSE {amplitude_band_hz}", "deg"),
    "pitch_time_rmse_deg": ("Pitch error in time, RMSE", "deg"),
    "pitch_time_rmse_lag_corrected_deg": ("Pitch error in time, lag corrected", "deg"),
    "pitch_time_rmse_lag_corrected_band_deg": (
        "Pitch error in time, lag corrected, {time_band_hz}",
        "deg",
    ),
    "stroke_phase_rmse_deg": ("Stroke phase error, RMSE over the Bode", "deg"),
    "pitch_phase_rmse_deg": ("Pitch phase error, RMSE over the Bode", "deg"),
    "collision_spectrum_rmse_deg": (
        "Collision metric with the obstacle (pitch FFT vs sine)",
        "deg",
    ),
    "no_collision_spectrum_rmse_deg": ("Collision metric without the obstacle", "deg"),
    "collision_time_rmse_deg": ("Pitch vs sine in time, with the obstacle", "deg"),
    "no_collision_time_rmse_deg": ("Pitch vs sine in time, without the obstacle", "deg"),
    "transition_final_frequency_hz": ("dSA transition: final flapping frequency", "Hz"),
    "transition_final_amplitude_deg": ("dSA transition: final stroke amplitude", "deg"),
}


def _pick(
    bags: list[dict[str, Any]], methods: tuple[str, ...]
) -> tuple[str, dict[str, Any]] | None:
    """The run of one of `methods` with the strongest drive
    (the paper's 200 Vpp), with its 'bag/run' name.
    """
    best = None
    for bag in bags:
        for name, run in bag["runs"].items():
            if (
                run.get("method") in methods
                and "stroke" in run
                and (best is None or run["drive_amplitude_v"] > best[1]["drive_amplitude_v"])
            ):
                best = (f"{bag['experiment']}/{name}", run)
    return best


def transition_source(bag: dict[str, Any]) -> str:
    """Where a transition headline comes from: the bag, its experiment and its transition runs."""
    runs = [name for name, run in bag["runs"].items() if run.get("method") == "transition"]
    shown = f"{bag['experiment']}/{', '.join(runs)}" if runs else bag["experiment"]
    return f"{shown} ({bag['bag']})"


def _transition_bag(
    bags: list[dict[str, Any]], chosen: str | None
) -> tuple[dict[str, Any] | None, str]:
    """The bag the transition figures come from, and how it was chosen (for the note).

    `chosen` names a bag (its path or directory name), its experiment, or one of its transition
    runs; None: the first bag with a transition, and the note says so when there are several.
    """
    candidates = [bag for bag in bags if "transition" in bag]
    if chosen is None:
        if len(candidates) > 1:
            others = "; ".join(transition_source(b) for b in candidates[1:])
            return candidates[0], (
                f"the first of {len(candidates)} transition bags (also: {others}); "
                "--headline-transition chooses"
            )
        return (candidates[0] if candidates else None), ""
    for bag in candidates:
        runs = [name for name, run in bag["runs"].items() if run.get("method") == "transition"]
        names = {bag["bag"], bag["bag"].rstrip("/").rsplit("/", 1)[-1], bag["experiment"], *runs}
        if chosen in names:
            return bag, "chosen by --headline-transition"
    there = "; ".join(transition_source(b) for b in candidates) or "none"
    raise HeadlineChoiceError(
        f"--headline-transition {chosen}: no bag with a transition run is named so (bags with "
        f"one: {there})"
    )


def headline(
    bags: list[dict[str, Any]], bands: BandLabels, transition: str | None = None
) -> dict[str, dict[str, Any]]:
    """The paper's headline figures as measured here,
    beside the paper's, with label, unit and source.

    Parameters
    ----------
    bags
        Each bag's analysis (`flaair_tools.analysis.analyze.analyze_bag`'s result).
    bands
        The configured analysis bands (`flaair_sensors.analysis_io.AnalysisBands`), which some
        labels name.
    transition
        The bag (path or name), experiment or run the transition figures come from; None: the
        first bag holding a transition, the note naming the others.

    Raises
    ------
    HeadlineChoiceError
        `transition` names no bag with a transition run.
    """
    chosen, how = _transition_bag(bags, transition)
    ours: dict[str, tuple[float | None, str]] = {}
    chirp = _pick(bags, ("chirp",))
    stepped = _pick(bags, ("stepped",)) or chirp
    if chirp:
        source, run = chirp
        for key in ("gain_deg_per_v", "amplitude_rmse_deg", "phase_rmse_deg"):
            ours[f"stroke_{key}"] = (run["stroke"].get(key), source)
    if stepped:
        source, run = stepped
        for key in (
            "gain_deg_per_v",
            "amplitude_rmse_deg",
            "amplitude_rmse_band_deg",
            "time_rmse_deg",
            "time_rmse_lag_corrected_deg",
            "time_rmse_lag_corrected_band_deg",
            "phase_rmse_deg",
        ):
            ours[f"pitch_{key}"] = (run["pitch"].get(key), source)
    for bag in bags:
        runs = bag.get("collision", {}).get("runs", {})
        if "spectrum_rmse_deg" in runs.get("collision", {}) and "spectrum_rmse_deg" in runs.get(
            "no_collision", {}
        ):
            source = f"{bag['experiment']}/collision, no_collision"
            for prefix, part in (("", "collision"), ("no_", "no_collision")):
                ours[f"{prefix}collision_spectrum_rmse_deg"] = (
                    runs[part]["spectrum_rmse_deg"],
                    source,
                )
                ours[f"{prefix}collision_time_rmse_deg"] = (runs[part]["time_rmse_deg"], source)
    table = {}
    for key, paper in PAPER.items():
        value, source = ours.get(key, (None, ""))
        label = LABELS[key][0].format(
            amplitude_band_hz=bands.label("amplitude_band_hz"),
            time_band_hz=bands.label("time_band_hz"),
        )
        table[key] = {
            "flaair": finite_or_none(value),
            "paper": paper,
            "label": label,
            "unit": LABELS[key][1],
            "source": source,
        }
    if chosen is not None:
        t = chosen["transition"]
        source = transition_source(chosen)
        where = f"from {source}" + (f", {how}" if how else "")
        for key, value in (
            ("transition_final_frequency_hz", t["final_frequency_hz"]),
            ("transition_final_amplitude_deg", t["final_amplitude_deg"]),
        ):
            resonance = f"stroke resonance {t['resonance_hz']:g} Hz; paper: slightly above it; "
            table[key] = {
                "flaair": value,
                "paper": None,
                "label": LABELS[key][0],
                "unit": LABELS[key][1],
                "source": source,
                "note": (resonance if key.endswith("hz") else "") + where,
            }
    return table
