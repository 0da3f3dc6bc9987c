"""How sure a discovered term's form is, in terms a lab can act on.

For each discovered term (`discovery.Discovered`): the held-out error of the next best form of
its step, whether the runs tell the two apart (their held-out errors differ by more than
`PARSIMONY`, the margin the search itself calls a tie), and a suggested experiment that would: a
steady sine of the drive, at one of `LEVELS` of the runs' largest drive and one frequency of a
grid over the analysed bands, where the two fitted models' predictions of the judged channel
differ most (in units of that channel's noise), and whether that difference reaches the noise
(`SEPARATES_OVER_NOISE`): where it does not, no run tried tells the two apart (a form the other
nests, e.g. a low-pass whose fitted corner is far above the drive).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from flaair_model.model import Model
from flaair_sim.core.plant import simulate_batch

__all__ = [
    "LEVELS",
    "PARSIMONY",
    "SEPARATES_OVER_NOISE",
    "SETTLE_S",
    "SUGGESTED_RUN_S",
    "TEST_S",
    "form_uncertainty",
    "suggest_experiment",
    "suggested_drive",
]

# Drive levels tried, as fractions of the runs' largest drive amplitude.
LEVELS = (0.25, 0.5, 0.75, 1.0)
# Held-out errors within this fraction of each other: the runs do not tell the forms apart.
PARSIMONY = 0.02
# The suggested run tells two forms apart where their predictions differ by this x the noise RMS.
SEPARATES_OVER_NOISE = 1.0
# A suggested sine is simulated this long to settle, then compared over TEST_S.
SETTLE_S = 0.08
TEST_S = 0.05
# The run a suggestion names lasts this long: dozens of wingbeats after it settles (the discovery
# benchmarks measure that run and add it).
SUGGESTED_RUN_S = 0.5


def _channel(out: Any, channel: str) -> np.ndarray:
    if channel in ("stroke_deg", "pitch_deg"):
        rad = out.stroke_rad if channel == "stroke_deg" else out.pitch_rad
        return np.degrees(np.asarray(rad, dtype=np.float64))
    return np.asarray(getattr(out, channel), dtype=np.float64)


def suggested_drive(
    amplitude_v: float, frequency_hz: float, fs_hz: float, duration_s: float
) -> np.ndarray:
    """The steady sine a suggestion names, as a run's drive: ramped up over half of `SETTLE_S`
    (as `suggest_experiment` simulates it), `duration_s` long (V).
    """
    t = np.arange(round(duration_s * fs_hz)) / fs_hz
    ramp = np.minimum(t / (0.5 * SETTLE_S), 1.0)
    return amplitude_v * np.sin(2.0 * np.pi * frequency_hz * t) * ramp


def suggest_experiment(
    models: Sequence[Model],
    channel: str,
    fs_hz: float,
    amplitude_v: float,
    frequencies_hz: Sequence[float],
    noise: float,
) -> dict[str, Any]:
    """The steady sine (level, frequency) where `models[0]` and `models[1]` differ most on
    `channel`: {waveform, drive_amplitude_v, level, frequency_hz, duration_s, rms_difference,
    over_noise, separates} (`separates`: the difference reaches `SEPARATES_OVER_NOISE` x the
    noise; the run: that sine, ramped up as `suggested_drive`, `SUGGESTED_RUN_S` long).
    """
    n_settle = round(SETTLE_S * fs_hz)
    best: dict[str, Any] = {"rms_difference": -1.0}
    for level in LEVELS:
        for f in frequencies_hz:
            drive = suggested_drive(level * amplitude_v, f, fs_hz, SETTLE_S + TEST_S)
            out = simulate_batch(drive, fs_hz, list(models[:2]))
            a, b = (_channel(out, channel)[k, n_settle:] for k in (0, 1))
            rms = float(np.sqrt(np.mean((a - b) ** 2)))
            if rms > best["rms_difference"]:
                best = {
                    "waveform": "sine",
                    "drive_amplitude_v": level * amplitude_v,
                    "level": level,
                    "frequency_hz": float(f),
                    "duration_s": SUGGESTED_RUN_S,
                    "rms_difference": rms,
                }
    best["over_noise"] = best["rms_difference"] / noise if noise > 0 else math.inf
    best["separates"] = bool(best["over_noise"] >= SEPARATES_OVER_NOISE)
    return best


def form_uncertainty(
    winner: tuple[Any, ...],
    judged: Sequence[tuple[Any, ...]],
    channel: str,
    fs_hz: float,
    amplitude_v: float,
    frequencies_hz: Sequence[float],
    noise: float,
) -> dict[str, Any]:
    """The next best form of the step (judged candidates: (evidence, kind, site, specs, model)),
    whether the runs tell it from the winner, and the experiment that would.
    """
    ev, model = winner[0], winner[4]
    rivals = sorted(
        (j for j in judged if j[0] is not ev and math.isfinite(j[0].heldout_nrmse_after)),
        key=lambda j: j[0].heldout_nrmse_after,
    )
    if not rivals:
        return {"next_best": None, "distinguishable": None, "suggested_experiment": None}
    rev, rkind, rsite, _rspecs, rmodel = rivals[0]
    margin = rev.heldout_nrmse_after / ev.heldout_nrmse_after - 1.0
    return {
        "next_best": {
            "term": rkind.name,
            "acts_on": rsite,
            "heldout_nrmse_after": rev.heldout_nrmse_after,
            "accepted": rev.accepted,
        },
        "heldout_nrmse_after": ev.heldout_nrmse_after,
        "relative_margin": margin,
        "distinguishable": bool(margin > PARSIMONY),
        "suggested_experiment": suggest_experiment(
            [model, rmodel], channel, fs_hz, amplitude_v, frequencies_hz, noise
        ),
    }
