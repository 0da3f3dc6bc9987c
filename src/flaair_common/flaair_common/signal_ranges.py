"""signal_ranges: the values a measured run may plausibly hold, checked on every import path.

A CSV export and a lab's MAT log and tracks become the same `MeasuredRun`; before either is
written to a bag, every column is checked against one bound (`PLAUSIBLE_ABS`), so a log in
millivolts read as volts, a wrong gain, or a wild value is refused by column, whatever the
file it came from. NaN is left to the readers (a sensor cell must be finite, a truth cell may
be untracked).
"""

from __future__ import annotations

import numpy as np

from flaair_common.runcsv import MeasuredRun

__all__ = ["PLAUSIBLE_ABS", "implausible"]

# column -> the largest magnitude a real bench run reaches, with a wide margin
PLAUSIBLE_ABS: dict[str, float] = {
    "drive_v": 1e4,  # the piezo drive is a few hundred volts
    "stroke_sensor_v": 1e3,  # charge-amplifier outputs sit within their supply rails
    "pitch_sensor_v": 1e3,
    "stroke_deg": 360.0,  # a wing angle past a full turn is a tracking or unit error
    "pitch_deg": 360.0,
}


def implausible(run: MeasuredRun) -> str | None:
    """What is implausible in `run` (column, sample and value), or None when nothing is."""
    for column, bound in PLAUSIBLE_ABS.items():
        if column not in run.columns:
            continue
        values = np.abs(run.columns[column])
        with np.errstate(invalid="ignore"):
            beyond = np.flatnonzero(values > bound)
        if beyond.size:
            k = int(beyond[0])
            return (
                f"{column}[{k}] = {run.columns[column][k]:.4g} is beyond the plausible "
                f"+-{bound:g} ({beyond.size} sample(s)): check the file's units and gains"
            )
    return None
