"""Bode figure laid out like the paper's Fig. "bode" (matplotlib, Agg backend).

Two columns: (a) stroke, (b) pitch. Top row: amplitude (deg); bottom row: phase (deg;
stroke relative to the drive, pitch relative to stroke). Sensor-derived curve (blue) against
ground truth (orange). Kept apart from the numpy/scipy cores.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from .characterization import Bode, ChannelBode  # noqa: E402

__all__ = ["bode_figure", "save_bode_figure"]

SENSOR_COLOR = "tab:blue"
TRUTH_COLOR = "tab:orange"


def _column(ax_mag: Any, ax_ph: Any, cb: ChannelBode, title: str, phase_label: str) -> None:
    f = cb.frequency_hz
    ax_mag.plot(f, cb.sensor_amplitude_deg, "o-", color=SENSOR_COLOR, ms=3, label="sensor")
    ax_mag.plot(f, cb.truth_amplitude_deg, "s--", color=TRUTH_COLOR, ms=3, label="ground truth")
    ax_mag.set_title(title)
    ax_mag.set_ylabel("amplitude (deg)")
    ax_mag.grid(True, alpha=0.3)
    ax_mag.legend(fontsize=8)
    ax_ph.plot(f, cb.sensor_phase_deg, "o-", color=SENSOR_COLOR, ms=3, label="sensor")
    ax_ph.plot(f, cb.truth_phase_deg, "s--", color=TRUTH_COLOR, ms=3, label="ground truth")
    ax_ph.set_ylabel(phase_label)
    ax_ph.set_xlabel("frequency (Hz)")
    ax_ph.grid(True, alpha=0.3)


def bode_figure(stroke_bode: Bode, pitch_bode: Bode | None = None, title: str | None = None) -> Any:
    """Build the two-column Bode figure.

    Parameters
    ----------
    stroke_bode
        Bode data whose ``stroke`` channel fills column (a) (paper: the chirp).
    pitch_bode
        Bode data whose ``pitch`` channel fills column (b) (paper: the stepped sines);
        default: ``stroke_bode``.
    title
        Optional figure title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    pitch_bode = stroke_bode if pitch_bode is None else pitch_bode
    fig, axes = plt.subplots(2, 2, figsize=(9.0, 5.5), sharex="col", constrained_layout=True)
    _column(axes[0, 0], axes[1, 0], stroke_bode.stroke, f"(a) stroke ({stroke_bode.method})", "phase vs drive (deg)")
    _column(axes[0, 1], axes[1, 1], pitch_bode.pitch, f"(b) pitch ({pitch_bode.method})", "phase vs stroke (deg)")
    if title:
        fig.suptitle(title)
    return fig


def save_bode_figure(path: str | Path, stroke_bode: Bode, pitch_bode: Bode | None = None, title: str | None = None, dpi: int = 150) -> Path:
    """Build the Bode figure and save it as PNG; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig = bode_figure(stroke_bode, pitch_bode, title)
    try:
        fig.savefig(path, dpi=dpi, format="png")
    finally:
        plt.close(fig)
    return path
