"""Bode figure laid out like the paper's Fig. "bode" (matplotlib Figure, no pyplot).

Two columns: (a) stroke, (b) pitch. Top row: amplitude (deg); bottom row: phase (deg;
stroke relative to the drive, pitch relative to stroke). Sensor-derived curve (blue) against
ground truth (orange). Kept apart from the numpy/scipy cores.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
from matplotlib.figure import Figure  # no pyplot: a notebook user's backend is left alone
from matplotlib.text import Text

from flaair_model.checked_files import printable
from flaair_sensors.core.bode import Bode, ChannelBode

__all__ = [
    "bode_figure",
    "collision_fft_figure",
    "literal_texts",
    "overlaid_bode_figure",
    "save_bode_figure",
    "save_figure",
]

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
    # Fixed margins (room for 5-character tick labels and the axis labels): the same look as
    # constrained layout at half the drawing time, which measures every tick label first.
    fig = Figure(figsize=(9.0, 5.5))
    axes = fig.subplots(2, 2, sharex="col")
    fig.subplots_adjust(
        left=0.085, right=0.985, bottom=0.09, top=0.88 if title else 0.93, wspace=0.28, hspace=0.08
    )
    _column(
        axes[0, 0],
        axes[1, 0],
        stroke_bode.stroke,
        f"(a) stroke ({stroke_bode.method})",
        "phase vs drive (deg)",
    )
    _column(
        axes[0, 1],
        axes[1, 1],
        pitch_bode.pitch,
        f"(b) pitch ({pitch_bode.method})",
        "phase vs stroke (deg)",
    )
    if title:
        fig.suptitle(title)
    return fig


def save_bode_figure(
    path: str | Path,
    stroke_bode: Bode,
    pitch_bode: Bode | None = None,
    title: str | None = None,
    dpi: int = 150,
) -> Path:
    """Build the Bode figure and save it as PNG; returns the path."""
    return save_figure(bode_figure(stroke_bode, pitch_bode, title), path, dpi)


def literal_texts(fig: Any) -> Any:
    """Every title, label, legend entry and note of `fig` drawn as the literal text it holds
    (run names come from files: a `$` is no mathtext, bytes that are not UTF-8 and control
    characters other than a line break are replaced);
    tick labels keep their own formatting. Returns `fig`.
    """
    ticks = {
        id(text)
        for ax in fig.axes
        for axis in (ax.xaxis, ax.yaxis)
        for text in axis.findobj(Text)
        if text is not axis.label
    }
    for text in fig.findobj(Text):
        if id(text) not in ticks:
            # line by line: a figure's own line breaks are layout, not control characters
            text.set_text("\n".join(printable(line) for line in text.get_text().split("\n")))
            text.set_parse_math(False)
    return fig


def save_figure(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Save a figure as PNG, its texts literal (`literal_texts`); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    literal_texts(fig).savefig(path, dpi=dpi, format="png")
    return path


def overlaid_bode_figure(bodes: dict[str, Bode], title: str | None = None) -> Any:
    """Bodes of several runs (e.g. the drive levels) overlaid: one colour per run.

    Sensor-derived curves solid, ground truth dashed; columns stroke and pitch, rows amplitude
    and phase as in ``bode_figure``.
    """
    fig = Figure(figsize=(12.0, 6.5), layout="constrained")
    axes = fig.subplots(2, 2, sharex="col")
    colors = matplotlib.colormaps["viridis"](
        [i / max(1, len(bodes) - 1) for i in range(len(bodes))]
    )
    for color, (label, bode) in zip(colors, bodes.items(), strict=True):
        for column, cb in enumerate((bode.stroke, bode.pitch)):
            axes[0, column].plot(
                cb.frequency_hz, cb.sensor_amplitude_deg, "-", color=color, lw=1.4, label=label
            )
            axes[0, column].plot(cb.frequency_hz, cb.truth_amplitude_deg, "--", color=color, lw=0.9)
            axes[1, column].plot(cb.frequency_hz, cb.sensor_phase_deg, "-", color=color, lw=1.4)
            axes[1, column].plot(cb.frequency_hz, cb.truth_phase_deg, "--", color=color, lw=0.9)
    for column, name in enumerate(("(a) stroke", "(b) pitch")):
        axes[0, column].set_title(f"{name}: sensor solid, ground truth dashed")
        axes[0, column].set_ylabel("amplitude (deg)")
        axes[1, column].set_ylabel(
            "phase vs drive (deg)" if column == 0 else "phase vs stroke (deg)"
        )
        axes[1, column].set_xlabel("frequency (Hz)")
        for row in range(2):
            axes[row, column].grid(True, alpha=0.3)
    fig.legend(
        *axes[0, 0].get_legend_handles_labels(),
        loc="outside right upper",
        fontsize=8,
        title="run (drive)",
        title_fontsize=8,
    )
    if title:
        fig.suptitle(title)
    return fig


def collision_fft_figure(
    frequency_hz: Any,
    spectra_deg: dict[str, Any],
    reference_deg: Any,
    drive_frequency_hz: float,
    insets: dict[str, tuple[Any, Any]],
    band_hz: float = 500.0,
) -> Any:
    """The paper's collision figure (b): FFT of sensor
    pitch per run against a pure sine, with time insets.

    Parameters
    ----------
    frequency_hz, spectra_deg
        Common frequency axis and each run's pitch amplitude spectrum (deg), by label.
    reference_deg
        Spectrum of the pure sine at the drive frequency (deg).
    insets
        label -> (time_s, pitch_deg): a few wingbeats of each run's pitch, drawn as insets.
    """
    colors = {"collision": "tab:blue", "no collision": "tab:green"}
    fig = Figure(figsize=(9.0, 5.0))
    ax = fig.subplots()
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.1, top=0.93)  # fixed: see bode_figure
    for label, spectrum in spectra_deg.items():
        ax.plot(
            frequency_hz,
            spectrum,
            "-",
            lw=1.5,
            color=colors.get(label),
            label=f"sensor pitch, {label}",
        )
    ax.plot(
        frequency_hz,
        reference_deg,
        "--",
        lw=1.2,
        color="tab:red",
        label=f"pure {drive_frequency_hz:g} Hz sine",
    )
    ax.set_xlim(0, band_hz)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("pitch amplitude (deg)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="center right", fontsize=8)
    for k, (label, (time_s, pitch_deg)) in enumerate(insets.items()):
        inset = ax.inset_axes([0.40 + 0.32 * k, 0.66, 0.25, 0.28])
        inset.plot(time_s, pitch_deg, color=colors.get(label, "k"), lw=1.0)
        inset.set_title(f"{label}: pitch vs time", fontsize=7)
        inset.set_xlabel("time (ms)", fontsize=7, labelpad=1)
        inset.set_ylabel("deg", fontsize=7, labelpad=1)
        inset.tick_params(labelsize=6)
    ax.set_title("Collision: FFT of sensor-derived pitch (paper Fig. collisions b)")
    return fig
