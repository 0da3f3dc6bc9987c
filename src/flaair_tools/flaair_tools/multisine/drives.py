"""A design's realizations as drive_node runs: what `flaair experiment multisine` plays.

An experiment of config/experiments.yaml with a `multisine:` block (the options of
`flaair multisine design`, its seed fixed) gets one run per realization, each (T + P) N samples
of `waveform: multisine` with the design's lines and that realization's phases.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from flaair_analysis.multisine.design import MultisineDesign, design_multisine

__all__ = ["DESIGN_KEYS", "design_of", "realization_runs"]

# the keys of an experiment's `multisine:` block, and their defaults (those of the command)
DESIGN_KEYS: dict[str, Any] = {
    "band_hz": [100.0, 250.0],
    "base_hz": 2.0,
    "lines_per_group": 3,
    "rms_v": 25.0,
    "periods": 4,
    "transient_periods": 1,
    "realizations": 4,
    "max_v": 100.0,
    "seed": None,
}


def design_of(block: Mapping[str, Any], fs_hz: float) -> MultisineDesign:
    """The design an experiment's `multisine:` block names (its seed required)."""
    unknown = sorted(set(block) - set(DESIGN_KEYS))
    if unknown:
        raise ValueError(f"multisine: unknown key(s) {', '.join(unknown)}")
    values = {**DESIGN_KEYS, **block}
    if values["seed"] is None:
        raise ValueError("multisine: a seed is required (the runs must be reproducible)")
    low, high = (float(v) for v in values["band_hz"])
    return design_multisine(
        band_hz=(low, high),
        base_hz=float(values["base_hz"]),
        lines_per_group=int(values["lines_per_group"]),
        rms_v=float(values["rms_v"]),
        periods=int(values["periods"]),
        transient_periods=int(values["transient_periods"]),
        realizations=int(values["realizations"]),
        fs_hz=fs_hz,
        max_v=float(values["max_v"]),
        seed=int(values["seed"]),
    )


def realization_runs(design: MultisineDesign) -> list[dict[str, Any]]:
    """One run per realization: name, run_time_s and the drive_node parameters."""
    return [
        {
            "name": f"realization_{m + 1}",
            "run_time_s": design.n_samples / design.fs_hz,
            "drive": {
                "waveform": "multisine",
                "amplitude_v": design.amplitude_v,
                "frequency_hz": design.base_frequency_hz,
                "multisine_lines": [float(k) for k in design.excited_lines],
                "multisine_phases_rad": list(design.phases_rad[m]),
            },
        }
        for m in range(design.realizations)
    ]
