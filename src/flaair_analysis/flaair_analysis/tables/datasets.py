"""Tables the simulated robot makes: steady sines through the plant, read as from video. Pure."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from flaair_model.model import Model
from flaair_model.settings import TableSettings

from .reader import Table
from .steady_state import steady_response

__all__ = ["simulated_table"]


def simulated_table(
    model: Model,
    levels_v: Sequence[float],
    frequency_hz: Sequence[float],
    s: TableSettings,
    rng: np.random.Generator,
    *,
    columns: Sequence[str] = ("stroke_pp_deg", "pitch_pp_deg"),
    noise_scale: float = 1.0,
    missing_pitch: float = 0.0,
    name: str = "simulated",
) -> Table:
    """The table a lab would read off video of `model` driven at every level and frequency.

    Each cell is the steady state plus reading noise of the size the fit assumes (x
    `noise_scale`); a fraction `missing_pitch` of pitch cells is left unmeasured (NaN).
    """
    f = np.tile(np.asarray(frequency_hz, dtype=float), len(levels_v))
    a = np.repeat(np.asarray(levels_v, dtype=float), len(frequency_hz))
    b = np.zeros_like(f)
    resp = steady_response([model], f, a, b, s)
    out = {}
    for c in columns:
        clean = resp[c][0]
        if "phase" in c:
            sigma = np.full(f.shape, s.phase_noise_deg)
        else:
            floor = s.reading_noise_deg / (2.0 if "amplitude" in c else 1.0)
            sigma = np.hypot(floor, s.reading_noise_rel * clean)
        value = clean + noise_scale * sigma * rng.standard_normal(f.size)
        if "phase" not in c:
            value = np.abs(value)
        if c.startswith("pitch") and missing_pitch > 0:
            value[rng.random(f.size) < missing_pitch] = np.nan
        out[c] = value
    return Table(name, "simulated", f, a, b, out, np.arange(f.size) + 2)
